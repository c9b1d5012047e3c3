"""The objectives' conformance kit catches what it promises to, on real episodes; a maximised
objective passes it."""

import dataclasses
import itertools

import numpy as np
import pytest

from gainfarm.schemas.objectives import MAXIMISE, MINIMISE, Objective, declared
from gainfarm.testing.objectives import (
    ObjectiveTests,
    check_declared,
    check_deterministic,
    check_diverged_worse,
    check_finite,
    check_no_episode_worst,
    check_objective,
    diverged_log,
    finished_log,
)


def share_run(log: object) -> float:
    """The share of its planned ticks the episode ran: 1 for a finished one, less if not."""
    return log.ticks / log.metadata.ticks_planned  # type: ignore[attr-defined]


# Maximised: a diverged episode runs a smaller share, which is worse.
COMPLETION = Objective(
    name="completion",
    unit="1",
    direction=MAXIMISE,
    description="share of the planned ticks run",
    no_episode=-1.0,
    function=share_run,
)


class TestAMaximisedObjective(ObjectiveTests):
    objective = COMPLETION
    name = "completion"


def test_the_falling_episode_diverged_and_the_tracked_one_finished() -> None:
    assert diverged_log().metadata.diverged and not finished_log().metadata.diverged
    assert diverged_log().ticks < diverged_log().metadata.ticks_planned


def test_a_bare_function_runs_but_is_not_declared() -> None:
    bare = declared(share_run, "completion")
    assert (bare.unit, bare.direction) == ("", MINIMISE) and "not declared" in bare.description
    with pytest.raises(AssertionError, match="not an Objective: declare its name, unit"):
        check_declared(share_run, "completion")


@pytest.mark.parametrize(
    ("change", "name", "refusal"),
    [
        ({}, "other", "installed as 'other' declares the name 'completion'"),
        ({"unit": " "}, "completion", "declares no unit"),
        ({"description": "two\nlines"}, "completion", "a one-line description"),
    ],
)
def test_a_declaration_short_of_the_rule_is_refused(change: dict, name: str, refusal: str) -> None:
    with pytest.raises(AssertionError, match=refusal):
        check_declared(dataclasses.replace(COMPLETION, **change), name)


def test_an_objective_that_scores_one_log_two_ways_is_caught() -> None:
    counter = itertools.count()
    drifting = dataclasses.replace(COMPLETION, function=lambda log: float(next(counter)))
    with pytest.raises(AssertionError, match=r"scored one log 0\.0 then 1\.0"):
        check_deterministic(drifting)


def test_an_objective_not_finite_on_a_real_episode_is_caught() -> None:
    nan = dataclasses.replace(COMPLETION, function=lambda log: float(np.nan))
    with pytest.raises(AssertionError, match="not a finite number"):
        check_finite(nan)


def test_an_objective_that_prefers_a_diverged_episode_is_caught() -> None:
    # The same share, minimised: a fallen arm's shorter episode would look better.
    backwards = dataclasses.replace(COMPLETION, direction=MINIMISE, no_episode=2.0)
    with pytest.raises(AssertionError, match="not worse than a finished one's"):
        check_diverged_worse(backwards)
    with pytest.raises(AssertionError, match="not worse than a finished one's"):
        check_objective(backwards, "completion")


def test_a_no_episode_score_within_the_episodes_is_caught() -> None:
    lenient = dataclasses.replace(COMPLETION, no_episode=0.5)  # a finished episode scores 1
    with pytest.raises(AssertionError, match=r"no-episode score 0\.5 is not worse"):
        check_no_episode_worst(lenient)
