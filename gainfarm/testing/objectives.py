"""The conformance kit for an objective (the gainfarm.objectives group): what gainfarm relies on
an objective for, checked on real episodes, as its own built-ins are checked.

In a plug-in's tests, subclass `ObjectiveTests` and name the objective (what its entry point
names) and the name it is installed under; pytest collects the checks:

    from gainfarm.testing.objectives import ObjectiveTests
    from mypkg.objectives import peak_torque

    class TestPeakTorque(ObjectiveTests):
        objective = peak_torque
        name = "peak_torque"

or call `check_objective(peak_torque, "peak_torque")` from a test of your own. Each check fails
with an AssertionError saying what is wrong. The checks:

    declared        an Objective (schemas/objectives/declaration.py) whose name is the one it is
                    installed under and follows the plug-in name rule (gainfarm.plugins), with
                    its unit, direction and a line for reports declared (a bare function of the
                    log still runs in a tuning, but its reports cannot say what it is)
    deterministic   the same log scores the same, bit for bit: a farm's replicas and the referee
                    compare scores exactly
    finite          a real episode's score is a finite number
    diverged worse  an episode stopped early (the arm fell) scores worse than one that finished
    no episode      the no-episode score is worse than any episode's, a diverged one's too

The episodes are real (MuJoCo, the worker's own `run_episode`), short, and simulated once per
process: a 3 s spiral tracked by stiff gains, and gains too soft to hold the arm up without the
robot's gravity compensation, which fall and are stopped early.
"""

import math
import re
from functools import cache
from typing import Any

from gainfarm import plugins
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.objectives import Objective
from gainfarm.schemas.robot import PLAIN_PLANT
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.episode import run_episode

# Stiff enough to track a spiral closely; too soft to hold the arm up on a plain torque interface.
TRACKING = PDGains(kp=(2000, 2000, 1200, 1200, 400, 200, 100), kd=(60, 60, 40, 40, 10, 5, 2))
FALLING = PDGains(kp=(5,) * 7, kd=(1,) * 7)
SECONDS = 3.0  # the spiral's shortest feasible duration is 2.6 s


@cache
def finished_log() -> EpisodeLog:
    """A real episode that ran to its end: a 3 s spiral, tracked."""
    return run_episode(EpisodeSpec(gains=TRACKING, trajectory=TrajectorySpec(duration=SECONDS)))


@cache
def diverged_log() -> EpisodeLog:
    """A real episode stopped early: the arm fell (soft gains, no gravity compensation)."""
    spec = EpisodeSpec(
        gains=FALLING, trajectory=TrajectorySpec(duration=SECONDS), plant=PLAIN_PLANT
    )
    log = run_episode(spec)
    assert log.metadata.diverged, "the kit's falling episode did not diverge: report it"
    return log


def check_declared(objective: Any, name: str) -> Objective:
    """It is an Objective, named `name` by the plug-in name rule, its unit, direction and
    description declared; returns it."""
    assert isinstance(objective, Objective), (
        f"objective {name!r} is a {type(objective).__name__}, not an Objective: declare its "
        "name, unit, direction, description and no-episode score "
        "(gainfarm.schemas.objectives.Objective)"
    )
    assert objective.name == name, (
        f"objective installed as {name!r} declares the name {objective.name!r}"
    )
    assert re.fullmatch(plugins.NAME_PATTERN, name), f"objective name {name!r}: {plugins.NAME_RULE}"
    assert objective.unit.strip(), f"objective {name!r} declares no unit ('1' if it has none)"
    assert objective.description.strip(), f"objective {name!r} declares no description"
    assert "\n" not in objective.description, f"objective {name!r}: a one-line description"
    return objective


def check_deterministic(objective: Objective, log: EpisodeLog | None = None) -> None:
    """The same log scores the same, bit for bit."""
    log = log or finished_log()
    first, second = objective(log), objective(log)
    assert first == second or (math.isnan(first) and math.isnan(second)), (
        f"objective {objective.name!r} scored one log {first!r} then {second!r}"
    )


def check_finite(objective: Objective, log: EpisodeLog | None = None) -> None:
    """A real episode's score is a finite float."""
    value = objective(log or finished_log())
    assert isinstance(value, float) and math.isfinite(value), (
        f"objective {objective.name!r} scored a real episode {value!r}: not a finite number"
    )


def check_diverged_worse(objective: Objective) -> None:
    """An episode stopped early scores worse (as the optimiser is told it) than one that
    finished."""
    finished, diverged = objective(finished_log()), objective(diverged_log())
    assert math.isfinite(diverged), f"objective {objective.name!r} scored a diverged log {diverged}"
    assert objective.minimised(diverged) > objective.minimised(finished), (
        f"objective {objective.name!r} ({objective.direction}) scores an episode stopped early "
        f"{diverged!r}, not worse than a finished one's {finished!r}: charge the ticks it did "
        "not run"
    )


def check_no_episode_worst(objective: Objective) -> None:
    """The no-episode score is worse than any episode's: the finished and the diverged one's."""
    for log in (finished_log(), diverged_log()):
        value = objective(log)
        assert objective.told_no_episode > objective.minimised(value), (
            f"objective {objective.name!r}: its no-episode score {objective.no_episode!r} is not "
            f"worse than an episode's {value!r} ({objective.direction})"
        )


def check_objective(objective: Any, name: str) -> Objective:
    """Every check of the kit, in order; returns the declaration."""
    declared = check_declared(objective, name)
    check_deterministic(declared)
    check_finite(declared)
    check_finite(declared, diverged_log())
    check_diverged_worse(declared)
    check_no_episode_worst(declared)
    return declared


class ObjectiveTests:
    """The kit as pytest tests: subclass it (a class named Test...), set `objective` (what the
    entry point names) and `name` (the entry point's name)."""

    objective: Any = None
    name: str = ""

    def _declared(self) -> Objective:
        return check_declared(self.objective, self.name)

    def test_declares_its_name_unit_direction_and_description(self) -> None:
        self._declared()

    def test_scores_a_log_the_same_every_time(self) -> None:
        check_deterministic(self._declared())

    def test_scores_a_real_episode_finite(self) -> None:
        check_finite(self._declared())
        check_finite(self._declared(), diverged_log())

    def test_scores_a_diverged_episode_worse_than_a_finished_one(self) -> None:
        check_diverged_worse(self._declared())

    def test_scores_no_episode_worse_than_any_episode(self) -> None:
        check_no_episode_worst(self._declared())
