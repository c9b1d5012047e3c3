"""The experiments, one module each, and the registry that finds them.

An experiment is a module holding an `ExperimentSpec` (analytic.experiments.base) named
EXPERIMENT: its name, its own options, and the function that runs it, computes its table and
draws its figure. The registry is the entry-point group `gainfarm.experiments`: the built-ins
are declared in gainfarm's pyproject.toml, and an installed distribution adds one the same way,

    [project.entry-points."gainfarm.experiments"]
    my-experiment = "my_package.my_experiment:EXPERIMENT"

after which `analytic experiment my-experiment` runs it. Listing the names reads installed
metadata only; `load` imports the one module asked for.
"""

from importlib.metadata import entry_points
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from gainfarm.analytic.experiments.base import ExperimentSpec

GROUP = "gainfarm.experiments"


class UnknownExperiment(LookupError):
    """A name no installed experiment has."""


def names() -> list[str]:
    """Every installed experiment's name, sorted."""
    return sorted({point.name for point in entry_points(group=GROUP)})


def load(name: str) -> "ExperimentSpec":
    """The experiment `name` (its module imported); UnknownExperiment if none has it."""
    from gainfarm.analytic.experiments.base import ExperimentSpec

    found = [point for point in entry_points(group=GROUP) if point.name == name]
    if not found:
        raise UnknownExperiment(f"{name!r} is not one of {', '.join(names()) or 'none'}")
    spec = found[0].load()
    if not isinstance(spec, ExperimentSpec) or spec.name != name:
        raise TypeError(f"{found[0].value} ({GROUP}) is no ExperimentSpec named {name!r}")
    return spec
