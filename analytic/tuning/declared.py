"""A run's objectives as declared: what its names in `RunConfig.objectives` are, for the records,
figures and reports to label their columns and axes with (schemas/objectives/declaration.py).

A built-in's declaration is gainfarm's own; a plug-in's is loaded from where it is installed. A
run read where its plug-in is not installed (a colleague's run directory) still reads: its
objective is then named, its unit and meaning unknown, and taken as minimised.
"""

from collections.abc import Sequence

from gainfarm import plugins
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.objectives import MAXIMISE, Objective, declared, unknown


def _declaration(name: str) -> Objective:
    # Not cached: a plug-in registered in-process may be replaced; plugins.load caches the
    # installed ones' imports.
    try:
        found = plugins.load(plugins.OBJECTIVES, name)
    except plugins.PluginError:
        return unknown(name)
    return declared(found, name)


def declarations(names: Sequence[str] = DEFAULT_OBJECTIVES) -> tuple[Objective, ...]:
    """The declaration of each objective named, in order. ValueError if an installed plug-in's
    is not an objective (nor a function) or declares another name."""
    return tuple(_declaration(name) for name in names)


def maximised(names: Sequence[str]) -> tuple[str, ...]:
    """Those of `names` whose objective is maximised (told the optimiser negated)."""
    return tuple(
        objective.name for objective in declarations(names) if objective.direction == MAXIMISE
    )
