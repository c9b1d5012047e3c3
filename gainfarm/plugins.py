"""Plug-ins: optimisers, trajectory kinds, objectives, experiments and robots, gainfarm's own
built-ins and those added without editing gainfarm, through the same seams.

Five groups, each a namespace of names (docs/plugins.md says what each provides):

    gainfarm.algorithms     an optimiser: factory(pop_size, seed, space) -> ask and tell object
    gainfarm.trajectories   a trajectory kind: a Kind (worker/trajectories/), or a path
                            function path(spec, u) -> the flange's offsets, m
    gainfarm.objectives     an objective: objective(log) -> float, lower is better
    gainfarm.experiments    an experiment `analytic experiment NAME` runs
    gainfarm.robots         an arm: its model builder, limits, default gains, gravity model,
                            workspace

A plug-in enters a group by a Python entry point of the distribution that holds it, as pytest's
plug-ins do (its pyproject.toml: `[project.entry-points."gainfarm.objectives"]` then
`peak_torque = "mypkg.objectives:peak_torque"`), or in one process by `register`.

The built-in ones enter the same way: gainfarm's own pyproject.toml declares each in its group,
one module each, and they are read from gainfarm's installed metadata with everyone else's. Their
names are reserved for gainfarm's own distribution: `register` refuses one, and another
distribution's entry point that takes one is ignored. (An installation's metadata is written when
it is installed: a built-in added to pyproject.toml since needs `pip install -e .` again, and
`PluginError` says so.)

Cheap to import (the standard library only, nothing of the project, no plug-in), because command
lines whose start-up is measured import it: `names` reads the installed distributions' metadata
(once a process, again only when sys.path changes) without importing any plug-in; `load`
imports the one asked for.
"""

import re
import sys
from collections.abc import Iterable
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

GROUPS = (ALGORITHMS, TRAJECTORIES, OBJECTIVES, EXPERIMENTS, ROBOTS)
# The distribution whose entry points are the built-ins.
DISTRIBUTION = "gainfarm"
# The order command lines and experiments list a group's built-ins in, the default first (an
# installation's metadata keeps none of its own): names only, their entry points say where each
# is. A built-in missing here is listed after these, by name; one here that the metadata lacks
# is an installation older than this source (`_unknown` says so).
ORDER: dict[str, tuple[str, ...]] = {
    ALGORITHMS: ("nsga2", "nsga3", "smsemoa", "moead", "agemoea2", "tpe", "random"),
    TRAJECTORIES: ("spiral", "random", "pyramid", "fourier"),
    OBJECTIVES: ("f_acc", "f_t", "f_t_joint"),  # the paper's pair first
    EXPERIMENTS: (
        "popsize",
        "generic-vs-specific",
        "speed",
        "algorithms",
        "dataset-value",
        "sensitivity",
        "feedforward",
    ),
    ROBOTS: ("iiwa14", "panda", "ur5e", "gen3"),
}


class PluginError(ValueError):
    """A plug-in that cannot be had here: unknown to this installation, or failing to load.
    str() is one line naming the group, the name and what is available."""


_registered: dict[str, dict[str, Any]] = {group: {} for group in GROUPS}
_loaded: dict[tuple[str, str], Any] = {}  # entry points loaded once: a worker loads per job
_Points = dict[str, dict[str, Any]]  # entry points by group, then by name
# sys.path when last scanned, and gainfarm's entry points and the others' then (_scan)
_found: tuple[tuple[str, ...], tuple[_Points, _Points]] | None = None


def register(group: str, name: str, plugin: Any) -> None:
    """Make `plugin` the one named `name` in `group`, in this process only (a farm's workers
    need it installed: an entry point). Registering a name again replaces the earlier one."""
    _check_group(group)
    if not isinstance(name, str) or not re.fullmatch(NAME_PATTERN, name):
        raise ValueError(f"{group}: plug-in name {name!r}: {NAME_RULE}")
    if name in _scan()[0][group]:
        raise ValueError(f"{group}: {name!r} is a built-in name; choose another")
    _registered[group][name] = plugin


