"""Robust tuning: plant variants drawn from the uncertainty ranges, the same for every candidate,
each trajectory's objectives aggregated over them."""

import json
from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.plants import (
    CORNERS,
    HELD_OUT,
    BadUncertainty,
    corner,
    design,
    ranges,
    variants,
)
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.models import compile_model, resolve
from gainfarm.schemas import Scores, TrajectorySpec
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.objectives import objectives
from gainfarm.schemas.robot import IDEAL_PLANT, REALISTIC_PLANT, LoadData
from gainfarm.worker.plant import gravity_spec
from tests.helpers import analytic

# The realistic plant with its robot's numbers written out, as the variants are.
NOMINAL = resolve(REALISTIC_PLANT)


def _scores(f_acc: float, f_t: float) -> Scores:
    return Scores(
        f_acc=f_acc, f_t=f_t, max_error=f_acc, saturated_fraction=0.0, diverged=False, ticks=1
    )


def test_variants_stay_in_their_ranges_and_the_robots_model_stays_nominal() -> None:
    drawn = variants(REALISTIC_PLANT, 12, seed=3)
    assert drawn == variants(REALISTIC_PLANT, 12, seed=3)  # deterministic in the seed
    assert drawn != variants(REALISTIC_PLANT, 12, seed=4)
    assert len(set(drawn)) == 12
    nominal = NOMINAL
    for plant in drawn:
        assert all(0.85 <= scale <= 1.15 for scale in plant.mass_scale)
        assert 0.0 <= plant.payload <= 3.0 and plant.delay in (0, 1, 2)
        factors = np.divide(plant.rotor_inertia, nominal.rotor_inertia)
        assert np.all((factors >= 0.5) & (factors <= 10.0))
        coulomb = np.divide(plant.friction.coulomb, nominal.friction.coulomb)
        assert np.all((coulomb >= 0.5) & (coulomb <= 2.0))
        assert plant.sensors.seed != nominal.sensors.seed
        assert gravity_spec(plant) == gravity_spec(nominal)  # the robot knows none of it
        compile_model(plant)  # the physics steps its springs need
    # A plant without friction has none to vary; the rest varies as for any plant.
    assert all(plant.friction is None for plant in variants(IDEAL_PLANT, 3, seed=0))


def test_the_design_puts_the_corners_first_at_their_ranges_ends_then_random_draws() -> None:
    table = ranges()
    heavy, light, *drawn = design(REALISTIC_PLANT, 4, seed=3)
    assert list(CORNERS) == ["heavy", "light"]
    assert tuple(drawn) == variants(REALISTIC_PLANT, 2, seed=3)  # the random ones as before
    assert design(REALISTIC_PLANT, 1, seed=3) == (heavy,)  # fewer: the corners in order
    assert design(REALISTIC_PLANT, 0, seed=3) == ()
    assert heavy.payload == table["payload"].high and light.payload == table["payload"].low
    assert heavy.delay == light.delay == table["delay"].high  # both late by the range's top
    assert heavy.mass_scale == (table["mass_scale"].high,) * 7
    rotor = np.divide(light.rotor_inertia, NOMINAL.rotor_inertia)
    assert np.allclose(rotor, table["rotor_inertia"].low)
    assert heavy.rotor_inertia == NOMINAL.rotor_inertia  # fast paths stay feasible
    softer = np.divide(heavy.stiffness, NOMINAL.stiffness)
    assert np.allclose(softer, table["stiffness"].low)
    stiffness = np.divide(light.stiffness, NOMINAL.stiffness)
    assert np.allclose(stiffness, table["stiffness"].high)
    # Only what a corner names moves: its sensors keep the nominal noise, on a seed of its own.
    assert heavy.spring_damping == NOMINAL.spring_damping
    assert heavy.sensors.noise == REALISTIC_PLANT.sensors.noise
    assert len({REALISTIC_PLANT.sensors.seed, heavy.sensors.seed, light.sensors.seed}) == 3
    assert gravity_spec(heavy) == gravity_spec(REALISTIC_PLANT)  # the robot knows none of it
    for plant in (heavy, light):
        compile_model(plant)  # the physics steps its springs need
    assert heavy.substeps == REALISTIC_PLANT.substeps < light.substeps  # stiffer: finer steps
    # A table without a range leaves its field nominal at every corner.
    table.pop("payload")
    assert design(REALISTIC_PLANT, 1, seed=3, uncertainty=table)[0].payload == 0.0
    with pytest.raises(KeyError):
        corner(REALISTIC_PLANT, {"payload": "high"}, table)


