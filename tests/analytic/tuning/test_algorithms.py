"""The optimisers behind `analytic start --algorithm`, the objective scaling the optimiser is told,
and the classical (no-GA) baseline. Tuning runs on the toy problem (tests.analytic.toy)."""

import importlib
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments.classical import classical_gains, joint_inertias, rule
from gainfarm.analytic.tuning import evolution
from gainfarm.analytic.tuning.checkpoint import ALLOWED, decode, encode
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.evolution import ALGORITHMS, Evolution, normalise
from gainfarm.analytic.tuning.records import RunIdentity, read_run
from gainfarm.analytic.tuning.run import RunProgress, TuningRun
from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.objectives import objectives
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.wire import describe
from tests.analytic.toy import toy_scores
from tests.analytic.tuning.test_run_in_process import Interrupt, Shuffled, tune
from tests.helpers import analytic

TINY = RunConfig(
    pop=6, seed=7, trajectories=(TrajectorySpec(kind="fourier", duration=0.5),), generations=3
)
# The algorithms that need the moea extra, and the package each needs.
NEEDS = {"agemoea2": "numba", "tpe": "optuna"}
EVERY = [
    pytest.param(
        name,
        marks=pytest.mark.skipif(
            name in NEEDS and importlib.util.find_spec(NEEDS[name]) is None,
            reason=f"needs {NEEDS.get(name)}",
        ),
    )
    for name in ALGORITHMS
]


# The algorithms whose checkpoints name a class of their own module (the others' are pymoo's).
MOVED_CLASSES = ("nsga3", "smsemoa", "tpe", "random")


def toy_objectives(config: RunConfig, gains) -> tuple[float, float]:
    """What the toy evaluator finds for `gains`: the raw objectives a run must record."""
    specs = [
        EpisodeSpec(gains=gains, trajectory=t, plant=config.plant) for t in config.trajectories
    ]
    return objectives([toy_scores(spec) for spec in specs])


@pytest.mark.parametrize("algorithm", EVERY)
@pytest.mark.slow
def test_every_algorithm_tunes_and_keeps_the_same_front_guarantee(
    algorithm: str, tmp_path: Path
) -> None:
    config = TINY.model_copy(update={"algorithm": algorithm})
    whole = tune(tmp_path / "whole", config)
    assert whole.state.stopped == "3 generations"
    assert [row.evaluations for row in whole.state.history] == [6, 12, 18]
    hypervolumes = [row.hypervolume for row in whole.state.history]
    assert hypervolumes[-1] >= hypervolumes[0] > 0
    front = (whole.directory / "front.csv").read_bytes()
    evaluated = (whole.directory / "evaluated.csv").read_bytes()
    assert read_run(whole.directory).config.algorithm == algorithm

    # the same seed: the same front; another seed: another
    assert (tune(tmp_path / "again", config).directory / "front.csv").read_bytes() == front
    other = tune(tmp_path / "other", config.model_copy(update={"seed": 8}))
    assert (other.directory / "front.csv").read_bytes() != front

    # results in any order: the same front
    with TuningRun.create(tmp_path / "shuffled", config) as shuffled:
        shuffled.run(Shuffled(3))
    assert (tmp_path / "shuffled" / "front.csv").read_bytes() == front

    # stopped halfway through generation 2, resumed from its checkpoint: the same front
    def stop_in_generation_two(progress: RunProgress) -> None:
        if progress.generation == 2 and progress.evaluations > 14:
            raise Interrupt

    with pytest.raises(Interrupt):
        tune(tmp_path / "stopped", config, on_progress=stop_in_generation_two)
    with TuningRun.open(tmp_path / "stopped") as resumed:
        assert resumed.state.evolution.algorithm_name == algorithm
        assert not resumed.finished
        resumed.run(InProcessEvaluator(scorer=toy_scores))
    assert (tmp_path / "stopped" / "front.csv").read_bytes() == front
    assert (tmp_path / "stopped" / "evaluated.csv").read_bytes() == evaluated


def test_random_search_draws_a_fresh_uniform_population_every_generation() -> None:
    evolution = Evolution(6, seed=1, algorithm="random")
    space = SearchSpace()
    first = evolution.ask()
    evolution.tell([(1.0, 1.0)] * 6)
    second = evolution.ask()
    assert len(second) == 6 and not set(first) & set(second)
    for gains in first + second:
        assert all(
            lo <= k <= hi for lo, k, hi in zip(space.kp_low, gains.kp, space.kp_high, strict=True)
        )
        assert all(
            lo <= k <= hi for lo, k, hi in zip(space.kd_low, gains.kd, space.kd_high, strict=True)
        )


