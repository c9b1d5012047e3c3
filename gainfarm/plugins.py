"""Plug-ins: optimisers, trajectory kinds and objectives added without editing gainfarm.

Three groups, each a namespace of names (docs/plugins.md says what each provides):

    gainfarm.algorithms     an optimiser: factory(pop_size, seed, space) -> ask and tell object
    gainfarm.trajectories   a trajectory kind: path(spec, u) -> the flange's offsets, m
    gainfarm.objectives     an objective: objective(log) -> float, lower is better

A plug-in enters a group by a Python entry point of the distribution that holds it, as pytest's
plug-ins do (its pyproject.toml: `[project.entry-points."gainfarm.objectives"]` then
`peak_torque = "mypkg.objectives:peak_torque"`), or in one process by `register`.

The built-in ones are listed here, statically, as references loaded on first use: they are part
of gainfarm, so they are there whatever the state of the installation's metadata (an editable
install made before one was added, a source tree on PYTHONPATH), and their names are reserved:
`register` refuses one, and an entry point that takes one is ignored.

Cheap to import (the standard library only, nothing of the project, no plug-in), because command
lines whose start-up is measured import it: `names` reads the installed distributions' metadata
without importing any plug-in; `load` imports the one asked for.
"""

import re
import sys
from collections.abc import Iterable
from importlib import import_module
from typing import Any

ALGORITHMS = "gainfarm.algorithms"
TRAJECTORIES = "gainfarm.trajectories"
OBJECTIVES = "gainfarm.objectives"
EXPERIMENTS = "gainfarm.experiments"
ROBOTS = "gainfarm.robots"

# A plug-in's name becomes part of job ids and file names (a trajectory kind names the jobs of an
# experiment) and of command-line choices: short, lower case, no separator of a key expression.
# schemas/trajectory.py repeats it (the contract imports nothing of the project): a test keeps
# the two equal.
NAME_PATTERN = r"^[a-z][a-z0-9_-]{0,31}$"
NAME_RULE = "a lower-case letter, then up to 31 lower-case letters, digits, '_' or '-'"

# Each group's built-ins, in the order command lines list them (the default first).
BUILTIN: dict[str, dict[str, str]] = {
    ALGORITHMS: {
        "nsga2": "gainfarm.analytic.tuning.evolution:nsga2",
        "nsga3": "gainfarm.analytic.tuning.evolution:nsga3",
        "smsemoa": "gainfarm.analytic.tuning.evolution:smsemoa",
        "moead": "gainfarm.analytic.tuning.evolution:moead",
        "agemoea2": "gainfarm.analytic.tuning.evolution:agemoea2",
        "tpe": "gainfarm.analytic.tuning.evolution:OptunaTPE",
        "random": "gainfarm.analytic.tuning.evolution:UniformRandom",
    },
    # The spiral's and the random kind's paths are of a plug-in's form (worker.trajectories.Path);
    # the worker builds the pyramid (it rests at its corners) and the fourier kind (a joint-space
    # motion) by their own rules.
    TRAJECTORIES: {
        "spiral": "gainfarm.worker.trajectories:spiral",
        "random": "gainfarm.worker.trajectories:random_path",
        "pyramid": "gainfarm.worker.trajectories:pyramid",
        "fourier": "gainfarm.worker.trajectories:fourier_coefficients",
    },
    OBJECTIVES: {
        "f_acc": "gainfarm.schemas.objectives.accuracy:f_acc",
        "f_t": "gainfarm.schemas.objectives.torque_change:f_t",
        # f_t with each joint's change weighed by its torque limit
        "f_t_joint": "gainfarm.schemas.objectives.joint_torque_change:f_t_joint",
    },
    EXPERIMENTS: {
        "popsize": "gainfarm.analytic.experiments.popsize:EXPERIMENT",
        "generic-vs-specific": "gainfarm.analytic.experiments.generic_vs_specific:EXPERIMENT",
        "speed": "gainfarm.analytic.experiments.speed:EXPERIMENT",
        "algorithms": "gainfarm.analytic.experiments.algorithms:EXPERIMENT",
        "dataset-value": "gainfarm.analytic.experiments.dataset_value:EXPERIMENT",
        "sensitivity": "gainfarm.analytic.experiments.sensitivity:EXPERIMENT",
        "feedforward": "gainfarm.analytic.experiments.feedforward:EXPERIMENT",
    },
    # An arm: its model builder, limits, default gains, the robot's gravity model, its workspace.
    ROBOTS: {},
}
GROUPS = tuple(BUILTIN)


