"""When a run stops: after N generations, after N evaluations, or when it has converged.

Convergence is the default: the hypervolume has grown by less than `tolerance` (relative) over
the last `window` generations. The hypervolume of an elitist front never falls, so the test is a
plain comparison with the value `window` generations ago.
"""

from dataclasses import dataclass

CONVERGENCE_TOLERANCE = 0.005  # 0.5 % relative hypervolume gain ...
CONVERGENCE_WINDOW = 5  # ... over this many generations


@dataclass(frozen=True)
class Termination:
    generations: int | None = None
    evaluations: int | None = None
    tolerance: float = CONVERGENCE_TOLERANCE
    window: int = CONVERGENCE_WINDOW

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
            return (
                f"converged after {evaluations} evaluations (hypervolume gain below "
                f"{self.tolerance:.1%} over {self.window} generations)"
            )
        return None
