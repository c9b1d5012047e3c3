"""pymoo's NSGA-III."""

from typing import Any

import numpy as np
from pymoo.algorithms.moo.nsga3 import NSGA3, comp_by_cv_then_random
from pymoo.core.population import Population
from pymoo.operators.selection.tournament import TournamentSelection

from gainfarm.analytic.tuning.algorithms.common import reference_directions, set_up
from gainfarm.analytic.tuning.search_space import SearchSpace


def nsga3(pop_size: int, seed: int, space: SearchSpace) -> NSGA3:
    """pymoo's NSGA-III on reference_directions(pop_size)."""
    method = NSGA3(
        ref_dirs=reference_directions(pop_size),
        pop_size=pop_size,
        selection=TournamentSelection(func_comp=_by_cv_then_random),
    )
    return set_up(method, seed, space)


def _by_cv_then_random(pop: Population, P: np.ndarray, **kwargs: Any) -> np.ndarray:
    """NSGA-III's tournament: pymoo's own function is wrapped by a decorator that pickle cannot
    name (a checkpoint holds the algorithm), so the algorithm holds this, which calls it."""
    return comp_by_cv_then_random(pop, P, **kwargs)
