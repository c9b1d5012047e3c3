"""The members of a front worth naming: the recommended member (the controller to use), the knee,
the most accurate and the smoothest. One rule for every reader of a run: `analytic export`, the
run's report and figure, and `analytic dataset --select knee`.

The recommended member is the knee (below) among the members that dominate the default gains as
the run scored them (baseline.json: the run's trajectories, weights and plant), that is as
accurate and as smooth as the defaults and better in one: of those, the one the knee's measure
on the whole front ranks best, so the knee itself whenever it dominates the defaults. A tuned
controller that loses to the factory gains on either objective is no recommendation, however
good a compromise it is on its own front. When no member dominates the defaults nothing is
recommended, and the member closest to dominating them is named instead: the one whose worse
objective falls least short of the defaults', as a factor (`shortfall`: the larger of
log10(f_acc / f_acc default) and log10(f_t / f_t default)). When the defaults diverged their
point is a penalty, and every member that finished its episodes beats it.

The knee is pymoo's achievement scalarisation function (ASF) with equal weights on the front
normalised between its own ideal and nadir points: the member whose worse normalised objective
is the least bad, the point where neither objective is given up for the other. Both objectives
enter on a log scale: a front spans decades in each (a chattering member's f_t is 10²-10⁴ times
a smooth one's; the softest members' error 20 times the stiffest's), and what a user trades is
factors, not differences. On linear scales the extremes decide: one chattering member puts
every other at f_t ≈ 0 and pulls the knee towards it.

pymoo's other rules do not fit: HighTradeoffPoints returns a set (often empty, undefined on
fronts of one or two members), pseudo-weights divide by zero on a one-member front, and its
CompromiseProgramming returns nothing (pymoo 0.6). The ASF is defined for any front; ties go to
the lowest row of front.csv (the more accurate member). Members whose episodes diverged carry a
penalty, not a measurement: no pick is one of them unless every member is.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pymoo.decomposition.asf import ASF

from gainfarm.analytic.tuning.records import Baseline, FrontMember, sorted_front
from gainfarm.schemas.gains import PDGains


@dataclass(frozen=True)
class Advice:
    """What the held-out check (analytic.tuning.check) advises: the gains of the member that
    holds on the held-out plants, or None: keep the default gains."""

    gains: PDGains | None


@dataclass(frozen=True)
class Pick:
    """A member of a front, chosen: `name` (recommended, closest, knee, accurate, smooth, or
    row), its 1-based `row` in front.csv, and how many members share its scores exactly
    (`sharing`, itself included)."""

    name: str
    row: int
    member: FrontMember
    sharing: int


def _finished(front: Sequence[FrontMember]) -> list[int]:
    """The members with finite scores that did not diverge: measured, not a penalty."""
    return [i for i, m in enumerate(front) if not m.diverged and np.all(np.isfinite(m.objectives))]


def _measured(front: Sequence[FrontMember]) -> list[int]:
    """The rows a pick may be: the finished members (all of them if none finished: a pick is
    still defined, and says it diverged)."""
    return _finished(front) or list(range(len(front)))


def knee_index(front: Sequence[FrontMember]) -> int:
    """The knee's index in `front` (sorted, as front.csv is): see the module's docstring."""
    rows = _measured(front)
    return rows[int(np.argmin(_asf(front, rows)))]  # argmin: the first of equals, the lowest row


def _log(objectives: Sequence[float]) -> np.ndarray:
    return np.log10(np.maximum(np.asarray(objectives, dtype=float), np.finfo(float).tiny))


def _asf(front: Sequence[FrontMember], rows: Sequence[int]) -> np.ndarray:
    """The knee's measure of each member of `front` at `rows` (non-empty): the ASF on log scales
    normalised between those members' ideal and nadir points. The knee is its least."""
    objectives = np.array([front[i].objectives for i in rows], dtype=float)
    points = _log(objectives)  # an exact 0 stays finite
    ideal, nadir = points.min(axis=0), points.max(axis=0)
    span = np.where(nadir > ideal, nadir - ideal, 1.0)  # one member, or all alike: all 0
    normalised = (points - ideal) / span
    return ASF().do(normalised, weights=np.array([0.5, 0.5]))


