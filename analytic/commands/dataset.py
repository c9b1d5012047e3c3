"""`analytic dataset`: tuned controllers' episodes gathered into a dataset."""

from pathlib import Path
from typing import Any

import click

from gainfarm.analytic.commands.shared import farm_options, prechecked

# Held here, not imported, so that parsing and --help load nothing heavy: tests/analytic/commands/
# test_held_defaults.py keeps each equal to its source's.
SPLIT = (0.6, 0.2, 0.2)  # analytic.data.dataset.DEFAULT_SPLIT


@click.command()
@click.argument("run_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), required=True, help="dataset directory")
@click.option(
    "--select",
    "selection",
    type=click.Choice(["front", "knee"]),
    default="front",
    show_default=True,
    help="every Pareto-front controller, or each run's knee",
)
@click.option(
    "--split",
    "split_text",
    metavar="TRAIN,VALIDATION,TEST",
    default=",".join(f"{value:g}" for value in SPLIT),
    show_default=True,
    help="fractions of the trajectories in each part: the split is by trajectory, never by tick",
)
@click.option(
    "--split-seed",
    type=click.IntRange(min=0),
    default=0,
    show_default=True,
    help="seed of the order the trajectories are dealt into the split in",
)
@click.option(
    "--rerun",
    "rerun_file",
    type=click.Path(path_type=Path),
    help="JSON list of trajectories (TrajectorySpec objects): run every selected controller once "
    "more on each, through the farm (a local one unless --connect), and add those episodes",
)
@click.option(
    "--excitations",
    type=click.IntRange(min=0, max=10_000),
    default=0,
    show_default=True,
    help="add N fourier excitations (10 s each, seeds 0 to N-1) to the rerun's trajectories",
)
@click.option(
    "--plants",
    type=click.IntRange(min=0, max=100),
    default=0,
    show_default=True,
    help="rerun on each run's plant and on K variants of it, drawn from the plant's "
    "uncertainty ranges (models/uncertainty.toml, held-out stream, seed --split-seed)",
)
@click.option(
    "--infeasible",
    is_flag=True,
    help="keep controllers that break their run's safety limits on an episode (a run from "
    "before the limits, or on a --rerun trajectory); their rows say so (within_limits)",
)
@click.option(
    "--include-rough",
    is_flag=True,
    help="keep episodes that chatter or diverged (clean by construction: left out unless "
    "asked); their rows say so (calm false)",
)
@click.option(
    "--release",
    "release_name",
    metavar="NAME",
    help="make the dataset a frozen release NAME: release.json (content hash, fixed splits), "
    "stats.json (train only), baselines.json and the card's baselines (needs gainfarm[learn])",
)
@click.option(
    "--format",
    "release_format",
    type=click.Choice(["gainfarm", "lerobot"]),
    default="gainfarm",
    show_default=True,
    help="lerobot: the release also in LeRobot's v3.0 layout, in DIR/lerobot/ (with --release)",
)
@click.option(
    "--baselines",
    "baselines_text",
    metavar="KIND,...",
    help="with --release: the baseline models its card scores  [default: every one: plant, "
    "rigid, linear, mlp, residual, gp, history]",
)
@farm_options
def dataset(**given: Any) -> None:
    """Gather tuned controllers' episodes into a dataset: MCAP logs, Parquet tables, a card."""
    prechecked(given, "run_dirs")  # before the work's imports: the contract, MuJoCo, Zenoh, pymoo
    # start-up: the work loads when the command runs, not to parse it or show its --help
    from gainfarm.analytic.commands.work.dataset import dataset as work

    work(**given)
