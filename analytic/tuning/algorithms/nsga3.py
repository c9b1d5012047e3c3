"""pymoo's NSGA-III."""

from typing import Any

import numpy as np
from pymoo.algorithms.moo.nsga3 import NSGA3
from pymoo.core.population import Population
from pymoo.operators.selection.tournament import TournamentSelection, compare

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


def _by_cv_then_random(
    pop: Population, P: np.ndarray, random_state: Any = None, **kwargs: Any
) -> np.ndarray:
    """NSGA-III's tournament, pymoo's comp_by_cv_then_random but for one thing: two infeasible
    points of equal violation are told apart by the algorithm's random state. pymoo 0.6.2's
    calls `compare` without it, which then draws from a fresh unseeded generator, so a
    constrained run was neither reproducible nor resumed identically (the conformance kit,
    gainfarm.testing.algorithms, found it). Between feasible points it draws as pymoo's does:
    an unconstrained run is unchanged. (Also, pymoo's function is wrapped by a decorator that
    pickle cannot name, and a checkpoint holds the algorithm's tournament.)"""
    winners = np.full(P.shape[0], np.nan)
    for i in range(P.shape[0]):
        a, b = P[i, 0], P[i, 1]
        if pop[a].CV > 0.0 or pop[b].CV > 0.0:
            winners[i] = compare(
                a,
                pop[a].CV,
                b,
                pop[b].CV,
                method="smaller_is_better",
                return_random_if_equal=True,
                random_state=random_state,
            )
        else:
            winners[i] = random_state.choice([a, b])
    return winners[:, None].astype(int)
