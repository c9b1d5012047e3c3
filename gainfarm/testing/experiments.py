"""The conformance kit for an experiment of the gainfarm.experiments group: the checks gainfarm's
own built-ins pass, for a plug-in's author to run on theirs (docs/experiments.md, "Adding an
experiment").

Either call the checks, each given the experiment's name (registered or installed here), or
subclass `ExperimentChecks` in a test module as pytest collects it:

    from gainfarm.testing.experiments import ExperimentChecks

    class TestSeeds(ExperimentChecks):
        experiment = "seeds"
        options = {"--runs": "2"}  # as typed after `analytic experiment seeds`
        bad_options = {"--runs": "0"}  # each refused in one line

`check_runs` does what `analytic experiment NAME` does (the options parsed by the experiment's
own parsers, its `prepare`, then its `run`), at a tiny scale (TINY: a population of 4, one
generation, one 3 s spiral, one repetition) on an in-process evaluator: real MuJoCo episodes by
default, or the evaluator an author gives (a toy scorer, for speed). Twice, into two
directories: the same seeds must give the same table.
"""

import csv
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

from gainfarm import plugins
from gainfarm.analytic.evaluators.inprocess import InProcessEvaluator
from gainfarm.analytic.experiments import registry
from gainfarm.analytic.experiments.registry import ExperimentSpec
from gainfarm.analytic.experiments.runner import EvaluatorFactory, Experiment
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.schemas.trajectory import TrajectorySpec

# A run as small as a tuning run gets: seconds of MuJoCo per repetition.
TINY = RunConfig(pop=4, trajectories=(TrajectorySpec(duration=3.0),), generations=1, keep="front")
TABLE = "results.csv"  # the experiment's table: a row per run (or per measure)
REPORT = "report.md"  # how it was run, its table, its findings and its figures
PNG = b"\x89PNG\r\n\x1a\n"
# Columns of the table that time the machine, not the experiment: never the same twice.
WALL_CLOCK = re.compile(r".*_seconds$")
FIGURE_LINK = re.compile(r"!\[[^\]]*\]\(([^)]+)\)")


def in_process(_study: str, directory: Path) -> InProcessEvaluator:
    """The evaluator `check_runs` uses unless given one: real episodes, in this process, their
    logs under `directory` (an experiment that learns from logs needs them)."""
    return InProcessEvaluator(directory)


def check_declaration(name: str) -> ExperimentSpec:
    """The experiment `name` is had here by the group's rules (a name of NAME_PATTERN, loaded by
    gainfarm.plugins: an entry point, a built-in, or registered) and declares an ExperimentSpec of
    that very name, with a one-line summary and options of their own flags; returned."""
    assert re.fullmatch(plugins.NAME_PATTERN, name), f"{name!r}: {plugins.NAME_RULE}"
    assert name in registry.names(), f"{name!r} is not in {registry.GROUP} here"
    spec = registry.load(name)
    assert isinstance(spec, ExperimentSpec) and spec.name == name, f"{name}: {spec!r}"
    assert spec.summary and "\n" not in spec.summary, f"{name}: a summary of one line"
    flags = [option.flag for option in spec.options]
    assert len(set(flags)) == len(flags), f"{name}: an option flag given twice: {flags}"
    for option in spec.options:
        assert option.flag.startswith("--") and option.parameter.isidentifier(), (
            f"{name}: option {option.flag!r} ({option.parameter!r}) is no --flag of a parameter"
        )
    return spec


def check_refusals(name: str, bad: Mapping[str, str]) -> None:
    """Every option's default is taken; each value of `bad` (flag → text, as typed) is refused
    by its option's parser with a ValueError of one line (the command puts the flag before it,
    and writes nothing)."""
    spec = registry.load(name)
    options = {option.flag: option for option in spec.options}
    for option in spec.options:
        if option.default is not None:
            option.parse(option.default)  # a ValueError here: a default the command refuses
    for flag, text in bad.items():
        assert flag in options, f"{name}: no option {flag} (it has {', '.join(options) or 'none'})"
        try:
            options[flag].parse(text)
        except ValueError as error:
            said = str(error)
        else:
            raise AssertionError(f"{name} {flag} {text!r}: taken, not refused")
        assert said.strip() and "\n" not in said, f"{name} {flag} {text!r}: said {said!r}"


