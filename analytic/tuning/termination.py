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

from dataclasses import dataclass

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
            return f"{generation} generations" if generation >= self.generations else None
        if self.evaluations is not None:
            return f"{evaluations} evaluations" if evaluations >= self.evaluations else None
        if generation <= self.window:
            return None
        before, now = hypervolumes[-1 - self.window], hypervolumes[-1]
        if now > 0 and now - before <= self.tolerance * before:
            return f"converged after {evaluations} evaluations ({self.rule})"
        return None