class PluginError(ValueError):
    """A plug-in that cannot be had here: unknown to this installation, or failing to load.
    str() is one line naming the group, the name and what is available."""


_registered: dict[str, dict[str, Any]] = {group: {} for group in GROUPS}
_loaded: dict[tuple[str, str], Any] = {}  # entry points loaded once: a worker loads per job
_found: tuple[tuple[str, ...], dict[str, dict[str, Any]]] | None = None  # (sys.path, by group)


def register(group: str, name: str, plugin: Any) -> None:
    """Make `plugin` the one named `name` in `group`, in this process only (a farm's workers
    need it installed: an entry point). Registering a name again replaces the earlier one."""
    _check_group(group)
    if not isinstance(name, str) or not re.fullmatch(NAME_PATTERN, name):
        raise ValueError(f"{group}: plug-in name {name!r}: {NAME_RULE}")
    if name in BUILTIN[group]:
        raise ValueError(f"{group}: {name!r} is a built-in name; choose another")
    _registered[group][name] = plugin


def unregister(group: str, name: str) -> None:
    """Forget a plug-in `register` made (nothing if there is none)."""
    _check_group(group)
    _registered[group].pop(name, None)


def builtin_names(group: str) -> tuple[str, ...]:
    """The built-in names of `group`, the default first: free, no metadata read."""
    _check_group(group)
    return tuple(BUILTIN[group])


def names(group: str) -> tuple[str, ...]:
    """Every name `group` has here: the built-ins (the default first), then the plug-ins,
    registered or installed, sorted. Imports no plug-in."""
    _check_group(group)
    builtin = BUILTIN[group]
    others = (set(_registered[group]) | set(_entry_points(group))) - set(builtin)
    return (*builtin, *sorted(others))


def check_name(group: str, name: str) -> str:
    """`name`, if `group` has it here (a built-in costs nothing: no metadata read, no import);
    PluginError naming what the group has if not."""
    _check_group(group)
    if name in BUILTIN[group] or name in _registered[group] or name in _entry_points(group):
        return name
    raise _unknown(group, name)


def load(group: str, name: str) -> Any:
    """The plug-in named `name` in `group`: a built-in, one `register`ed in this process, or an
    installed entry point's object. PluginError if there is none, or it fails to load."""
    _check_group(group)
    if name in BUILTIN[group]:
        module, _, attribute = BUILTIN[group][name].partition(":")
        return getattr(import_module(module), attribute)
    if name in _registered[group]:
        return _registered[group][name]
    if (group, name) in _loaded:
        return _loaded[(group, name)]
    point = _entry_points(group).get(name)
    if point is None:
        raise _unknown(group, name)
    try:
        plugin = point.load()
    except Exception as error:  # whatever a third party's import raises: one line, its name
        reason = " ".join(f"{type(error).__name__}: {error}".split())[:300]
        raise PluginError(
            f"{group}: plug-in {name!r} ({point.value}) failed to load: {reason}"
        ) from None
    _loaded[(group, name)] = plugin
    return plugin


def load_plugins(group: str, wanted: Iterable[str]) -> dict[str, Any]:
    """The plug-ins among the names `wanted` (the built-ins left out), loaded, by name: what a
    job names that its worker must have. PluginError naming the first that cannot be had."""
    return {name: load(group, name) for name in wanted if name not in BUILTIN[group]}


def _unknown(group: str, name: str) -> PluginError:
    return PluginError(
        f"{group}: no plug-in named {name!r} here (there are {', '.join(names(group))}); "
        "install the distribution that provides it"
    )


def _check_group(group: str) -> None:
    if group not in BUILTIN:
        raise ValueError(f"no plug-in group {group!r}: one of {', '.join(GROUPS)}")


def _entry_points(group: str) -> dict[str, Any]:
    """The group's installed entry points by name. All three groups are read in one scan of every
    distribution's metadata (tens of ms: too much for each job of a worker), again only when
    sys.path changed. Two distributions giving one name: the first on sys.path wins, as an import
    would."""
    global _found
    path = tuple(sys.path)
    if _found is None or _found[0] != path:
        from importlib.metadata import entry_points  # tens of ms: only when a plug-in is looked up

        every = entry_points()  # one scan; .select works on Python 3.11's result and 3.12's
        points: dict[str, dict[str, Any]] = {each: {} for each in GROUPS}
        for each in GROUPS:
            for point in every.select(group=each):
                if re.fullmatch(NAME_PATTERN, point.name):  # else no job or option could name it
                    points[each].setdefault(point.name, point)
        _found = (path, points)
    return _found[1][group]
