"""The experiments' registry: the declaration an experiment makes of itself (an `ExperimentSpec`
named EXPERIMENT in its module, with its own command-line options) and its lookup by name.

The experiments are the plug-in group `gainfarm.experiments` (gainfarm.plugins), by the rules of
every group: a name of NAME_PATTERN, the built-ins reserved and loaded on first use, a third
party's through its distribution's entry point,

    [project.entry-points."gainfarm.experiments"]
    my-experiment = "my_package.my_experiment:EXPERIMENT"

after which `analytic experiment my-experiment` runs it (gainfarm.testing.experiments checks
one). Listing the names imports no experiment; `load` imports the one asked for.
"""

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from gainfarm import plugins
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.schemas.trajectory import TrajectorySpec

T = TypeVar("T")
GROUP = plugins.EXPERIMENTS


@dataclass(frozen=True)
class Option:
    """An option of one experiment's own on the command line (`analytic experiment NAME`).

    `parse` turns the text given (or `default`) into the keyword `parameter` of the
    experiment's run; a ValueError says, in one line, what is wrong with it (the command puts
    the option's name in front)."""

    flag: str  # "--sizes"
    parameter: str  # "sizes"
    help: str
    default: str | None = None  # as typed; None: the run's own default, unless given
    parse: Callable[[str], object] = str
    metavar: str = "TEXT"


def _same(base: RunConfig, _options: Mapping[str, Any]) -> RunConfig:
    return base


def _base_trajectories(base: RunConfig, _options: Mapping[str, Any]) -> Sequence[TrajectorySpec]:
    return base.trajectories


@dataclass(frozen=True)
class ExperimentSpec:
    """One experiment as the registry and the command line know it.

    `run(experiment, base, reps, **options)` does it all: the runs, results.csv, stats.csv,
    normalisation.json, its figure and report.md. Before anything runs, `prepare(base,
    options)` checks the options against the base configuration and returns the one the runs
    start from (ValueError, naming the option, if they do not fit), and `trajectories(base,
    options)` are every trajectory its episodes follow, which the command checks the arm can
    follow (blaming `trajectory_option`)."""

    name: str  # as `analytic experiment NAME` names it
    summary: str  # one line
    run: Callable[..., object]
    help: str = ""  # what `analytic experiment NAME --help` says; the summary if empty
    options: tuple[Option, ...] = ()
    duration: float | None = 5.0  # --duration's default, s; None: it takes no --duration
    prepare: Callable[[RunConfig, Mapping[str, Any]], RunConfig] = _same
    trajectories: Callable[[RunConfig, Mapping[str, Any]], Sequence[TrajectorySpec]] = (
        _base_trajectories
    )
    trajectory_option: str = "--duration"
    # The arms it runs on, by name (None: any, the robot it is given). An experiment that is
    # one arm's by design names it and says why (`only_on`); another arm is refused in one line.
    robots: tuple[str, ...] | None = None
    only_on: str = ""

    def refusal(self, robot: str) -> str | None:
        """Why the experiment does not run on `robot`, in one line; None if it does."""
        if self.robots is None or robot in self.robots:
            return None
        return f"{self.name} runs on {', '.join(self.robots)} only, not {robot}: {self.only_on}"


def numbers(kind: Callable[[float], T]) -> Callable[[str], list[T]]:
    """A parser of comma-separated numbers, each made `kind` (int, float)."""

    def parse(text: str) -> list[T]:
        try:
            values = [float(part) for part in text.split(",")]
        except ValueError:
            raise ValueError(f"expected comma-separated numbers, got {text!r}") from None
        return [kind(value) for value in values]

    return parse


def at_least(minimum: int) -> Callable[[str], int]:
    """A parser of one integer no smaller than `minimum`."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise ValueError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise ValueError(f"{value} is not at least {minimum}")
        return value

    return parse


def names() -> tuple[str, ...]:
    """Every experiment this installation has: the built-ins, then the plug-ins, sorted.
    Imports none of them."""
    return plugins.names(GROUP)


def load(name: str) -> ExperimentSpec:
    """The experiment `name`, its module imported. PluginError (one line naming the group, the
    name and the experiments there are) if there is none, it fails to load, or what it declares
    is no ExperimentSpec of that name."""
    spec = plugins.load(GROUP, plugins.check_name(GROUP, name))
    if not isinstance(spec, ExperimentSpec) or spec.name != name:
        raise plugins.PluginError(f"{GROUP}: plug-in {name!r} is no ExperimentSpec named {name!r}")
    return spec
