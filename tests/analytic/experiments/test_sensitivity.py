"""The sensitivity experiment: end to end at toy size on real MuJoCo episodes (in-process), its
moved plants, its findings on made-up samples, and its refusals."""

import json
from pathlib import Path

import pytest

from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import sensitivity as sens
from gainfarm.analytic.experiments.runner import Experiment
from gainfarm.analytic.experiments.statistics import holm_adjusted
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.records import BASELINE_JSON, read_baseline
from gainfarm.models import resolve
from gainfarm.schemas import TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.robot import IDEAL_PLANT, REALISTIC_PLANT, PlantSpec
from tests.analytic.experiments.common import PNG, refusal, rows, stats_rows

# Toy size: the shortest trajectory the arm can follow at speed, one generation of four.
BASE = RunConfig(
    pop=4,
    trajectories=(TrajectorySpec(kind="fourier", duration=1.0),),
    generations=1,
    keep="front",
)


@pytest.mark.slow
def test_two_parameters_moved_tuned_again_and_judged_against_the_nominal(tmp_path: Path) -> None:
    experiment = Experiment(tmp_path, lambda _study, directory: InProcessEvaluator(directory))
    sens.run(experiment, BASE, reps=1, parameters=["rotor", "delay"])

    plants = ["nominal", "rotor-x5", "delay-2", "delay-3"]
    results = rows(tmp_path / "results.csv")
    assert [r["plant"] for r in results] == plants
    assert all(0 <= float(r["hypervolume"]) <= 1 for r in results)
    assert {r["pick"] for r in results} <= {"recommended", "closest"}
    # Each run tuned on its moved plant, and nothing else moved.
    models = {
        plant: PlantSpec.model_validate(
            json.loads((tmp_path / "runs" / f"{plant}-rep0" / "config.json").read_text())["plant"]
        )
        for plant in plants
    }
    assert models["nominal"] == BASE.plant
    assert models["rotor-x5"] == BASE.plant.model_copy(
        update={"rotor_inertia": tuple(5 * b for b in BASE.plant.rotor_inertia)}
    )
    assert [models[p].delay for p in plants[2:]] == [2, 3]
    # The default gains run on each moved plant track otherwise than on the nominal one: the
    # move reached the simulation.
    nominal = read_baseline(tmp_path / "runs" / "nominal-rep0" / BASELINE_JSON)
    moved = [float(r["default_gains_error_mm"]) for r in results[1:]]
    assert all(error > 0 and error != pytest.approx(nominal.f_acc * 1000) for error in moved)
    assert results[0]["nominal_controller_error_mm"] == ""
    assert all(float(r["nominal_controller_error_mm"]) > 0 for r in results[1:])

    compared = [(r["comparison"], r["metric"]) for r in stats_rows(tmp_path)]
    assert compared == [
        (f"{label} vs nominal", metric)
        for label in ("rotor ×5", "delay 2 ticks", "delay 3 ticks")
        for metric in (*sens.METRICS, sens.RETUNED)
    ]
    assert "all plants" in json.loads((tmp_path / "normalisation.json").read_text())
    assert (tmp_path / sens.FIGURE).read_bytes().startswith(PNG)
    report = (tmp_path / "report.md").read_text()
    # One repetition decides nothing, and the report says so and how many would.
    assert "12 of 12 comparisons cannot be decided" in report
    assert "6 repetitions per plant could decide" in report
    survival = report.split("## Which conclusions survive the plant's assumptions")[1]
    assert "| rotor inertia B | ×5 |" in survival
    assert "| command delay | 3 ticks |" in survival
    assert survival.count("cannot decide (1 repetition too few after Holm)") == 3


def outcome(error_mm: float, hypervolume: float = 0.5) -> sens.RunOutcome:
    return sens.RunOutcome([], hypervolume, "recommended", DEFAULT_GAINS, error_mm / 1000, 1.0)


