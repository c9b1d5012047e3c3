"""What an objective declares: its name, unit, direction, a line for reports, and the score of a
candidate with no episode; the scoring function it wraps.

Every objective is one of these, the built-ins (f_acc, f_t, f_t_joint: a module each beside this
one) as a third party's (an entry point of the gainfarm.objectives group naming its
`Objective`). The declaration is what lets a run's files, figures and reports say what a column
is: front.csv's header carries the name, a figure's axis the name and unit, report.md the line.

A bare function `objective(log) -> float` still serves (`declared` wraps it), minimised, with no
unit: a report then says the unit is not declared. The declared form is the way (docs/plugins.md).

A maximised objective is told to the optimiser negated (`minimised`), so that everything that
ranks (the optimiser, the hypervolume, the picks, a robust run's worst plant) ranks as for one
minimised; a run's files and reports write it in its own sense (`minimised` is its own inverse).
"""

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.trajectory import KIND_PATTERN

MINIMISE = "minimise"
MAXIMISE = "maximise"
Direction = Literal["minimise", "maximise"]
DIRECTIONS = (MINIMISE, MAXIMISE)

# The no-episode score of a bare function: far beyond what a real objective reaches, as the
# paper's f_t's (NO_EPISODE).
BARE_NO_EPISODE = 1e12

Function = Callable[[EpisodeLog], float]


@dataclass(frozen=True)
class Objective:
    """An objective: `function` scores an episode's decoded log; the rest says what that is.

    name         its name in the gainfarm.objectives group (KIND_PATTERN: it names columns)
    unit         of its value, as reports print it ("" when not declared: a bare function)
    direction    MINIMISE or MAXIMISE: which way is better
    description  one line for reports: what it measures ("mean squared torque change")
    no_episode   the score of a candidate with no episode (its path out of reach, or lost), in
                 its own sense: worse than any episode's, a diverged one's too, so the optimiser
                 ranks it last

    Calling it scores a log, so it stands wherever its function did.
    """

    name: str
    unit: str
    direction: Direction
    description: str
    no_episode: float
    function: Function = field(repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not re.fullmatch(KIND_PATTERN, self.name):
            raise ValueError(f"objective name {self.name!r} does not match {KIND_PATTERN}")
        if self.direction not in DIRECTIONS:
            raise ValueError(
                f"objective {self.name!r}: direction {self.direction!r} is not one of "
                f"{', '.join(DIRECTIONS)}"
            )
        if not math.isfinite(self.no_episode):
            raise ValueError(f"objective {self.name!r}: no_episode must be finite")
        if not callable(self.function):
            raise ValueError(f"objective {self.name!r}: its function is not callable")

    def __call__(self, log: EpisodeLog) -> float:
        return float(self.function(log))

    def minimised(self, value: float) -> float:
        """`value` as the optimiser is told it (negated if maximised); and back again."""
        return -value if self.direction == MAXIMISE else value

    @property
    def label(self) -> str:
        """Its name and unit, as a column or an axis is labelled: "f_acc (m)"."""
        return f"{self.name} ({self.unit})" if self.unit else self.name

    @property
    def told_no_episode(self) -> float:
        """`no_episode` as the optimiser is told it."""
        return self.minimised(self.no_episode)


def declared(plugin: Any, name: str) -> Objective:
    """The declaration of the objective found under `name`: `plugin` itself if it is one (its
    declared name must be `name`), else a bare function wrapped as minimised, unit unknown.
    ValueError if it is neither."""
    if isinstance(plugin, Objective):
        if plugin.name != name:
            raise ValueError(f"objective {name!r} declares the name {plugin.name!r}")
        return plugin
    if not callable(plugin):
        raise ValueError(f"objective {name!r} is neither an Objective nor a function of the log")
    return Objective(
        name=name,
        unit="",
        direction=MINIMISE,
        description=f"{name} (a plug-in's function: unit and meaning not declared)",
        no_episode=BARE_NO_EPISODE,
        function=plugin,
    )


def unknown(name: str) -> Objective:
    """A stand-in for an objective this installation lacks (a run read where its plug-in is not
    installed): named, unit unknown, taken as minimised; it scores nothing."""

    def absent(log: EpisodeLog) -> float:
        raise ValueError(f"objective {name!r} is not installed here")

    return Objective(
        name=name,
        unit="",
        direction=MINIMISE,
        description=f"{name} (not installed here: unit and meaning unknown)",
        no_episode=BARE_NO_EPISODE,
        function=absent,
    )
