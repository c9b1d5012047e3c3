"""The secure profile as data: identities, the credentials directory, the access policy's shape.
(How a session is opened with them: tests/edges/test_transport.py.)"""

from pathlib import Path

import pytest

from gainfarm.schemas import keys
from gainfarm.schemas.security import (
    TlsIdentity,
    UnknownIdentity,
    access_control,
    load_identity,
    owned_study,
    participants,
)


def _touch(directory: Path, *common_names: str) -> None:
    """Credential files by name only: these tests read the layout, not the certificates."""
    (directory / "ca.pem").write_text("")
    for common_name in common_names:
        (directory / f"{common_name}.pem").write_text("")
        (directory / f"{common_name}.key").write_text("")


def test_an_identity_is_a_role_and_a_name(tmp_path: Path) -> None:
    worker = TlsIdentity(tmp_path, "worker", "cobot-3")
    assert worker.common_name == "worker.cobot-3"
    assert worker.certificate == tmp_path / "worker.cobot-3.pem"
    assert worker.private_key == tmp_path / "worker.cobot-3.key"
    broker = TlsIdentity(tmp_path, "broker")
    assert (broker.name, broker.common_name) == ("broker", "broker")
    assert broker.certificate == tmp_path / "broker.pem"
    assert owned_study("alice", "run-1") == "alice.run-1"
    # No dots (alice.x must not be a study of a participant called alice.x's owner), no
    # wildcards, nothing empty or longer than 32 characters.
    for bad in ("", "a.b", "a*", "$*", "a/b", "x" * 33):
        with pytest.raises(UnknownIdentity):
            TlsIdentity(tmp_path, "analytic", bad)
    with pytest.raises(UnknownIdentity):
        TlsIdentity(tmp_path, "worker")  # a participant needs a name


def test_loading_picks_the_only_identity_of_a_role_or_the_one_named(tmp_path: Path) -> None:
    assert load_identity(None, "worker") is None
    with pytest.raises(ValueError, match=r"ca\.pem"):
        load_identity(tmp_path, "worker", "cobot-1")
    _touch(tmp_path, "broker", "worker.cobot-1", "analytic.alice", "analytic.bob")
    assert load_identity(tmp_path, "worker") == TlsIdentity(tmp_path, "worker", "cobot-1")
    assert load_identity(tmp_path, "broker") == TlsIdentity(tmp_path, "broker")
    assert load_identity(tmp_path, "analytic", "bob") == TlsIdentity(tmp_path, "analytic", "bob")
    with pytest.raises(UnknownIdentity, match=r"several analytic identities.*alice, bob"):
        load_identity(tmp_path, "analytic")
    with pytest.raises(UnknownIdentity, match=r"no worker 'cobot-2'.*holds cobot-1"):
        load_identity(tmp_path, "worker", "cobot-2")
    # A file missing, or no identity of the role at all, is the directory's fault, not a name's.
    (tmp_path / "worker.cobot-1.key").unlink()
    with pytest.raises(ValueError, match=r"worker\.cobot-1\.key") as missing:
        load_identity(tmp_path, "worker")
    assert not isinstance(missing.value, UnknownIdentity)
    only_ca = tmp_path / "only-ca"
    only_ca.mkdir()
    _touch(only_ca)
    with pytest.raises(ValueError, match="no worker identity") as none:
        load_identity(only_ca, "worker")
    assert not isinstance(none.value, UnknownIdentity)


def test_the_participants_are_the_certificates_there_minus_the_revoked(tmp_path: Path) -> None:
    _touch(tmp_path, "broker", "worker.cobot-1", "worker.cobot-2", "analytic.alice")
    (tmp_path / "worker.pem").write_text("")  # an old role-only certificate: nobody now
    (tmp_path / "worker.cobot-1.key").unlink()  # the broker's host needs no participant's key
    (tmp_path / "revoked.txt").write_text("# revoked\nworker.cobot-2  # stolen laptop\n")
    allowed = participants(tmp_path)
    assert [identity.common_name for identity in allowed] == ["analytic.alice", "worker.cobot-1"]


def test_the_policy_names_each_participant_and_only_its_own_keys(tmp_path: Path) -> None:
    allowed = [TlsIdentity(tmp_path, "analytic", "alice"), TlsIdentity(tmp_path, "worker", "w1")]
    policy = access_control(allowed)
    assert policy["enabled"] and policy["default_permission"] == "deny"
    rules = {rule["id"]: rule for rule in policy["rules"]}
    assert len(rules) == len(policy["rules"]), "rule ids are unique"
    subjects = {subject["id"]: subject["cert_common_names"] for subject in policy["subjects"]}
    assert subjects == {
        "broker": ["broker"],
        "analytic.alice": ["analytic.alice"],
        "worker.w1": ["worker.w1"],
    }
    granted: dict[str, set[tuple[str, str, str]]] = {}
    for entry in policy["policies"]:
        (subject,) = entry["subjects"]
        granted[subject] = {
            (message, rule["flows"][0], key)
            for rule in (rules[rule_id] for rule_id in entry["rules"])
            for message in rule["messages"]
            for key in rule["key_exprs"]
        }
    alice, worker = granted["analytic.alice"], granted["worker.w1"]
    assert ("query", "ingress", keys.submit("alice.$*")) in alice
    assert ("query", "ingress", keys.confirm("alice.$*")) in alice
    assert ("declare_subscriber", "ingress", keys.study_results("alice.$*")) in alice
    assert ("liveliness_token", "ingress", keys.alive_study("alice.$*")) in alice
    assert ("query", "ingress", keys.lease("w1")) in worker
    assert ("liveliness_token", "ingress", keys.alive_worker("w1")) in worker
    assert ("put", "ingress", keys.ALL_RESULTS) in worker
    assert ("declare_queryable", "ingress", keys.model("alice.$*", "*")) in alice
    assert ("query", "ingress", keys.ALL_MODELS) in worker
    assert ("declare_queryable", "ingress", keys.worker_logs("w1")) in worker
    assert ("query", "ingress", keys.log("alice.$*", "*", "*")) in alice
    # Everything a participant may send names itself, but for status, the broker's token, and a
    # worker's results (the broker checks those against its leases) and model fetches (the model
    # must hash to the digest the job names). A worker serves logs under its own name alone.
    for _, flow, key in alice:
        assert flow == "egress" or "/alice.$*" in key or key in (keys.STATUS, keys.ALIVE_BROKER)
    for _, flow, key in worker:
        assert (
            flow == "egress"
            or key.endswith("/w1")
            or key == keys.worker_logs("w1")
            or key
            in (
                keys.STATUS,
                keys.ALL_RESULTS,
                keys.ALL_MODELS,
            )
        )
    assert not {g for g in alice if g[0] == "put" and g[1] == "ingress"}, "alice forges no result"
    assert not {g for g in worker if "submit" in g[2]}, "a worker submits nothing"
    assert granted["broker"] == {
        ("query", "ingress", keys.STATUS),
        ("reply", "egress", keys.STATUS),
    }
