"""Uniform random sampling of the search space: the baseline any optimiser must beat."""

import numpy as np
from pymoo.core.population import Population

from gainfarm.analytic.tuning.search_space import SearchSpace


class UniformRandom:
    """The "random" algorithm: `pop_size` points drawn uniformly from the decision space every
    generation, whatever came before (ask and tell as pymoo's algorithms have them)."""

    def __init__(self, pop_size: int, seed: int, space: SearchSpace):
        self.pop_size = pop_size
        self.lower, self.upper = space.lower, space.upper
        self.random_state = np.random.default_rng(seed)
        self.pop = None  # no population: nothing for Evolution.correct to correct

    def ask(self) -> Population:
        shape = (self.pop_size, len(self.lower))
        return Population.new(X=self.random_state.uniform(self.lower, self.upper, shape))

    def tell(self, infills: Population) -> None:
        pass  # it asks the same whatever it is told

    def rank_constraints(self, count: int) -> bool:
        """Nothing to rank (Evolution.constrain): it asks the same whatever it is told."""
        return True
