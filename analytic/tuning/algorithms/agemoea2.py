"""pymoo's AGE-MOEA-II (it compiles with numba, the moea extra)."""

from typing import Any

from gainfarm.analytic.tuning.algorithms.common import set_up
from gainfarm.analytic.tuning.search_space import SearchSpace


def agemoea2(pop_size: int, seed: int, space: SearchSpace) -> Any:
    """pymoo's AGE-MOEA-II (it compiles with numba: a ValueError without it)."""
    try:  # optional extra: numba (moea), which pymoo's module compiles with as it loads
        from pymoo.algorithms.moo.age2 import AGEMOEA2
    except Exception:  # pymoo raises a bare Exception when numba is missing
        raise ValueError("algorithm agemoea2 needs numba: pip install numba") from None
    return set_up(AGEMOEA2(pop_size=pop_size), seed, space)
