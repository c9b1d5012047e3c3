"""Every built-in optimiser passes the conformance kit a plug-in's author runs
(gainfarm.testing.algorithms): the project's own algorithms are checked as a third party's are."""

import importlib.util

import pytest

from gainfarm import plugins
from gainfarm.testing.algorithms import AlgorithmChecks

# The algorithms that need the moea extra, and the package each needs.
NEEDS = {"agemoea2": "numba", "tpe": "optuna"}
EVERY = [
    pytest.param(
        name,
        marks=pytest.mark.skipif(
            name in NEEDS and importlib.util.find_spec(NEEDS[name]) is None,
            reason=f"needs {NEEDS.get(name)}",
        ),
    )
    for name in plugins.builtin_names(plugins.ALGORITHMS)
]


class TestEveryBuiltInAlgorithm(AlgorithmChecks):
    @pytest.fixture(name="algorithm", params=EVERY)
    def _algorithm(self, request: pytest.FixtureRequest) -> str:
        return request.param
