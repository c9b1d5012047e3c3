"""What the built-in pymoo algorithms share: the gain problem they are set up on, the set-up
itself, and the reference directions NSGA-III and MOEA/D spread on."""

from typing import Any

import numpy as np
from pymoo.core.problem import Problem
from pymoo.core.termination import NoTermination
from pymoo.util.ref_dirs import get_reference_directions

from gainfarm.analytic.tuning.search_space import SearchSpace


class GainProblem(Problem):
    """The decision space for pymoo; evaluation happens outside, through ask and tell."""

    def __init__(self, space: SearchSpace):
        super().__init__(n_var=len(space.lower), n_obj=2, xl=space.lower, xu=space.upper)


def set_up(method: Any, seed: int, space: SearchSpace) -> Any:
    # The run terminates itself (analytic.termination): pymoo's default criteria, updated on
    # every tell, were a quarter of a steady-state run's CPU, and decide nothing that is asked.
    method.termination = NoTermination()
    method.setup(GainProblem(space), seed=seed, verbose=False)
    return method


def reference_directions(pop_size: int) -> np.ndarray:
    """NSGA-III's and MOEA/D's reference directions: pop_size evenly spread on the 2-objective
    simplex (Das and Dennis, pop_size - 1 partitions), so that the population is the config's."""
    return get_reference_directions("das-dennis", 2, n_partitions=pop_size - 1)