def dominates(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """`a` is as good as `b` in both objectives (both minimised) and better in one."""
    return a[0] <= b[0] and a[1] <= b[1] and a != b


def dominating(front: Sequence[FrontMember], baseline: Baseline) -> list[int]:
    """The indices in the sorted `front` of the finished members that dominate the default
    gains (`baseline`): every finished member if the defaults diverged."""
    finished = _finished(front)
    if baseline.diverged:
        return finished
    return [i for i in finished if dominates(front[i].objectives, baseline.objectives)]


def ranked_dominating(front: Sequence[FrontMember], baseline: Baseline) -> list[int]:
    """The indices in the sorted `front` of the members that dominate the default gains, in the
    knee's order (its measure, ties to the lowest row): the candidates to recommend."""
    rows = dominating(front, baseline)
    if not rows:
        return []
    measured = _measured(front)
    ranked = dict(zip(measured, _asf(front, measured), strict=True))
    return sorted(rows, key=lambda i: (ranked[i], i))


def recommended_index(
    front: Sequence[FrontMember], baseline: Baseline, advice: "Advice | None" = None
) -> int | None:
    """The recommended member's index in the sorted `front`: the one the held-out check's
    `advice` names, if there is advice (None: it found none that holds); without advice, of
    the members that dominate the default gains, the one the knee's measure ranks best (ties
    to the lowest row); None if none dominates them."""
    if advice is not None:
        if advice.gains is None:
            return None
        same = [i for i, m in enumerate(front) if m.gains == advice.gains]
        return same[0] if same else None
    rows = ranked_dominating(front, baseline)
    return rows[0] if rows else None


def shortfall(member: FrontMember | Baseline, baseline: Baseline) -> float:
    """How far `member` is from dominating the default gains: the larger of its objectives' log10
    ratios to theirs (0.1: its worse objective is 26 % worse than the defaults'; ≤ 0: as good in
    both)."""
    return float(np.max(_log(member.objectives) - _log(baseline.objectives)))


def closest_index(front: Sequence[FrontMember], baseline: Baseline) -> int:
    """The index in the sorted, non-empty `front` of the member closest to dominating the
    default gains: the least `shortfall`, ties to the lowest row."""
    return min(_measured(front), key=lambda i: (shortfall(front[i], baseline), i))


def knee(front: Sequence[FrontMember]) -> FrontMember:
    """The knee of a non-empty `front`, in any order."""
    ordered = sorted_front(front)
    return ordered[knee_index(ordered)]


def pick_at(front: Sequence[FrontMember], name: str, index: int) -> Pick:
    """Member `index` of the sorted `front`, picked as `name`."""
    member = front[index]
    return Pick(name, index + 1, member, sum(1 for m in front if m.objectives == member.objectives))


def picks(
    front: Sequence[FrontMember], baseline: Baseline | None = None, advice: Advice | None = None
) -> list[Pick]:
    """The members of `front` worth naming (none if it is empty): given the default gains'
    `baseline`, first the recommended member (the held-out check's `advice`, if it gave one),
    or the closest to dominating the defaults if none is; then the knee, the most accurate and
    the smoothest."""
    front = sorted_front(front)
    if not front:
        return []
    rows = _measured(front)
    first = []
    if baseline is not None:
        recommended = recommended_index(front, baseline, advice)
        first = [
            pick_at(front, "closest", closest_index(front, baseline))
            if recommended is None
            else pick_at(front, "recommended", recommended)
        ]
    return [
        *first,
        pick_at(front, "knee", knee_index(front)),
        pick_at(front, "accurate", rows[0]),  # sorted by the first objective, then the second
        pick_at(front, "smooth", min(rows, key=lambda i: (front[i].objectives[1], i))),
    ]