@pytest.mark.parametrize("algorithm", ["nsga2", "smsemoa"])
def test_log_scaling_changes_what_the_optimiser_sees_not_what_is_recorded(
    algorithm: str, tmp_path: Path
) -> None:
    raw = tune(tmp_path / "raw", TINY.model_copy(update={"algorithm": algorithm}))
    config = TINY.model_copy(update={"algorithm": algorithm, "objective_scaling": "log"})
    log = tune(tmp_path / "log", config)
    evolution = log.state.evolution
    # what the optimiser holds: the normalised objectives, not the raw ones
    population = evolution.algorithm.pop
    told = population.get("F")
    truth = [toy_objectives(config, evolution.space.gains(x)) for x in population.get("X")]
    np.testing.assert_allclose(told, normalise(truth, config.reference_point))
    assert not np.allclose(told, truth)
    # what is recorded: raw, the toy's own objectives
    for member in read_run(log.directory).front:
        assert member.objectives == pytest.approx(toy_objectives(config, member.gains))
    for (f_acc, f_t), member in zip(log.state.evaluated[:6], raw.state.evaluated[:6], strict=True):
        assert (f_acc, f_t) == member  # the first generation is sampled, whatever the scaling
    assert log.state.history[-1].hypervolume > 0
    with TuningRun.open(log.directory) as resumed:  # the checkpoint keeps the scaling
        assert resumed.state.evolution.objective_scaling == "log"


def test_corrected_objectives_reach_the_optimiser_scaled() -> None:
    evolution = Evolution(6, seed=2, objective_scaling="log")
    asked = evolution.ask()
    evolution.tell([(0.01 * (i + 1), 10.0 ** (i - 1)) for i in range(6)])
    member = evolution.front()[0]
    evolution.correct(member.gains, (0.5, 1e3))
    row = next(
        i
        for i, x in enumerate(evolution.algorithm.pop.get("X"))
        if evolution.space.gains(x) == member.gains
    )
    np.testing.assert_allclose(evolution.algorithm.pop[row].F, normalise([(0.5, 1e3)])[0])
    assert all(candidate.objectives != (0.5, 1e3) for candidate in evolution.front())
    assert len(asked) == 6


def test_the_config_records_algorithm_and_scaling_and_old_configs_still_load() -> None:
    config = TINY.model_copy(update={"algorithm": "nsga3", "objective_scaling": "log"})
    text = config.model_dump_json()
    assert RunConfig.model_validate_json(text) == config
    assert json.loads(text)["algorithm"] == "nsga3"
    old = json.loads(TINY.model_dump_json())
    del old["algorithm"], old["objective_scaling"]  # a config.json from before the fields
    loaded = RunConfig.model_validate(old)
    assert (loaded.algorithm, loaded.objective_scaling) == ("nsga2", "raw")
    with pytest.raises(ValidationError):
        RunConfig(algorithm="cmaes")
    with pytest.raises(ValidationError):
        RunConfig(objective_scaling="sqrt")


