"""When a run stops: after N generations, after N evaluations, or when it has converged.

Convergence is the default: the hypervolume has grown by less than `tolerance` (relative) over
the last `window` generations. The hypervolume of an elitist front never falls, so the test is a
plain comparison with the value `window` generations ago.

The run's hypervolume is taken in a fixed, wide box (analytic.evolution.REFERENCE_POINT), where a
gain that matters looks small. So the rule is set against the hypervolume an experiment compares
runs by (normalised between the pooled fronts' ideal and nadir: analytic.experiments.Normalisation),
measured on 10 NSGA-II runs (population 30, 5 s spiral, realistic plant, seeds 0-9) carried to
1,500 evaluations (`analytic experiment algorithms --algorithms nsga2 --reps 10 --evaluations
1500`). The former rule, 0.5 % over 5 generations, stopped them after a median of 435
evaluations, with 0.043 of that hypervolume still to come by 1,500 (11 times the spread between
the seeds' final values, interquartile range 0.0038; the best error still fell from 6.2 to
5.4 mm). 0.25 % over 10 generations stops them after a median of 1,140 evaluations, with 0.0044
to come (about that spread; best error 5.5 mm). The hypervolume never stops climbing outright (an
elitist archive only gains, so a paired test finds the later value higher after any stop): the
rule's standard is that what is left is no more than what another seed would change.
"""

import warnings
from dataclasses import dataclass

import numpy as np

from gainfarm.cli.words import counted

CONVERGENCE_TOLERANCE = 0.0025  # 0.25 % relative hypervolume gain ...
CONVERGENCE_WINDOW = 10  # ... over this many generations


@dataclass(frozen=True)
class Termination:
    generations: int | None = None
    evaluations: int | None = None
    tolerance: float = CONVERGENCE_TOLERANCE
    window: int = CONVERGENCE_WINDOW

    @property
    def rule(self) -> str:
        """The convergence rule in words: 'hypervolume gain below 0.25% over 10 generations'."""
        return f"hypervolume gain below {self.tolerance * 100:g}% over {self.window} generations"

    def reason(self, hypervolumes: list[float], evaluations: int) -> str | None:
        """Why to stop after these generations' hypervolumes, or None to go on."""
        generation = len(hypervolumes)
        if self.generations is not None:
            return counted(generation, "generation") if generation >= self.generations else None
        if self.evaluations is not None:
            return counted(evaluations, "evaluation") if evaluations >= self.evaluations else None
        if generation <= self.window:
            return None
        before, now = hypervolumes[-1 - self.window], hypervolumes[-1]
        if now > 0 and now - before <= self.tolerance * before:
            return f"converged after {evaluations} evaluations ({self.rule})"
        return None


# The convergence estimate. The hypervolume of a run that converges rises ever more slowly; its
# course so far is fitted as h(g) = H − A·exp(−k·g) (least squares, SciPy), continued from the
# last generation on, and the rule is applied to the continued course: the first generation it
# would stop at is the estimate. Not before ESTIMATE_AFTER generations (a fit of 3 parameters
# needs some), nor beyond ESTIMATE_HORIZON generations from now (a course that flat says little).
ESTIMATE_AFTER = 5
ESTIMATE_HORIZON = 500


def expected_generations(termination: Termination, hypervolumes: list[float]) -> int | None:
    """The generation at which `termination`'s convergence rule is expected to stop a run whose
    generations so far had `hypervolumes`; None for a run with a budget (whose end is known),
    too few generations, no growth to fit, or a fit that does not converge."""
    # start-up: SciPy stays off `from gainfarm import RunConfig`, which reads the termination
    from scipy.optimize import OptimizeWarning, curve_fit

    if termination.generations is not None or termination.evaluations is not None:
        return None
    h = np.asarray(hypervolumes, dtype=float)
    if len(h) < ESTIMATE_AFTER or not np.all(np.isfinite(h)) or h[-1] <= 0:
        return None
    if termination.reason(list(h), 0) is not None:
        return len(h)  # the rule stops it now
    g = np.arange(1, len(h) + 1, dtype=float)

    def course(g: np.ndarray, top: float, gap: float, rate: float) -> np.ndarray:
        return top - gap * np.exp(-rate * g)

    rise = max(h[-1] - h[0], 1e-12)
    try:
        # A course with flat stretches leaves the fit's covariance unknown, which SciPy warns of
        # on stderr (through a run's live line); only the fitted values are used here.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimizeWarning)
            (top, gap, rate), _ = curve_fit(
                course,
                g,
                h,
                p0=(h[-1] + 0.1 * rise, rise, 0.1),
                bounds=((h[-1], 0.0, 1e-4), (np.inf, np.inf, 10.0)),
                maxfev=2000,
            )
    except (RuntimeError, ValueError):  # no fit found
        return None
    later = np.arange(len(h) + 1, len(h) + ESTIMATE_HORIZON + 1, dtype=float)
    # Continued from the last generation: its value, and the fit's rise from there on.
    ahead = h[-1] + course(later, top, gap, rate) - course(np.array([g[-1]]), top, gap, rate)[0]
    whole = np.concatenate([h, ahead])
    for end in range(max(len(h), termination.window) + 1, len(whole) + 1):  # the rule's first
        before, now = whole[end - 1 - termination.window], whole[end - 1]
        if now - before <= termination.tolerance * before:
            return end
    return None
