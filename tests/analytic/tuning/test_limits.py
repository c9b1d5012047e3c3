"""Safety limits as constraints of a run: infeasible candidates never reach the front, the
records, the report, an export or a dataset; `--limits FILE` decides which are."""

import json
import pickle
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.tuning.checkpoint import decode, encode
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import ALGORITHMS, Evolution
from gainfarm.analytic.tuning.records import REPORT_MD, read_front_json, read_run
from gainfarm.analytic.tuning.run import CHECKPOINT, TuningRun
from gainfarm.analytic.view.export import BadRun, controller
from gainfarm.analytic.view.run_report import write_run_report
from gainfarm.cli.values import limits_from
from gainfarm.schemas import EpisodeSpec, Scores, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.limits import MEASURED, MEASURES, Limits, measures, tally
from gainfarm.schemas.objectives import score
from gainfarm.schemas.robot import IDEAL_PLANT
from gainfarm.worker.episode import run_episode
from tests.analytic.toy import toy_scores
from tests.analytic.tuning.test_run_directory import one_error_line
from tests.helpers import analytic

TINY = RunConfig(
    pop=6, seed=7, trajectories=(TrajectorySpec(kind="fourier", duration=0.5),), generations=4
)
# The limits decide a front whatever searched it; uniform random sampling reaches the stiff,
# chattering and the under-damped corners of the toy in a few generations, where NSGA-II,
# starting from the default gains, stays near them.
SAMPLED = TINY.model_copy(update={"algorithm": "random"})


def rough_toy(spec: EpisodeSpec) -> Scores:
    """The toy's scores, with chatter growing with stiffness, as a real arm's does: the
    stiffer, the more accurate (the toy's own trade) and the rougher its command; over the
    limit once a joint is 1.4 times as stiff as the default gains make it."""
    kp = float(np.max(np.array(spec.gains.kp) / np.array(DEFAULT_GAINS.kp)))
    return toy_scores(spec).model_copy(update={"chatter": 0.01 * kp**2})


def damped_toy(spec: EpisodeSpec) -> Scores:
    """The rough toy, its closed loop the less damped the more damping its gains ask for (as a
    differenced velocity read a tick late makes a real arm's: worker.stability): unstable once
    a joint's Kd is 3 times the default gains'."""
    kd = float(np.max(np.array(spec.gains.kd) / np.array(DEFAULT_GAINS.kd)))
    return rough_toy(spec).model_copy(update={"damping": round(0.03 - 0.01 * kd, 6)})


def tuned(
    directory: Path, config: RunConfig = TINY, scorer: Callable[[EpisodeSpec], Scores] = rough_toy
) -> TuningRun:
    with TuningRun.create(directory, config) as run:
        run.run(InProcessEvaluator(scorer=scorer))
        write_run_report(run)
    return run


# --- real episodes: the optimiser never keeps a chattering candidate on its front --------------


@pytest.fixture(scope="module")
def real() -> dict[str, Scores]:
    """A chattering controller (the top of the search space, as accurate as the defaults) and a
    smooth, soft one (far less accurate), on the ideal plant's real episodes. The soft one is
    half the default stiffness: at 0.3 of it (and half the damping) its wrist overshoots this
    fast path to 1.17 times the data sheet's speed and lags 91 mrad, beyond the limits."""
    gains = {
        "chattering": PDGains(
            kp=tuple(3 * k for k in DEFAULT_GAINS.kp), kd=tuple(5 * k for k in DEFAULT_GAINS.kd)
        ),
        "soft": PDGains(
            kp=tuple(0.5 * k for k in DEFAULT_GAINS.kp), kd=tuple(1.0 * k for k in DEFAULT_GAINS.kd)
        ),
    }
    path = TrajectorySpec(kind="fourier", duration=1.5)
    return {
        name: score(run_episode(EpisodeSpec(gains=g, trajectory=path, plant=IDEAL_PLANT)))
        for name, g in gains.items()
    }


