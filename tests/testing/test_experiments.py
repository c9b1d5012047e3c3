"""Every built-in experiment passes the conformance kit a plug-in's author runs
(gainfarm.testing.experiments): its declaration and its options' refusals, and, where a tiny run
is affordable on the toy scorer, its files and the same table twice from the same seeds; and the
kit fails an experiment that breaks its rules."""

from pathlib import Path
from typing import ClassVar

import pytest

from gainfarm import plugins
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import popsize
from gainfarm.analytic.experiments.registry import ExperimentSpec, Option, at_least
from gainfarm.testing import experiments as kit
from tests.analytic.toy import toy_scores

# For each built-in, values of its own options it must refuse, as typed.
BAD = {
    "popsize": {"--sizes": "4,x"},
    "generic-vs-specific": {"--design": "neither"},
    "speed": {"--durations": "3,fast"},
    "algorithms": {
        "--algorithms": "nsga2,nope",
        "--objective-scaling": "raw,raw",
        "--budgets": "-5",
        "--torque-measure": "peak",
    },
    "dataset-value": {"--test-trajectories": "0", "--ticks": "9"},
    "sensitivity": {"--parameters": "gravity"},
    "feedforward": {"--learner": "oracle", "--held-out": "0", "--plants": "-1"},
}


def toy(_study: str, _directory: Path) -> InProcessEvaluator:
    return InProcessEvaluator(scorer=toy_scores)


def test_every_built_in_is_checked() -> None:
    assert set(BAD) == set(plugins.builtin_names(plugins.EXPERIMENTS))


@pytest.mark.parametrize("name", sorted(BAD))
def test_a_built_in_s_declaration_and_refusals_pass_the_kit(name: str) -> None:
    assert kit.check_declaration(name).name == name
    kit.check_refusals(name, BAD[name])


class TestPopsize(kit.ExperimentChecks):
    experiment = "popsize"
    options: ClassVar[dict[str, str]] = {"--sizes": "4,6"}
    bad_options: ClassVar[dict[str, str]] = BAD["popsize"]
    reps = 2

    def evaluator(self, study: str, directory: Path) -> InProcessEvaluator:
        return toy(study, directory)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "options", "base"),
    [
        ("speed", {"--durations": "3,3.5"}, kit.TINY),
        ("generic-vs-specific", {"--design": "paper"}, kit.TINY),
        (
            "algorithms",
            {"--algorithms": "nsga2,random", "--budgets": "4"},
            kit.TINY.model_copy(update={"generations": None, "evaluations": 8}),
        ),
    ],
)
def test_a_built_in_runs_alike_twice_and_writes_its_files(
    tmp_path: Path, name: str, options: dict[str, str], base: kit.RunConfig
) -> None:
    kit.check_runs(name, tmp_path, options, base, reps=1, evaluator=toy)


# --- the kit fails what breaks the rules -------------------------------------------------------


def test_the_kit_refuses_a_declaration_of_another_name_or_no_summary() -> None:
    try:
        plugins.register(plugins.EXPERIMENTS, "misnamed", popsize.EXPERIMENT)
        with pytest.raises(plugins.PluginError, match="is no ExperimentSpec named 'misnamed'"):
            kit.check_declaration("misnamed")
        silent = ExperimentSpec(name="silent", summary="", run=popsize.run)
        plugins.register(plugins.EXPERIMENTS, "silent", silent)
        with pytest.raises(AssertionError, match="silent: a summary of one line"):
            kit.check_declaration("silent")
    finally:
        plugins.unregister(plugins.EXPERIMENTS, "misnamed")
        plugins.unregister(plugins.EXPERIMENTS, "silent")


def lenient(text: str) -> int:
    return int(text) if text.isdigit() else 1  # takes anything: a bad value runs


def test_the_kit_refuses_an_option_that_takes_a_bad_value_or_says_so_in_many_lines() -> None:
    def wordy(text: str) -> int:
        raise ValueError(f"{text!r}:\nnot a count")

    spec = ExperimentSpec(
        name="loose",
        summary="options that do not refuse as they should",
        run=popsize.run,
        options=(
            Option("--count", "count", "any", "1", lenient),
            Option("--wordy", "wordy", "two lines", None, wordy),
            Option("--least", "least", "at least 2", "2", at_least(2)),
        ),
    )
    try:
        plugins.register(plugins.EXPERIMENTS, "loose", spec)
        kit.check_refusals("loose", {"--least": "1"})
        with pytest.raises(AssertionError, match="loose --count 'x': taken, not refused"):
            kit.check_refusals("loose", {"--count": "x"})
        with pytest.raises(AssertionError, match="loose --wordy 'x': said"):
            kit.check_refusals("loose", {"--wordy": "x"})
        with pytest.raises(AssertionError, match="loose: no option --nope"):
            kit.check_refusals("loose", {"--nope": "x"})
    finally:
        plugins.unregister(plugins.EXPERIMENTS, "loose")


def test_the_kit_refuses_a_report_with_no_findings_or_a_missing_figure(tmp_path: Path) -> None:
    (tmp_path / kit.TABLE).write_text("rep,hypervolume\n0,0.5\n")
    (tmp_path / kit.REPORT).write_text("# Title\n\n- setup\n\n![figure](figure.png)\n")
    with pytest.raises(AssertionError, match=r"report\.md states no findings"):
        kit.check_files("bare", tmp_path)
    (tmp_path / kit.REPORT).write_text("# Title\n\nIt levels off.\n\n![figure](figure.png)\n")
    with pytest.raises(AssertionError, match=r"shows figure\.png, which is no PNG"):
        kit.check_files("bare", tmp_path)
    (tmp_path / "figure.png").write_bytes(kit.PNG + b"...")
    kit.check_files("bare", tmp_path)
