"""`analytic learn`: a model of the arm's dynamics, learned from a dataset."""

import inspect
from pathlib import Path
from typing import Any

import click

from gainfarm.cli.options import Later, LazyChoice


def _targets() -> tuple[str, ...]:
    from gainfarm.models.dynamics import TARGETS

    return TARGETS


def _kinds() -> tuple[str, ...]:
    from gainfarm.models.dynamics import KINDS

    return KINDS


def _default(parameter: str) -> object:
    """The default of `learn`'s `parameter`: the library's, said once."""
    from gainfarm.analytic.data.learning import learn

    return inspect.signature(learn).parameters[parameter].default


@click.command()
@click.argument("dataset_dir", metavar="DATASET", type=click.Path(path_type=Path))
@click.option(
    "--out", type=click.Path(path_type=Path), required=True, help="model directory to write"
)
@click.option(
    "--target",
    type=LazyChoice(_targets),
    default=Later(lambda: _default("target")),
    show_default=True,
    help="inverse: torque u from (q, q̇, q̈); forward: q̈ from (q, q̇, u)",
)
@click.option(
    "--kind",
    type=LazyChoice(_kinds),
    default=Later(lambda: _default("kind")),
    show_default=True,
    help="rigid: the rigid-body physics prior, untrained; linear: its parameters identified "
    "by least squares; mlp: a network; residual: the prior plus a network of what it misses; "
    "plant: the simulated plant's own dynamics (payload and friction too), the anchor",
)
@click.option(
    "--seed", type=click.IntRange(min=0), default=Later(lambda: _default("seed")), show_default=True
)
def learn(**given: Any) -> None:
    """Learn the arm's dynamics from a dataset's train split; score on its test split.

    Writes OUT/model.npz (what --feedforward takes), scores.json (nMSE and RMSE per joint),
    report.md and prediction.png.
    """
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.learn import learn as work

    work(**given)
