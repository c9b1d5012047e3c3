"""pymoo's SMS-EMOA."""

from typing import Any

import numpy as np
from pymoo.algorithms.moo.sms import SMSEMOA, cv_and_dom_tournament
from pymoo.core.population import Population
from pymoo.operators.selection.tournament import TournamentSelection

from gainfarm.analytic.tuning.algorithms.common import set_up
from gainfarm.analytic.tuning.search_space import SearchSpace


def smsemoa(pop_size: int, seed: int, space: SearchSpace) -> SMSEMOA:
    """pymoo's SMS-EMOA, generational: pop offspring, then the least contributors go."""
    method = SMSEMOA(
        pop_size=pop_size, selection=TournamentSelection(func_comp=_by_cv_and_domination)
    )
    return set_up(method, seed, space)


def _by_cv_and_domination(pop: Population, P: np.ndarray, **kwargs: Any) -> np.ndarray:
    """SMS-EMOA's tournament, for the same reason."""
    return cv_and_dom_tournament(pop, P, **kwargs)