def test_steady_state_is_nsga2_only() -> None:
    with pytest.raises(ValidationError) as raised:
        RunConfig(asynchronous=True, algorithm="moead")
    message = describe(raised.value)
    assert "\n" not in message and "moead" in message and "nsga2" in message
    with pytest.raises(ValueError, match="nsga2"):
        Evolution(6, seed=0, steady_state=True, algorithm="nsga3")


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--algorithm", "cmaes"], "--algorithm"),
        (["--objective-scaling", "sqrt"], "--objective-scaling"),
        (["--async", "--algorithm", "smsemoa"], "--async"),
    ],
)
@pytest.mark.slow
def test_start_refuses_a_bad_algorithm_in_one_line(
    arguments: list[str], message: str, tmp_path: Path
) -> None:
    run = analytic("start", *arguments, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.startswith("analytic: error: ") and message in run.stderr
    assert len(run.stderr.splitlines()) == 1
    assert not (tmp_path / "runs").exists()


@pytest.mark.slow
def test_start_runs_another_algorithm_and_records_it(tmp_path: Path) -> None:
    run = analytic(
        "start",
        *("--pop", "4", "--generations", "2", "--trajectory", "fourier", "--duration", "0.5"),
        *("--algorithm", "moead", "--objective-scaling", "log", "--out", "run"),
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert (config["algorithm"], config["objective_scaling"]) == ("moead", "log")
    assert read_run(tmp_path / "run").evaluations == 8


# --- the classical rule ------------------------------------------------------------------------


def test_the_classical_rule_for_a_known_inertia() -> None:
    inertia = [2.0, 1.0, 0.5, 0.5, 0.1, 0.1, 0.05]
    kp, kd = rule(inertia, omega=10.0, zeta=0.7)
    np.testing.assert_allclose(kp, [200, 100, 50, 50, 10, 10, 5])
    np.testing.assert_allclose(kd, [28, 14, 7, 7, 1.4, 1.4, 0.7])
    wide = SearchSpace(
        kp_low=(1e-3,) * 7, kp_high=(1e6,) * 7, kd_low=(1e-3,) * 7, kd_high=(1e6,) * 7
    )
    grid = classical_gains(inertia, omegas=(10.0, 20.0), dampings=(0.7, 1.0), space=wide)
    assert grid.clipped == 0 and grid.settings == [(10, 0.7), (10, 1), (20, 0.7), (20, 1)]
    np.testing.assert_allclose(grid.gains[3].kp, np.array(inertia) * 400)
    np.testing.assert_allclose(grid.gains[3].kd, np.array(inertia) * 40)


def test_the_classical_rule_clips_to_the_search_space() -> None:
    space = SearchSpace()
    inertia = [1.0] * 7
    grid = classical_gains(inertia, omegas=(0.01, 30.0, 1000.0), dampings=(1.0,), space=space)
    slow, middle, fast = grid.gains
    assert slow.kp == space.kp_low and slow.kd == space.kd_low  # far below every bound
    assert fast.kp == space.kp_high and fast.kd == space.kd_high  # far above
    assert grid.clipped == 3  # 900 N·m/rad on A1 (bounds 200..6000) but 900 > A7's 300
    assert middle.kp[0] == 900.0 and middle.kd[0] == 60.0


def test_the_joint_inertias_include_the_rotors() -> None:
    without = PlantSpec(joints="rigid", rotor_inertia=(0.0,) * 7)
    rotors = (0.4, 0.4, 0.3, 0.3, 0.1, 0.1, 0.1)
    with_rotors = PlantSpec(joints="rigid", rotor_inertia=rotors)
    bare, full = joint_inertias(without), joint_inertias(with_rotors)
    assert np.all(bare > 0) and bare.shape == (7,)
    np.testing.assert_allclose(full - bare, rotors, atol=1e-12)


def test_agemoea2_without_numba_is_refused_before_the_run_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "pymoo.algorithms.moo.age2", None)  # as without numba
    config = TINY.model_copy(update={"algorithm": "agemoea2"})
    with pytest.raises(ValueError, match="needs numba"):
        TuningRun.create(tmp_path / "run", config)
    assert not (tmp_path / "run").exists()


def test_tpe_without_optuna_is_refused_before_the_run_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "optuna", None)  # as without optuna
    config = TINY.model_copy(update={"algorithm": "tpe"})
    with pytest.raises(ValueError, match="needs optuna") as raised:
        TuningRun.create(tmp_path / "run", config)
    assert "\n" not in str(raised.value) and "moea" in str(raised.value)
    assert not (tmp_path / "run").exists()


@pytest.mark.skipif(importlib.util.find_spec("optuna") is None, reason="needs optuna")
def test_tpe_resumes_from_plain_data_asking_what_it_would_have(tmp_path: Path) -> None:
    def toy(evolution: Evolution) -> list[tuple[float, float]]:
        return [toy_objectives(TINY, gains) for gains in evolution.ask()]

    whole = Evolution(6, seed=5, algorithm="tpe")
    asked = []
    for _ in range(4):
        asked.append(whole.ask())
        whole.tell(toy(whole))
    assert len({gains for generation in asked for gains in generation}) == 24

    identity = RunIdentity.new()
    resumed = Evolution(6, seed=5, algorithm="tpe")
    for generation in range(4):
        assert resumed.ask() == asked[generation]
        # a checkpoint between ask and tell, and one between tell and ask: through the
        # restricted unpickler, which resolves no class of Optuna's
        resumed = decode(encode(resumed, identity), tmp_path / "checkpoint.pkl", identity)
        resumed.tell(toy(resumed))
        resumed = decode(encode(resumed, identity), tmp_path / "checkpoint.pkl", identity)
    assert resumed.front() == whole.front()
    assert resumed.ask() == whole.ask()
    assert all("optuna" not in module for module, _ in ALLOWED)


