"""pymoo's NSGA-II, the default optimiser."""

from pymoo.algorithms.moo.nsga2 import NSGA2

from gainfarm.analytic.tuning.algorithms.common import set_up
from gainfarm.analytic.tuning.search_space import SearchSpace


def nsga2(pop_size: int, seed: int, space: SearchSpace, steady_state: bool = False) -> NSGA2:
    """pymoo's NSGA-II; steady state (mu + 1) asks one offspring at a time."""
    method = NSGA2(
        pop_size=pop_size, n_offsprings=1 if steady_state else None, eliminate_duplicates=True
    )
    return set_up(method, seed, space)
