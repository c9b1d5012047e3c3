"""The normalised space an experiment's findings are taken in, one per problem (one trajectory the
fronts are judged on), and the measures of fronts in it.

Between the ideal and the nadir point of the pooled non-dominated front of every front the
experiment judged on that problem, f_acc linearly and f_t on a log scale (as
analytic.tuning.evolution.normalise does), against the reference point 1.1 × (nadir − ideal)
beyond the ideal, a hypervolume is a fraction of that box. Penalty points (NO_EPISODE, a
diverged episode, any point with a mean error of DIVERGED_TICK_ERROR or more) never set the ideal
or the nadir, so the values spread over the range where the controllers really differ.
normalisation.json records the ideal and the nadir of each problem.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pymoo.indicators.hv import HV

from gainfarm.analytic.tuning.evolution import F_T_FLOOR, REFERENCE_POINT, non_dominated_indices
from gainfarm.analytic.tuning.records import RunRecord
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR, NO_EPISODE

MARGIN = 0.1  # the reference point lies this fraction of (nadir - ideal) beyond the nadir
NORMALISATION_JSON = "normalisation.json"

Point = tuple[float, float]


def is_penalty(point: Point, penalised: frozenset[Point] | set[Point] = frozenset()) -> bool:
    """A penalty rather than a measured controller: no episode, a diverged one (`penalised`), a
    mean error no finished episode reaches, or a non-finite value."""
    return (
        point == NO_EPISODE
        or point in penalised
        or not (math.isfinite(point[0]) and math.isfinite(point[1]))
        or point[0] >= DIVERGED_TICK_ERROR
    )


@dataclass(frozen=True)
class Normalisation:
    """The normalised objective space of one problem: ideal → 0, nadir → 1 (f_t on a log
    scale, floored at F_T_FLOOR)."""

    ideal: Point
    nadir: Point

    @classmethod
    def of(
        cls,
        point_sets: Sequence[Sequence[Point]],
        penalised: frozenset[Point] | set[Point] = frozenset(),
    ) -> "Normalisation":
        """Between the ideal and the nadir of the pooled non-dominated front of `point_sets`,
        penalty points left out; the fixed REFERENCE_POINT box if no point is left."""
        pooled = [p for points in point_sets for p in points if not is_penalty(p, penalised)]
        if not pooled:
            return cls(ideal=(0.0, F_T_FLOOR), nadir=REFERENCE_POINT)
        front = np.asarray(non_dominated(pooled), dtype=float)
        ideal, nadir = front.min(axis=0), front.max(axis=0)
        return cls(
            ideal=(float(ideal[0]), float(ideal[1])), nadir=(float(nadir[0]), float(nadir[1]))
        )

    def normalise(self, points: Sequence[Point]) -> np.ndarray:
        f = np.asarray(points, dtype=float).reshape(-1, 2)
        span_acc = self.nadir[0] - self.ideal[0]
        f_acc = (f[:, 0] - self.ideal[0]) / (span_acc if span_acc > 0 else 1.0)
        low, high = (np.log(max(v, F_T_FLOOR)) for v in (self.ideal[1], self.nadir[1]))
        span_t = high - low
        f_t = (np.log(np.maximum(f[:, 1], F_T_FLOOR)) - low) / (span_t if span_t > 0 else 1.0)
        return np.column_stack([f_acc, f_t])

    def hypervolume(self, points: Sequence[Point]) -> float:
        """The share of the box from the ideal to the reference point that `points` dominate."""
        finite = [p for p in points if math.isfinite(p[0]) and math.isfinite(p[1])]
        if not finite:
            return 0.0
        reference = np.full(2, 1.0 + MARGIN)
        return float(HV(ref_point=reference)(self.normalise(finite))) / float(reference.prod())

    def as_dict(self) -> dict[str, list[float]]:
        return {"ideal": list(self.ideal), "nadir": list(self.nadir)}


def non_dominated(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    return [points[index] for index in non_dominated_indices(np.asarray(points).reshape(-1, 2))]


def front_points(record: RunRecord) -> list[tuple[float, float]]:
    return [member.objectives for member in record.front]


def dominated_count(points: Sequence[Point], by: Sequence[Point]) -> int:
    """How many of `points` some point of `by` dominates (no worse in both, better in one)."""
    return sum(
        any(q[0] <= p[0] and q[1] <= p[1] and (q[0] < p[0] or q[1] < p[1]) for q in by)
        for p in points
    )
