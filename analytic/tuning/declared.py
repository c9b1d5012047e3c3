"""A run's objectives as declared: what its names in `RunConfig.objectives` are, for the records,
figures and reports to label their columns and axes with (schemas/objectives/declaration.py).

A built-in's declaration is gainfarm's own; a plug-in's is loaded from where it is installed. A
run read where its plug-in is not installed (a colleague's run directory) still reads: its
objective is then named, its unit and meaning unknown, and taken as minimised.
"""

from collections.abc import Sequence
from typing import Any

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


# How a value in a unit is shown to a person: lengths in mm (a tracking error is millimetres),
# with the digits the paper's tables use; any other unit as it is, to 4 significant digits.
SHOWN = {"m": ("mm", 1000.0, "{:.3f}")}
PLAIN = "{:.4g}"


def shown_unit(objective: Objective) -> tuple[str, float]:
    """The unit `objective` is shown in, and the factor from its own: ("mm", 1000) for m."""
    unit, factor, _ = SHOWN.get(objective.unit, (objective.unit, 1.0, PLAIN))
    return unit, factor


def number_text(objective: Objective, value: float) -> str:
    """`value` (its own sense) as a table's cell shows it, in `shown_unit`: "12.345", "0.1234"."""
    _, factor, form = SHOWN.get(objective.unit, (objective.unit, 1.0, PLAIN))
    return form.format(value * factor)


def value_text(objective: Objective, value: float) -> str:
    """`value` (its own sense) as a person reads it: "12.345 mm", "0.1234 (N·m)²", "3.2" (no
    unit declared)."""
    return f"{number_text(objective, value)} {shown_unit(objective)[0]}".strip()


def column_title(objective: Objective) -> str:
    """A table's column for `objective`: "f_acc (mm)", "f_t ((N·m)²)", "peak" (no unit)."""
    unit, _ = shown_unit(objective)
    return f"{objective.name} ({unit})" if unit else objective.name


def point_text(point: Any, name_first: bool = False) -> str:
    """A front member's or baseline's objectives (`.named`) as reports say them: the paper's
    "12.345 mm, f_t 0.1234 (N·m)²" (f_acc unnamed unless `name_first`), each other objective
    named before its value."""
    texts = []
    for objective in declarations(tuple(point.named)):
        text = value_text(objective, point.named[objective.name])
        unnamed = objective.name == "f_acc" and not name_first and not texts
        texts.append(text if unnamed else f"{objective.name} {text}")
    return ", ".join(texts)


def axis_label(objective: Objective) -> str:
    """A figure's axis for `objective`: "f_t: mean squared torque change per tick ((N·m)²)"."""
    unit, _ = shown_unit(objective)
    described = f"{objective.name}: {objective.description}"
    return f"{described} ({unit})" if unit else described