def unregister(group: str, name: str) -> None:
    """Forget a plug-in `register` made (nothing if there is none)."""
    _check_group(group)
    _registered[group].pop(name, None)


def builtin_names(group: str) -> tuple[str, ...]:
    """The built-in names of `group` (gainfarm's own entry points), the default first. Reads the
    installation's metadata (once a process), imports nothing."""
    _check_group(group)
    return tuple(_scan()[0][group])


def names(group: str) -> tuple[str, ...]:
    """Every name `group` has here: the built-ins (the default first), then the plug-ins,
    registered or installed, sorted. Imports no plug-in."""
    _check_group(group)
    builtin, installed = _scan()
    others = (set(_registered[group]) | set(installed[group])) - set(builtin[group])
    return (*builtin[group], *sorted(others))


def check_name(group: str, name: str) -> str:
    """`name`, if `group` has it here (no import); PluginError naming what the group has if
    not."""
    _check_group(group)
    builtin, installed = _scan()
    if name in builtin[group] or name in _registered[group] or name in installed[group]:
        return name
    raise _unknown(group, name)


def load(group: str, name: str) -> Any:
    """The plug-in named `name` in `group`: a built-in, one `register`ed in this process, or an
    installed entry point's object. PluginError if there is none, or it fails to load."""
    _check_group(group)
    builtin, installed = _scan()
    if name in _registered[group] and name not in builtin[group]:
        return _registered[group][name]
    if (group, name) in _loaded:
        return _loaded[(group, name)]
    point = builtin[group].get(name) or installed[group].get(name)
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
    builtin = _scan()[0][group]
    return {name: load(group, name) for name in wanted if name not in builtin}


def _unknown(group: str, name: str) -> PluginError:
    missing = [each for each in ORDER[group] if each not in _scan()[0][group]]
    if missing:  # gainfarm's own are not all there: its metadata is older than its source
        return PluginError(
            f"{group}: no plug-in named {name!r} here, and gainfarm's installed metadata lacks "
            f"its own {', '.join(missing)}: reinstall gainfarm (pip install -e . in a checkout)"
        )
    return PluginError(
        f"{group}: no plug-in named {name!r} here (there are {', '.join(names(group))}); "
        "install the distribution that provides it"
    )


def _check_group(group: str) -> None:
    if group not in GROUPS:
        raise ValueError(f"no plug-in group {group!r}: one of {', '.join(GROUPS)}")


def _scan() -> tuple[_Points, _Points]:
    """Every group's entry points by name: gainfarm's own (the built-ins, in ORDER then by
    name) and the other distributions'. All groups are read in one scan of every
    distribution's metadata (tens of ms: too much for each job of a worker), again only when
    sys.path changed. Two distributions giving one name: the first on sys.path wins, as an
    import would; gainfarm's own always does."""
    global _found
    path = tuple(sys.path)
    if _found is None or _found[0] != path:
        from importlib.metadata import entry_points  # start-up: tens of ms, on first look-up

        every = entry_points()  # one scan; .select works on Python 3.11's result and 3.12's
        builtin: _Points = {each: {} for each in GROUPS}
        installed: _Points = {each: {} for each in GROUPS}
        ours: dict[int, bool] = {}  # by distribution: its name is parsed from its metadata
        for each in GROUPS:
            for point in every.select(group=each):
                if not re.fullmatch(NAME_PATTERN, point.name):
                    continue  # no job or option could name it
                if id(point.dist) not in ours:
                    ours[id(point.dist)] = getattr(point.dist, "name", None) == DISTRIBUTION
                (builtin if ours[id(point.dist)] else installed)[each].setdefault(point.name, point)
        for each in GROUPS:
            order = {name: index for index, name in enumerate(ORDER[each])}
            ranked = sorted(builtin[each], key=lambda name: (order.get(name, len(order)), name))
            builtin[each] = {name: builtin[each][name] for name in ranked}
            for name in builtin[each]:
                installed[each].pop(name, None)  # a built-in's name is gainfarm's
        _found = (path, (builtin, installed))
    return _found[1]