def test_each_shipped_range_names_its_source_or_says_it_is_an_assumption() -> None:
    for name, item in ranges().items():
        assert "source" in item.why or "assumption" in item.why, name


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("x = 1", "x: a table of field, draw, low, high and why expected"),
        ('[a]\nfield = "stiffness"\ndraw = "log"\nlow = 2\nhigh = 1\nwhy = "w"', "below low"),
        (
            '[a]\nfield = "payload"\nper_joint = true\ndraw = "uniform"\nlow = 0\nhigh = 1\n'
            'why = "w"',
            "one number, not one per joint",
        ),
        ("[a", "not TOML"),
        (
            '[a]\nfield = "stiffness"\ndraw = "log"\nlow = [1, 1]\nhigh = 2\nwhy = "w"',
            "low: one number, or one per joint with per_joint = true",
        ),
        (
            '[a]\nfield = "stiffness"\nper_joint = true\ndraw = "log"\nlow = [1, 1, 1, 1, 1, 1, 3]'
            '\nhigh = 2\nwhy = "w"',
            "high 2 is below low 1, 1, 1, 1, 1, 1, 3",
        ),
    ],
)
def test_a_bad_uncertainty_file_is_refused_in_one_line(text: str, says: str) -> None:
    with pytest.raises(BadUncertainty, match=says) as refused:
        ranges(text)
    assert "\n" not in str(refused.value)


def test_per_joint_bounds_draw_each_joint_within_its_own() -> None:
    # A calibrated twin's ranges: one pair per joint (analytic calibrate writes them).
    low, high = (0.9, 0.5, 1.0, 0.95, 0.99, 0.8, 1.0), (1.1, 2.0, 1.0, 1.05, 1.01, 1.25, 1.0)
    table = ranges(
        f'[k]\nfield = "stiffness"\nper_joint = true\ndraw = "log"\nlow = {list(low)}\n'
        f'high = {list(high)}\nwhy = "calibrated"\n'
        '[d]\nfield = "delay"\nabsolute = true\ndraw = "integer"\nlow = 2\nhigh = 2\nwhy = "w"\n'
    )
    drawn = variants(REALISTIC_PLANT, 32, seed=5, uncertainty=table)
    factors = np.array([p.stiffness for p in drawn]) / np.asarray(NOMINAL.stiffness)
    assert np.all(factors >= np.asarray(low) * (1 - 1e-12))
    assert np.all(factors <= np.asarray(high) * (1 + 1e-12))
    assert np.ptp(factors[:, 1]) > 1.0 and np.ptp(factors[:, 2]) == 0  # each joint its own
    assert {p.delay for p in drawn} == {2}


def test_each_trajectorys_objectives_aggregate_its_plants() -> None:
    # Two trajectories on three plants each (nominal first): f_acc 1, 2, 9 and 4, 4, 4.
    scores = [_scores(f_acc=v, f_t=10 * v) for v in (1.0, 2.0, 9.0, 4.0, 4.0, 4.0)]
    assert objectives(scores, None, 3, "mean") == pytest.approx((4.0, 40.0))
    assert objectives(scores, None, 3, "worst") == pytest.approx((6.5, 65.0))
    assert objectives(scores, None, 3, "cvar") == pytest.approx((6.5, 65.0))  # 1 of 3: worst
    nine = [_scores(f_acc=v, f_t=v) for v in range(1, 10)]
    assert objectives(nine, None, 9, "cvar")[0] == pytest.approx(8.0)  # the worst 3 of 9
    assert objectives(nine[:1], None, 1, "worst") == objectives(nine[:1])


def test_every_candidate_meets_the_same_variants(tmp_path: Path) -> None:
    config = RunConfig(
        pop=4,
        generations=2,
        trajectories=(TrajectorySpec(kind="fourier", duration=0.3),),
        plants=variants(REALISTIC_PLANT, 2, seed=0),
        keep="all",
    )
    with TuningRun.create(tmp_path / "run", config) as run:
        run.run(InProcessEvaluator(tmp_path / "run"), lambda progress: None)
        logs = sorted((tmp_path / "run" / "episodes").glob("*.mcap"))
        assert len(logs) == 8 * 3  # 8 candidates, each on the nominal plant and 2 variants
        for log in logs:
            plant = read_episode(log).metadata.spec.plant
            variant = log.stem.rpartition("-p")[2] if "-p" in log.stem else "0"
            assert plant == ([config.plant, *config.plants])[int(variant)], log.name
    saved = (tmp_path / "run" / "config.json").read_bytes()
    assert RunConfig.model_validate_json(saved).plants == config.plants  # and resumes with them


