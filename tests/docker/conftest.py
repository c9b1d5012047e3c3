"""The e2e test runs only when asked for, with `-m e2e`, as .ci/run does after the unit tests:
it takes minutes and needs root, a container engine (it installs one) and Debian's mirror."""

import pytest

E2E = "e2e"


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", f"{E2E}: the compose farm on a real container engine; runs only with -m {E2E}"
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Deselect (and count as deselected) the e2e test unless the marker expression names it:
    `-m e2e` runs it, `-m "not e2e"` deselects it as pytest does."""
    if E2E in (config.option.markexpr or ""):
        return
    chosen = [item for item in items if item.get_closest_marker(E2E) is None]
    if len(chosen) < len(items):
        config.hook.pytest_deselected(items=[item for item in items if item not in chosen])
        items[:] = chosen
