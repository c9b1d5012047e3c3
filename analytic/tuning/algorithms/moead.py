"""pymoo's MOEA/D, the parallel variant (its module brings scipy.spatial, a third of a second:
loaded only when a run names it)."""

from typing import Any

from pymoo.algorithms.moo.moead import ParallelMOEAD

from gainfarm.analytic.tuning.algorithms.common import reference_directions, set_up
from gainfarm.analytic.tuning.search_space import SearchSpace


def moead(pop_size: int, seed: int, space: SearchSpace) -> Any:
    """pymoo's MOEA/D, the parallel variant: a whole generation asked at once."""
    return set_up(ParallelMOEAD(ref_dirs=reference_directions(pop_size)), seed, space)