def test_plants_and_uncertainty_bad_input_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "bad.toml").write_text('[a]\nfield = "nothing"\n')
    (tmp_path / "empty.toml").write_text("# nothing yet\n")
    for arguments, says in (
        (["--plants", "-1"], "--plants"),
        (["--plants", "2", "--uncertainty", "bad.toml"], "--uncertainty: 'bad.toml': a: "),
        (["--plants", "2", "--uncertainty", "missing.toml"], "--uncertainty: cannot read"),
        (
            ["--plants", "2", "--uncertainty", "empty.toml"],
            "analytic: error: --uncertainty: 'empty.toml' holds no ranges (a table per "
            "parameter, as in the shipped models/uncertainty.toml)\n",
        ),
    ):
        result = analytic("start", *arguments, "--out", "run", cwd=tmp_path)
        assert result.returncode == 2, result.stderr
        assert result.stderr.count("\n") == 1 and says in result.stderr, result.stderr
        assert not (tmp_path / "run").exists()


def test_the_held_out_check_runs_the_controller_to_use_and_the_defaults(tmp_path: Path) -> None:
    from gainfarm.analytic.tuning.check import read_check, run_check
    from gainfarm.analytic.view.export import controller
    from gainfarm.analytic.view.run_report import write_run_report

    config = RunConfig(
        pop=4,
        generations=2,
        trajectories=(TrajectorySpec(kind="fourier", duration=0.3),),
        check_plants=variants(REALISTIC_PLANT, 3, seed=0, stream=HELD_OUT),
    )
    assert not set(config.check_plants) & set(variants(REALISTIC_PLANT, 3, seed=0))
    directory = tmp_path / "run"
    with TuningRun.create(directory, config) as run:
        evaluator = InProcessEvaluator(directory)
        run.run(evaluator, lambda progress: None)
        run.baseline(evaluator)
        checked = run_check(run, evaluator)
        write_run_report(run)
    names = [item.name for item in checked]
    assert names.count("default gains") == 1 and set(names) <= {
        "recommended",
        "candidate",
        "knee",
        "default gains",
    }
    for item in checked:
        assert item.nominal_f_acc > 0 and 0 < item.median_f_acc <= item.worst_f_acc
        assert item.violations + item.diverged <= 1
        assert (item.row is None or item.name == "recommended") == (not item.failed)
    record = read_check(directory)
    # 8 candidates' 8 episodes afford half as many: one held-out plant for the first round's
    # controllers (2 or 3), and no second round.
    assert record["plants"] == 1 and record["cost"]["episodes"] == len(checked) * 2 <= 6
    recommended = [item for item in checked if item.name == "recommended"]
    assert record["advice"]["row"] == (recommended[0].row if recommended else None)
    assert json.loads((directory / "front.json").read_text())["held_out"] == record
    assert "## Held-out plants" in (directory / "report.md").read_text()
    exported = controller(directory, "knee")  # checked, whether or not it is the one to use
    assert exported.member.held_out is not None and exported.member.held_out.plants == 1


def test_variants_draw_the_told_loads_error_around_it_and_the_robot_keeps_what_it_was_told() -> (
    None
):
    told = REALISTIC_PLANT.model_copy(update={"load": LoadData(mass=5.0, com=(0.0, 0.0, 0.1))})
    drawn = variants(told, 16, seed=3)
    scales = np.array([plant.load.mass_scale for plant in drawn])
    low, high = ranges()["load_mass"].low, ranges()["load_mass"].high
    assert np.all((scales >= low) & (scales <= high)) and np.ptp(scales) > 0.1
    assert scales.min() < 1.0 < scales.max()  # around the told mass, both ways
    for plant in drawn:
        assert gravity_spec(plant) == gravity_spec(told)  # told 5 kg at 10 cm, whatever is held
        assert 0.0 <= plant.payload <= 3.0  # and, as ever, a tool it may not have been told of
    # A plant told of no load draws nothing for the load's error: its variants are, draw for
    # draw, those of a table without that range.
    without = {name: item for name, item in ranges().items() if name != "load_mass"}
    assert variants(REALISTIC_PLANT, 4, seed=3) == variants(REALISTIC_PLANT, 4, 3, without)
    assert all(plant.load is None for plant in variants(REALISTIC_PLANT, 4, seed=3))
