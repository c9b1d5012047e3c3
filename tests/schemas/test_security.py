"""The secure profile's pieces that need no network: endpoint checks and the policy's shape."""

from pathlib import Path

import pytest

from schemas.security import POLICY, ROLES, RULES, TlsIdentity, access_control, load_identity
from schemas.transport import session_config


def test_secure_and_plain_endpoints_are_not_mixed(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="needs TLS credentials"):
        session_config("client", connect=["tls/127.0.0.1:7447"])
    with pytest.raises(ValueError, match="tls/ endpoints only"):
        session_config(
            "client", connect=["tcp/127.0.0.1:7447"], identity=TlsIdentity(tmp_path, "worker")
        )


def test_missing_credentials_are_named(tmp_path: Path) -> None:
    assert load_identity(None, "worker") is None
    with pytest.raises(ValueError, match=r"ca\.pem"):
        load_identity(tmp_path, "worker")


def test_every_policy_names_known_rules_and_the_default_is_deny() -> None:
    policy = access_control()
    assert policy["default_permission"] == "deny"
    rule_ids = {rule["id"] for rule in RULES}
    assert set(POLICY) == set(ROLES)
    for rules in POLICY.values():
        assert set(rules) <= rule_ids
    # The separation the farm depends on: jobs in from analytic only, results in from workers only.
    owners = {rule: {role for role, rules in POLICY.items() if rule in rules} for rule in rule_ids}
    assert owners["submit jobs"] == {"analytic"}
    assert owners["return results"] == {"worker"}
    assert owners["ask for work"] == {"worker"}
