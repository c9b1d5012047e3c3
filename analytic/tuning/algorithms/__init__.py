"""The built-in optimisers, one module each, registered as a third party's are: by entry points
of the gainfarm.algorithms group (pyproject.toml), each a factory(pop_size, seed, space) that
returns an ask and tell object (analytic.tuning.evolution.Optimiser).

    nsga2      pymoo's NSGA-II, the default (and its steady state, mu + 1)
    nsga3      pymoo's NSGA-III
    smsemoa    pymoo's SMS-EMOA
    moead      pymoo's MOEA/D, the parallel variant
    agemoea2   pymoo's AGE-MOEA-II (numba)
    tpe        Optuna's multi-objective TPE (and its steady state, one trial at a time)
    random     uniform random sampling, the baseline
    common     what pymoo's share: the gain problem, the set-up, the reference directions

This module imports neither pymoo nor SciPy: what a run's configuration needs to know of the
optimisers (which have a steady state) is here, so that a config is checked without them.
"""

# The algorithms with a steady-state variant (ask one candidate as another is told): NSGA-II's
# (mu + 1) and TPE's (one trial at a time, as Optuna runs it). Their factories take
# `steady_state=True`.
STEADY_STATE = ("nsga2", "tpe")


def steady_state_refusal(algorithm: str) -> str:
    """Why a steady-state run of `algorithm` is refused, in one line naming the way out."""
    which = " or ".join(STEADY_STATE)
    return (
        f"steady state (asynchronous, --async) is {which}'s only, not {algorithm}'s: "
        f"choose algorithm {which}, or drop --async to run {algorithm} generationally"
    )
