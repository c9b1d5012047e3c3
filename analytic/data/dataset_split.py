"""A dataset's split into train, validation and test, by trajectory: the fractions checked, each
part's count of trajectories, and which trajectory goes where (deterministic, by hash). Pure."""

import hashlib
import math
from collections.abc import Sequence

from gainfarm.analytic.data.loader import SPLITS

Split = tuple[float, float, float]

DEFAULT_SPLIT: Split = (0.6, 0.2, 0.2)


class BadSplit(ValueError):
    """The split's fractions, or too few trajectories for its non-empty parts."""


def check_split(fractions: Sequence[float]) -> Split:
    """Three non-negative fractions summing to 1 (train, validation, test)."""
    values = tuple(float(value) for value in fractions)
    if (
        len(values) != 3
        or not all(math.isfinite(value) and value >= 0 for value in values)
        or not math.isclose(sum(values), 1.0, abs_tol=1e-9)
    ):
        shown = ",".join(f"{value:g}" for value in values)
        raise BadSplit(
            f"expected three non-negative fractions (train,validation,test) summing to 1, "
            f"got {shown}"
        )
    return values  # type: ignore[return-value]  # three, checked above


def split_counts(fractions: Split, trajectories: int) -> list[int]:
    """How many trajectories each part gets: the largest-remainder rounding of its share, then
    every part with a positive fraction at least one, taken from the largest part."""
    fractions = check_split(fractions)
    positive = [index for index, value in enumerate(fractions) if value > 0]
    if len(positive) > trajectories:
        names = "/".join(SPLITS[index] for index in positive)
        example = "1,0,0" if trajectories <= 1 else "0.5,0,0.5"
        raise BadSplit(
            f"{len(positive)} non-empty parts ({names}) but the dataset has only {trajectories} "
            f"trajector{'y' if trajectories == 1 else 'ies'}: give the empty parts 0 "
            f"(e.g. {example}), or add trajectories with --rerun"
        )
    total = sum(fractions)
    exact = [value / total * trajectories for value in fractions]
    counts = [math.floor(value) for value in exact]
    leftover = trajectories - sum(counts)
    by_remainder = sorted(positive, key=lambda index: (counts[index] - exact[index], index))
    for index in by_remainder[:leftover]:
        counts[index] += 1
    for index in positive:
        if counts[index] == 0:  # some other part has two or more: there are enough trajectories
            donor = max(range(3), key=lambda other: (counts[other], -other))
            counts[donor] -= 1
            counts[index] += 1
    return counts


def assign_splits(ids: Sequence[str], fractions: Split, seed: int = 0) -> dict[str, str]:
    """trajectory_id → split. Deterministic: the ids in the order of their hash with `seed`,
    cut by `split_counts`; so the split does not depend on the order the runs were given in."""
    unique = sorted(set(ids))
    counts = split_counts(fractions, len(unique))
    order = sorted(unique, key=lambda tid: hashlib.sha256(f"{seed}:{tid}".encode()).hexdigest())
    names = [name for name, count in zip(SPLITS, counts, strict=True) for _ in range(count)]
    return dict(zip(order, names, strict=True))
