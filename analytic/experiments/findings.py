"""Findings the experiments share: how a measure moves over ascending settings (population
sizes, durations), and whether and where it levels off, in plain words."""

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from gainfarm.analytic.experiments import statistics as stats

T = TypeVar("T")


def step_comparisons(values: Mapping[T, Sequence[float]]) -> dict[tuple[T, T], stats.Comparison]:
    """Each setting against the next smaller one, in ascending order: (smaller, larger) → the
    larger's values compared with the smaller's."""
    ordered = sorted(values)
    return {
        (small, large): stats.compare(values[large], values[small])
        for small, large in itertools.pairwise(ordered)
    }


def level_from(gains: Sequence[float], ordered: Sequence[float]) -> float | None:
    """Where a measure levels off over the settings `ordered` (ascending), given the settings
    with a significant gain over the next smaller one: the largest of those (the first setting
    if there is none); None if that is the largest setting tried, where it still rises."""
    top = max(gains, default=ordered[0])
    return None if gains and top == ordered[-1] else top


@dataclass(frozen=True)
class LevelsOff:
    """Whether and where a measure levels off over ascending settings: `text` says it; `level`
    is the setting from which no consecutive step gains significantly (None when the data
    cannot say, or it still gains at the last setting: `rising`)."""

    text: str
    level: float | None
    rising: bool


def levels_off(
    steps: Mapping[tuple[Any, Any], stats.Comparison],
    reps: int,
    measure: str,
    setting: str,
    shown: Callable[[float], str] = "{:g}".format,
    higher_is_better: bool = True,
) -> LevelsOff:
    """The finding on `steps` (step_comparisons of `measure` over the values of `setting`,
    e.g. "the hypervolume" over "population size"; `shown` writes one value)."""
    if not steps:
        return LevelsOff(f"One {setting} only: nothing to compare.", None, False)
    if not all(stats.decidable(result) for result in steps.values()):
        return LevelsOff(
            f"With {reps} repetitions per {setting} the tests cannot reach p < "
            f"{stats.ALPHA:g}: cannot decide whether or where {measure} levels off; more "
            "repetitions are needed.",
            None,
            False,
        )
    ordered = sorted({value for step in steps for value in step})
    gains = [
        large
        for (_, large), result in steps.items()
        if stats.better(result, higher_is_better) == "a"
    ]
    level = level_from(gains, ordered)
    said = measure[:1].upper() + measure[1:]
    if level is None:
        text = (
            f"{said} still gains significantly at the last {setting} tried "
            f"({shown(ordered[-1])}): it does not level off within these {setting}s."
        )
    elif gains:
        text = (
            f"{said} levels off from {setting} {shown(level)} (no significant gain between "
            f"consecutive {setting}s from there on)."
        )
    else:
        text = (
            f"{said} shows no significant gain between consecutive {setting}s: it levels off "
            f"from the first, {shown(level)}."
        )
    return LevelsOff(text, level, level is None)