@pytest.mark.parametrize(
    "algorithm",
    # AGE-MOEA-II compiles with numba on first use: 10 s.
    [pytest.param(a, marks=pytest.mark.slow) if a == "agemoea2" else a for a in ALGORITHMS],
)
def test_a_chattering_candidate_is_on_no_front_whatever_the_optimiser(
    real: dict[str, Scores], algorithm: str
) -> None:
    rough, soft = real["chattering"], real["soft"]
    assert rough.f_acc < soft.f_acc and rough.f_t > soft.f_t  # unconstrained: both on the front
    limits = Limits()
    told = {
        "chattering": ((rough.f_acc, rough.f_t), limits.constraints(measures([rough]))),
        "soft": ((soft.f_acc, soft.f_t), limits.constraints(measures([soft]))),
    }
    for constrained in (False, True):
        evolution = Evolution(
            4, 1, algorithm=algorithm, constraints=limits.count if constrained else 0
        )
        for _ in range(2):  # and once more after a checkpoint's round trip
            asked = evolution.ask()
            names = ["chattering", "soft"] * (len(asked) // 2)
            evolution.tell(
                [told[name][0] for name in names],
                [told[name][1] for name in names] if constrained else None,
            )
            evolution = pickle.loads(pickle.dumps(evolution))
        on_front = {member.objectives for member in evolution.front()}
        if constrained:
            assert on_front == {told["soft"][0]}
            assert evolution.infeasible == evolution.evaluations // 2
        else:
            assert on_front == {told["soft"][0], told["chattering"][0]}


# --- a run ----------------------------------------------------------------------------------


def test_an_infeasible_candidate_is_on_no_front_and_the_run_says_how_many_and_why(
    tmp_path: Path,
) -> None:
    run = tuned(tmp_path / "run")
    record = read_run(run.directory)
    infeasible, why = tally(run.config.limits, record.measured)
    assert len(record.measured) == len(record.evaluated) == run.state.evolution.evaluations
    assert infeasible > 0 and why["chatter"] == infeasible  # the toy breaks chatter alone
    front = read_front_json(run.directory / "front.json")
    assert front and all(not run.config.limits.violated(m.measures) for m in front)
    lines = (run.directory / "evaluated.csv").read_text().splitlines()
    assert lines[0].split(",") == ["f_acc", "f_t", *MEASURED, "feasible"]
    assert sum(line.endswith(",false") for line in lines[1:]) == infeasible
    report = (run.directory / REPORT_MD).read_text()
    assert f"{infeasible} of {len(lines) - 1} candidates broke a safety limit (chatter " in report
    exported = controller(run.directory, "knee")  # the toy run scored no baseline
    assert exported.limits == run.config.limits
    assert exported.member.measures is not None
    assert exported.member.measures["chatter"] <= run.config.limits.chatter


def test_limits_from_the_config_decide_the_front(tmp_path: Path) -> None:
    """Without the chatter limit, the most accurate (stiffest) candidates chatter and take the
    front; with it they are gone."""
    free = tuned(tmp_path / "free", SAMPLED.model_copy(update={"limits": Limits(chatter=None)}))
    bound = tuned(tmp_path / "bound", SAMPLED)
    chatter = MEASURES.index("chatter")
    assert max(m.measures[chatter] for m in free.front()) > Limits().chatter
    assert max(m.measures[chatter] for m in bound.front()) <= Limits().chatter
    assert free.front() != bound.front()
    assert json.loads((tmp_path / "free" / "config.json").read_text())["limits"]["chatter"] is None


def test_a_run_nothing_of_which_keeps_the_limits_has_an_empty_front_and_says_so(
    tmp_path: Path,
) -> None:
    run = tuned(tmp_path / "run", TINY.model_copy(update={"limits": Limits(chatter=1e-9)}))
    assert run.front() == [] and run.state.stopped == "4 generations"
    assert read_run(run.directory).front == []
    assert "none met them all: the front is empty" in (run.directory / REPORT_MD).read_text()
    with pytest.raises(BadRun, match="empty front: no candidate has kept to the safety limits"):
        controller(run.directory)


def test_a_checkpoint_from_before_the_limits_resumes(tmp_path: Path) -> None:
    """Its state lacks every constraint and measure: its points count as within the limits,
    and the run goes on to the same end as one that never stopped."""
    whole = tuned(tmp_path / "whole")
    # Stopped after 2 generations, as an older gainfarm would have left it.
    config = TINY.model_copy(update={"generations": 2})
    with TuningRun.create(tmp_path / "old2", config) as run:
        run.run(InProcessEvaluator(scorer=toy_scores))  # its scores never measured anything
    path = tmp_path / "old2" / CHECKPOINT
    state = decode(path.read_bytes(), path, run.identity, config.algorithm)
    del state.__dict__["measured"]
    evolution = state.evolution
    for name in ("_seen_g", "constraints", "_ranks_feasibility"):
        del evolution.__dict__[name]
    evolution.algorithm.problem.n_ieq_constr = 0
    state.stopped = None
    path.write_bytes(encode(pickle.loads(pickle.dumps(state)), run.identity))
    (tmp_path / "old2" / "config.json").write_text(TINY.model_dump_json())
    with TuningRun.open(tmp_path / "old2") as resumed:
        assert resumed.state.measured == [(0.0,) * len(MEASURES)] * 12
        resumed.run(InProcessEvaluator(scorer=rough_toy))
        assert resumed.state.stopped == whole.state.stopped == "4 generations"
        assert len(resumed.state.measured) == resumed.state.evolution.evaluations == 24
        assert all(not resumed.config.limits.violated(m.measures) for m in resumed.front())


def test_a_checkpoint_from_before_the_lag_resumes_with_its_constraints(tmp_path: Path) -> None:
    """Its config.json names no lag and no damping bound, its measures lack the lag: neither is
    checked (its evolution was told four constraints), its points read a lag of 0, and it goes
    on to its end, its new points measured for the lag."""
    old_limits = Limits(lag=None, min_damping=None)
    assert old_limits.count == 4  # the constraints an older gainfarm told
    config = TINY.model_copy(update={"generations": 2, "limits": old_limits})
    with TuningRun.create(tmp_path / "old", config) as run:
        run.run(InProcessEvaluator(scorer=rough_toy))
    path = tmp_path / "old" / CHECKPOINT
    state = decode(path.read_bytes(), path, run.identity, config.algorithm)
    lag = MEASURED.index("lag")
    state.measured = [(*m[:lag], *m[lag + 1 :]) for m in state.measured]  # as it kept them
    del state.__dict__["lag_measured"]
    state.stopped = None
    path.write_bytes(encode(pickle.loads(pickle.dumps(state)), run.identity))
    stored = json.loads(TINY.model_dump_json())
    for name in ("lag", "min_damping"):
        del stored["limits"][name]
    (tmp_path / "old" / "config.json").write_text(json.dumps(stored))
    with TuningRun.open(tmp_path / "old") as resumed:
        assert resumed.config.limits == old_limits
        assert all(len(m) == len(MEASURED) and m[lag] == 0.0 for m in resumed.state.measured)
        resumed.run(InProcessEvaluator(scorer=lag_toy))
        assert resumed.state.stopped == "4 generations"
        assert resumed.state.evolution.constraints == 4
        assert len(resumed.state.measured) == resumed.state.evolution.evaluations == 24
        assert all(m[lag] == 0.02 for m in resumed.state.measured[12:])


def lag_toy(spec: EpisodeSpec) -> Scores:
    """The rough toy, lagging 20 mrad."""
    return rough_toy(spec).model_copy(update={"lag": 0.02})


# --- --min-damping -----------------------------------------------------------------------------


def test_a_damping_bound_keeps_every_front_member_above_it_and_the_report_lists_each(
    tmp_path: Path,
) -> None:
    assert TINY.limits.min_damping == -0.1  # a constraint by default (schemas.limits argues it)
    unbounded = SAMPLED.model_copy(update={"limits": Limits(min_damping=None)})
    free = tuned(tmp_path / "free", unbounded, scorer=damped_toy)
    assert free.state.evolution.constraints == len(MEASURES)  # not one when switched off
    assert min(member.measures[-1] for member in free.front()) < 0
    assert "not a constraint of this run" in (free.directory / REPORT_MD).read_text()
    config = SAMPLED.model_copy(update={"limits": Limits(min_damping=0.0)})
    run = tuned(tmp_path / "bound", config, damped_toy)
    assert run.state.evolution.constraints == len(MEASURED)
    _, why = tally(config.limits, read_run(run.directory).measured)
    assert why["damping"] > 0
    front = read_front_json(run.directory / "front.json")
    assert front and all(member.measures[-1] >= 0 for member in front)
    members = json.loads((run.directory / "front.json").read_text())["members"]
    assert all(set(member["measures"]) == set(MEASURED) for member in members)
    report = (run.directory / REPORT_MD).read_text()
    assert "## Damping margin" in report and "a constraint of this run: at least 0" in report
    for row, member in enumerate(run.front(), start=1):  # as front.csv numbers them
        assert f"| {row} | {member.f_acc * 1e3:.2f} | " in report
        assert f" | {member.measures[-1]:.4f} |" in report
    assert "| damping | at least 0 |" in report
    exported = controller(run.directory, "knee")  # the toy has no baseline to recommend by
    assert exported.limits is not None and exported.limits.min_damping == 0.0
    assert exported.member.measures is not None and exported.member.measures["damping"] >= 0


@pytest.mark.parametrize(
    ("value", "says"),
    [
        ("2", "analytic: error: --min-damping: min_damping: must be at most 1, got 2"),
        ("nan", "analytic: error: --min-damping: min_damping: must be a finite number, got nan"),
        ("abc", "'abc' is not a valid float"),
    ],
)
def test_a_bad_damping_bound_is_one_line_naming_the_option(
    tmp_path: Path, value: str, says: str
) -> None:
    result = analytic("start", "--min-damping", value, cwd=tmp_path)
    assert result.returncode != 0
    line = one_error_line(result.stderr)
    assert says in line and "--min-damping" in line, line


# --- --limits FILE ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (None, "cannot read"),
        ("{not json", "is not JSON"),
        ("[0.1]", "is not a JSON object of limits"),
        ('{"chatter": -1}', "chatter: must be more than 0, got -1"),
        (
            '{"jerk": 1}',
            "unknown limit 'jerk' (known: torque_step, saturated_fraction, speed, chatter, lag, "
            "min_damping)",
        ),
        ('{"torque_step": "abc"}', "torque_step: expected a number, got 'abc'"),
        ('{"lag": 0}', "lag: must be more than 0, got 0"),
        ('{"lag": "1 deg"}', "lag: expected a number, got '1 deg'"),
    ],
)
def test_a_bad_limits_file_is_one_line_naming_the_option(
    tmp_path: Path, content: str | None, says: str
) -> None:
    file = tmp_path / "limits.json"
    if content is not None:
        file.write_text(content)
    for command in (["start"], ["experiment", "popsize", "--out", str(tmp_path / "x")]):
        result = analytic(*command, "--limits", str(file), cwd=tmp_path)
        assert result.returncode != 0
        line = one_error_line(result.stderr)
        assert line.startswith("analytic: error: --limits: ") and says in line, line
    written = ["limits.json"] if content is not None else []
    assert sorted(path.name for path in tmp_path.iterdir()) == written  # no run, no experiment


def test_a_limits_file_sets_the_lag_and_switches_limits_off(tmp_path: Path) -> None:
    """The lag is a limit like the others in --limits FILE: set, or null (not checked); the
    damping's bound too, and --min-damping over the file's."""
    file = tmp_path / "limits.json"
    file.write_text('{"lag": 0.02, "min_damping": null}')
    limits = limits_from(file)
    assert limits.lag == 0.02 and limits.min_damping is None
    assert limits == Limits(lag=0.02, min_damping=None)  # the others keep their defaults
    assert limits.count == len(MEASURES)
    assert limits.violated((0.01, 0.0, 0.5, 0.001, 0.03)) == ("lag",)
    file.write_text('{"lag": null}')
    assert limits_from(file, damping=0.0) == Limits(lag=None, min_damping=0.0)
    assert limits_from(file).violated((0.01, 0.0, 0.5, 0.001, 3.0, -0.05)) == ()