def test_a_shift_the_data_show_is_one_and_an_equal_plant_survives() -> None:
    reps = 8
    rotor, delay = sens.settings_of(["rotor"]) + sens.settings_of(["delay"])[:1]
    outcomes = {("nominal", r): outcome(1.0 + 0.01 * r) for r in range(reps)}
    outcomes |= {(rotor.key, r): outcome(1.0 + 0.01 * r) for r in range(reps)}
    outcomes |= {(delay.key, r): outcome(2.0 + 0.01 * r, 0.3) for r in range(reps)}
    # The nominal's controller: dominating the defaults on the rotor plant, not with the delay.
    transfers = {(rotor.key, r): sens.Transfer((0.001, 1.0), (0.002, 2.0)) for r in range(reps)}
    transfers |= {(delay.key, r): sens.Transfer((0.003, 1.0), (0.002, 2.0)) for r in range(reps)}
    adjusted = holm_adjusted(sens.comparisons([rotor, delay], outcomes, transfers, reps))
    found = [sens.finding(s, outcomes, transfers, adjusted, reps) for s in (rotor, delay)]

    assert found[0].decision == "survives: no significant shift"
    assert (found[0].error_mm, found[0].hypervolume, found[0].holds) == (0, 0, reps)
    assert found[1].decision == "shifts: error higher, hypervolume lower"
    assert found[1].error_mm == pytest.approx(1.0)
    assert found[1].hypervolume == pytest.approx(-0.2)
    assert found[1].holds == 0
    text = sens.findings(found, adjusted, reps)
    assert "hypervolume lower" in text
    assert "delay 2 ticks is worse than nominal" not in text  # lower is better: named right
    assert "- delay 2 ticks, recommended error: nominal is better than delay 2 ticks" in text
    assert "shifts significantly under delay 2 ticks; neither shifts significantly under rotor" in (
        text
    )
    assert "in 8 of 16 cases" in text
    assert text.rstrip().endswith("| shifts: error higher, hypervolume lower |")


def test_each_setting_moves_its_own_numbers_only() -> None:
    nominal = resolve(REALISTIC_PLANT).model_dump()  # the robot's numbers, as they are moved
    for setting in sens.settings_of(list(sens.PARAMETERS)):
        moved = sens.moved(REALISTIC_PLANT, setting).model_dump()
        changed = {k for k in nominal if moved[k] != nominal[k]}
        field = setting.parameter.field.split(".")[0]
        # Stiffer springs need shorter physics steps.
        assert changed == ({field, "substeps"} if setting.label == "stiffness ×2" else {field})
    assert sens.moved(REALISTIC_PLANT, sens.settings_of(["mass"])[0]).mass_scale == (0.9,) * 7
    coulomb = sens.moved(REALISTIC_PLANT, sens.settings_of(["coulomb"])[1]).friction
    written = resolve(REALISTIC_PLANT).friction
    assert coulomb and written and written.coulomb
    assert coulomb.coulomb == tuple(2 * c for c in written.coulomb)


def test_parameters_are_named_once_each_and_fit_the_plant() -> None:
    assert sens.parameter_names("delay, mass") == ["delay", "mass"]
    for text, says in (
        ("rotor,spring", "'spring' is not one of rotor, coulomb"),
        ("mass,mass", "'mass' is named twice"),
        ("", "'' is not one of"),
    ):
        with pytest.raises(ValueError, match=says):
            sens.parameter_names(text)
    ideal = RunConfig(plant=IDEAL_PLANT)
    with pytest.raises(ValueError, match=r"^--parameters: coulomb: the plant has no friction"):
        sens.prepare(ideal, {"parameters": ["rotor", "coulomb"]})
    assert sens.prepare(ideal, {"parameters": ["delay"]}) == ideal


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--parameters", "rotor,spring"], "--parameters: 'spring' is not one of rotor, coulomb"),
        (
            ["--plant", "ideal", "--parameters", "coulomb"],
            "--parameters: coulomb: the plant has no friction to move",
        ),
    ],
)
@pytest.mark.slow
def test_bad_parameters_are_refused_in_one_line_before_anything_is_written(
    tmp_path: Path, arguments: list[str], message: str
) -> None:
    assert refusal(tmp_path, "sensitivity", *arguments).startswith(message)
