"""Tests that need a Debian package: skipped, saying which, where it is missing; failed in CI."""

import pytest

from tests.helpers import SYSTEM_TESTS, needs


def test_a_missing_package_skips_the_test_saying_which(monkeypatch) -> None:
    monkeypatch.delenv(SYSTEM_TESTS, raising=False)
    with pytest.raises(pytest.skip.Exception, match="needs Debian's chromium"):
        needs(False, "the dashboard's test needs Debian's chromium")
    needs(True, "never said")  # present: the test goes on


def test_where_ci_installed_the_packages_a_missing_one_fails(monkeypatch) -> None:
    monkeypatch.setenv(SYSTEM_TESTS, "required")
    with pytest.raises(pytest.fail.Exception, match="=required"):
        needs(False, "the dashboard's test needs Debian's chromium")