def parsed(spec: ExperimentSpec, given: Mapping[str, str]) -> dict[str, Any]:
    """The keyword arguments of the experiment's run, as the command makes them: each option
    given (flag → text) or with a default parsed by its own parser."""
    unknown = set(given) - {option.flag for option in spec.options}
    assert not unknown, f"{spec.name}: no option {', '.join(sorted(unknown))}"
    values = {}
    for option in spec.options:
        text = given.get(option.flag, option.default)
        if text is not None:
            values[option.parameter] = option.parse(text)
    return values


def run_once(
    name: str,
    out: Path,
    options: Mapping[str, str] | None = None,
    base: RunConfig = TINY,
    reps: int = 1,
    evaluator: EvaluatorFactory = in_process,
) -> None:
    """`analytic experiment NAME` with `options`, into `out`, on `evaluator`."""
    spec = registry.load(name)
    values = parsed(spec, options or {})
    prepared = spec.prepare(base, values)
    spec.run(Experiment(out, evaluator), prepared, reps, **values)


def table(path: Path) -> list[dict[str, str]]:
    """The table's rows, its wall-clock columns left out."""
    with path.open(newline="") as stream:
        rows = list(csv.DictReader(stream))
    return [{k: v for k, v in row.items() if not WALL_CLOCK.fullmatch(k)} for row in rows]


def check_files(name: str, out: Path) -> None:
    """What an experiment leaves: its table (a header and a row at least), and its report: a
    title, findings in words (a line that is no heading, list item, table row or figure) and
    every figure it shows, each a PNG beside it (one at least)."""
    assert (out / TABLE).is_file(), f"{name}: no {TABLE} in {out}"
    assert table(out / TABLE), f"{name}: {TABLE} has no row"
    assert (out / REPORT).is_file(), f"{name}: no {REPORT} in {out}"
    lines = (out / REPORT).read_text(encoding="utf-8").splitlines()
    assert lines and lines[0].startswith("# "), f"{name}: {REPORT} has no title"
    prose = [
        line
        for line in lines[1:]
        if line.strip() and not line.lstrip().startswith(("#", "-", "*", "|", "!["))
    ]
    assert prose, f"{name}: {REPORT} states no findings"
    figures = FIGURE_LINK.findall("\n".join(lines))
    assert figures, f"{name}: {REPORT} shows no figure"
    for figure in figures:
        drawn = out / figure
        assert drawn.is_file() and drawn.read_bytes().startswith(PNG), (
            f"{name}: {REPORT} shows {figure}, which is no PNG in {out}"
        )


def check_runs(
    name: str,
    directory: Path,
    options: Mapping[str, str] | None = None,
    base: RunConfig = TINY,
    reps: int = 1,
    evaluator: EvaluatorFactory = in_process,
) -> None:
    """Run twice, each into a directory of its own under `directory`: each writes its files
    (check_files), and the second's table is the first's (the same seeds: the same runs, the
    same numbers), wall-clock columns aside."""
    outs: Sequence[Path] = (directory / "first", directory / "second")
    for out in outs:
        run_once(name, out, options, base, reps, evaluator)
        check_files(name, out)
    first, second = (table(out / TABLE) for out in outs)
    assert first == second, f"{name}: the same seeds gave another {TABLE} the second time"


class ExperimentChecks:
    """The checks as pytest tests: subclass it as Test..., naming the experiment (`experiment`),
    the options its tiny run takes (`options`), values each option must refuse
    (`bad_options`), and the base, repetitions and evaluator of the tiny run if not TINY's,
    one and real episodes in-process."""

    experiment: ClassVar[str]
    options: ClassVar[Mapping[str, str]] = {}
    bad_options: ClassVar[Mapping[str, str]] = {}
    base: ClassVar[RunConfig] = TINY
    reps: ClassVar[int] = 1

    def evaluator(self, study: str, directory: Path) -> Any:
        """The tiny run's evaluator (an EvaluatorFactory): real episodes unless overridden."""
        return in_process(study, directory)

    def test_declaration(self) -> None:
        check_declaration(self.experiment)

    def test_refusals(self) -> None:
        check_refusals(self.experiment, self.bad_options)

    def test_runs_alike_twice_and_writes_its_files(self, tmp_path: Path) -> None:
        check_runs(self.experiment, tmp_path, self.options, self.base, self.reps, self.evaluator)
