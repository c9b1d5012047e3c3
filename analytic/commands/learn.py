"""`analytic learn`: a model of the arm's dynamics, learned from a dataset."""

from pathlib import Path
from typing import Any

import click

# Held here, not imported, so that parsing and --help load nothing heavy: tests/analytic/commands/
# test_held_defaults.py keeps each equal to its source's.
# models.dynamics's TARGETS and KINDS; analytic.data.learning.learn's defaults
TARGETS = ("inverse", "forward")
KINDS = ("rigid", "linear", "mlp", "residual", "plant")
TARGET, KIND, SEED = "inverse", "residual", 0


@click.command()
@click.argument("dataset_dir", metavar="DATASET", type=click.Path(path_type=Path))
@click.option(
    "--out", type=click.Path(path_type=Path), required=True, help="model directory to write"
)
@click.option(
    "--target",
    type=click.Choice(TARGETS),
    default=TARGET,
    show_default=True,
    help="inverse: torque u from (q, q̇, q̈); forward: q̈ from (q, q̇, u)",
)
@click.option(
    "--kind",
    type=click.Choice(KINDS),
    default=KIND,
    show_default=True,
    help="rigid: the rigid-body physics prior, untrained; linear: its parameters identified "
    "by least squares; mlp: a network; residual: the prior plus a network of what it misses; "
    "plant: the simulated plant's own dynamics (payload and friction too), the anchor",
)
@click.option("--seed", type=click.IntRange(min=0), default=SEED, show_default=True)
def learn(**given: Any) -> None:
    """Learn the arm's dynamics from a dataset's train split; score on its test split.

    Writes OUT/model.npz (what --feedforward takes), scores.json (nMSE and RMSE per joint),
    report.md and prediction.png.
    """
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.learn import learn as work

    work(**given)