@pytest.mark.parametrize("algorithm", [p for p in EVERY if p.values[0] in MOVED_CLASSES])
def test_a_checkpoint_from_before_the_optimisers_had_a_module_each_resumes(
    algorithm: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Such a checkpoint names their classes in analytic/tuning/evolution.py, where they were:
    read where they are now (checkpoint._Unpickler.MOVED), it asks what it would have."""
    whole = Evolution(6, seed=5, algorithm=algorithm)
    whole.tell([toy_objectives(TINY, gains) for gains in whole.ask()])
    # Pickled as the code before wrote it: each of their globals where it was.
    for module, name in ALLOWED:
        if module.startswith("gainfarm.analytic.tuning.algorithms."):
            moved = getattr(importlib.import_module(module), name)
            monkeypatch.setattr(moved, "__module__", evolution.__name__)
            monkeypatch.setattr(evolution, name, moved, raising=False)
    identity = RunIdentity.new()
    old = encode(whole, identity)
    monkeypatch.undo()
    assert b"tuning.algorithms" not in old
    resumed = decode(old, tmp_path / "checkpoint.pkl", identity, algorithm)
    assert resumed.ask() == whole.ask() and resumed.front() == whole.front()


# --- TPE in a steady state: told one result at a time ------------------------------------------

needs_optuna = pytest.mark.skipif(importlib.util.find_spec("optuna") is None, reason="needs optuna")


def steady_tpe(seed: int = 5) -> Evolution:
    """A steady-state TPE past its first (random, generational) generation of six."""
    evolution = Evolution(6, seed=seed, steady_state=True, algorithm="tpe")
    evolution.tell([toy_objectives(TINY, gains) for gains in evolution.ask()])
    return evolution


@needs_optuna
def test_steady_state_tpe_samples_from_every_result_told_so_far() -> None:
    told = []
    for worse in (False, True):
        evolution = steady_tpe()
        (first, first_gains), (second, second_gains) = evolution.ask_one(), evolution.ask_one()
        # The second returns first (a farm's order): the best point yet, or the worst; what it
        # found steers the next ask.
        evolution.tell_one(second, (1e3, 1e6) if worse else (1e-6, 1e-6))
        _, third_gains = evolution.ask_one()
        evolution.tell_one(first, toy_objectives(TINY, first_gains))
        told.append((first_gains, second_gains, third_gains))
        assert evolution.evaluations == 8 and evolution.algorithm.pending == [8]
        with pytest.raises(ValueError, match="not yet told"):
            evolution.tell_one(second, (1e-6, 1e-6))  # told once only
    (a1, b1, c1), (a2, b2, c2) = told
    assert (a1, b1) == (a2, b2)  # asked alike, from the same seed
    assert c1 != c2  # but the third learnt from the second's result, before the first's came


@needs_optuna
def test_a_steady_state_tpe_checkpoint_drops_the_trials_in_flight(tmp_path: Path) -> None:
    evolution = steady_tpe()
    handle, gains = evolution.ask_one()
    evolution.tell_one(handle, toy_objectives(TINY, gains))
    in_flight = [evolution.ask_one() for _ in range(2)]
    assert evolution.algorithm.pending == [7, 8]
    identity = RunIdentity.new()
    checkpoint = encode(evolution, identity)
    resumed, again = (decode(checkpoint, tmp_path / "checkpoint.pkl", identity) for _ in "ab")
    # A resumed run asks anew for what was in flight: failed trials, which TPE leaves out
    # (running ones would stand under the constant liar for ever).
    states = [trial.state.name for trial in resumed.algorithm._study.trials]
    assert states == ["COMPLETE"] * 7 + ["FAIL"] * 2 and resumed.algorithm.pending == []
    assert resumed.ask_one()[1] == again.ask_one()[1]  # deterministic from the checkpoint
    # The live run goes on telling them.
    for handle, gains in in_flight:
        evolution.tell_one(handle, toy_objectives(TINY, gains))
    assert evolution.algorithm.pending == [] and evolution.evaluations == 9


@needs_optuna
def test_an_async_tpe_run_keeps_its_budget_exactly(tmp_path: Path) -> None:
    config = TINY.model_copy(
        update={"algorithm": "tpe", "asynchronous": True, "generations": None, "evaluations": 15}
    )
    run = read_run(tune(tmp_path / "run", config).directory)
    assert run.config.asynchronous and run.config.algorithm == "tpe"
    assert [row.evaluations for row in run.history] == [6, 12, 15]
    assert len(run.evaluated) == 15
    assert run.front and all(m.objectives in run.evaluated for m in run.front)
