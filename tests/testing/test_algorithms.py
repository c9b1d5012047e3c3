"""Every built-in optimiser passes the conformance kit a plug-in's author runs
(gainfarm.testing.algorithms): the project's own algorithms are checked as a third party's are;
and the kit fails an optimiser that breaks its rules."""

import importlib.util
from collections.abc import Callable

import numpy as np
import pytest
from pymoo.core.population import Population

from gainfarm import plugins
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.testing.algorithms import (
    AlgorithmChecks,
    check_asks_within_the_space,
    check_the_same_seed_asks_the_same,
)

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


class Unseeded:
    """An optimiser that draws from the operating system's entropy, not its seed."""

    def __init__(self, pop_size: int, seed: int, space: SearchSpace) -> None:
        self.pop_size, self.space = pop_size, space
        self.pop = None

    def ask(self) -> Population:
        rng = np.random.default_rng()
        shape = (self.pop_size, len(self.space.lower))
        return Population.new(X=rng.uniform(self.space.lower, self.space.upper, shape))

    def tell(self, infills: Population) -> None:
        pass


class Wide(Unseeded):
    """One that asks a tenth beyond the search space's bounds."""

    def ask(self) -> Population:
        x = np.tile(self.space.upper + 0.1 * (self.space.upper - self.space.lower), (4, 1))
        return Population.new(X=x)


@pytest.mark.parametrize(
    ("factory", "check"),
    [(Unseeded, check_the_same_seed_asks_the_same), (Wide, check_asks_within_the_space)],
)
def test_the_kit_fails_an_optimiser_that_ignores_its_seed_or_leaves_the_space(
    factory: type, check: Callable[[str], None]
) -> None:
    plugins.register(plugins.ALGORITHMS, "misfit", factory)
    try:
        with pytest.raises(AssertionError, match="misfit"):
            check("misfit")
    finally:
        plugins.unregister(plugins.ALGORITHMS, "misfit")
