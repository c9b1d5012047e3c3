"""One real local farm for every experiment test that runs on one."""

from collections.abc import Iterator

import pytest

from gainfarm.analytic.evaluators.local import local_farm


@pytest.fixture(scope="package")
def endpoints() -> Iterator[list[str]]:
    with local_farm(workers=2) as endpoint:
        yield [endpoint]
