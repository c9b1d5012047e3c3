"""Scores as a person reads them, or as one JSON object: what `worker episode` and
`analytic evaluate` print for an episode log."""

import json
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from gainfarm.schemas.episode import Scores
from gainfarm.schemas.objectives import DIVERGED_TICK_ERROR

# Why a diverged episode's mean error can exceed its largest: said wherever scores are shown.
DIVERGED_TEXT = (
    "diverged: the episode was stopped early; every tick it did not run is charged "
    f"{DIVERGED_TICK_ERROR:g} m of error and the largest possible torque change, so f_acc and "
    "f_t are a penalty, not a measurement (f_acc can exceed the max error measured)"
)


def show_scores(scores: Scores, log: Path, as_json: bool) -> None:
    """One JSON object (the scores and the log's path) with `as_json`, else a table."""
    if as_json:
        click.echo(json.dumps({**scores.model_dump(), "log": str(log)}))
    else:
        print_scores(scores, source=str(log))


def print_scores(scores: Scores, source: str) -> None:
    """`source` on a line of its own, then the scores as a table."""
    table = Table(show_header=False)
    table.add_row("f_acc", f"{scores.f_acc * 1000:.3f} mm", "mean end-effector error")
    table.add_row("f_t", f"{scores.f_t:.4g} (N·m)²", "mean squared torque change per tick")
    table.add_row("max error", f"{scores.max_error * 1000:.3f} mm", "")
    table.add_row("saturated", f"{scores.saturated_fraction:.1%}", "of ticks, any joint")
    table.add_row("diverged", "yes" if scores.diverged else "no", f"{scores.ticks} ticks run")
    console = Console()
    print_title(console, source)
    console.print(table)
    if scores.diverged:
        console.print(DIVERGED_TEXT, highlight=False)


def print_title(console: Console, title: str) -> None:
    """A table's title on its own line, as rich styles one, but not padded to the table's width
    with trailing spaces (rich's own title is): a path, to be copied as it is."""
    console.print(title, style="table.title", highlight=False, soft_wrap=True)
