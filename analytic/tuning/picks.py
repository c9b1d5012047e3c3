"""The members of a front worth naming: the knee (the controller to use), the most accurate and
the smoothest. One rule for every reader of a run: `analytic export`, the run's report and
figure, and `analytic dataset --select knee`.

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

from gainfarm.analytic.tuning.records import FrontMember, sorted_front


@dataclass(frozen=True)
class Pick:
    """A member of a front, chosen: `name` (knee, accurate, smooth, or row), its 1-based `row`
    in front.csv, and how many members share its scores exactly (`sharing`, itself included)."""

    name: str
    row: int
    member: FrontMember
    sharing: int


def _measured(front: Sequence[FrontMember]) -> list[int]:
    """The rows a pick may be: members with finite scores that did not diverge (all of them if
    none is such: a pick is still defined, and says it diverged)."""
    good = [
        i
        for i, m in enumerate(front)
        if not m.diverged and np.isfinite(m.f_acc) and np.isfinite(m.f_t)
    ]
    return good or list(range(len(front)))


def knee_index(front: Sequence[FrontMember]) -> int:
    """The knee's index in `front` (sorted, as front.csv is): see the module's docstring."""
    rows = _measured(front)
    objectives = np.array([front[i].objectives for i in rows], dtype=float)
    points = np.log10(np.maximum(objectives, np.finfo(float).tiny))  # an exact 0 stays finite
    ideal, nadir = points.min(axis=0), points.max(axis=0)
    span = np.where(nadir > ideal, nadir - ideal, 1.0)  # one member, or all alike: all 0
    normalised = (points - ideal) / span
    values = ASF().do(normalised, weights=np.array([0.5, 0.5]))
    return rows[int(np.argmin(values))]  # argmin: the first of equals, the lowest row


def knee(front: Sequence[FrontMember]) -> FrontMember:
    """The knee of a non-empty `front`, in any order."""
    ordered = sorted_front(front)
    return ordered[knee_index(ordered)]


def pick_at(front: Sequence[FrontMember], name: str, index: int) -> Pick:
    """Member `index` of the sorted `front`, picked as `name`."""
    member = front[index]
    return Pick(name, index + 1, member, sum(1 for m in front if m.objectives == member.objectives))


def picks(front: Sequence[FrontMember]) -> list[Pick]:
    """The knee, the most accurate and the smoothest member of `front` (none if it is empty)."""
    front = sorted_front(front)
    if not front:
        return []
    rows = _measured(front)
    return [
        pick_at(front, "knee", knee_index(front)),
        pick_at(front, "accurate", rows[0]),  # sorted by f_acc, then f_t
        pick_at(front, "smooth", min(rows, key=lambda i: (front[i].f_t, i))),
    ]
