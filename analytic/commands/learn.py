"""`analytic learn`: a model of the arm's dynamics, learned from a dataset."""

import inspect
from pathlib import Path

import click

from gainfarm.cli.app import CliError
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
def learn(dataset_dir: Path, out: Path, target: str, kind: str, seed: int) -> None:
    """Learn the arm's dynamics from a dataset's train split; score on its test split.

    Writes OUT/model.npz (what --feedforward takes), scores.json (nMSE and RMSE per joint),
    report.md and prediction.png.
    """
    from gainfarm.analytic.data.learning import LearnError, OutUnwritable
    from gainfarm.analytic.data.learning import learn as learn_model

    try:
        scores = learn_model(dataset_dir, out, target, kind, seed)
    except OutUnwritable as error:
        raise CliError(f"--out: {error}") from None
    except LearnError as error:
        raise CliError(str(error)) from None
    nmse = " ".join(f"{joint} {value:.3f}" for joint, value in scores["nmse"].items())
    calm = scores["calm"]
    calm_text = f", calm {calm['nmse_mean']:.4f}" if calm and calm["rows"] < scores["rows"] else ""
    click.echo(
        f"{out}: {kind} {target} model, test nMSE {scores['nmse_mean']:.4f}{calm_text} "
        f"(mean over A1-A6; the plant's own dynamics {scores['floor']['nmse_mean']:.4f}, the "
        f"rigid prior {scores['prior']['nmse_mean']:.3f}, the mean "
        f"{scores['mean_predictor_nmse']:.2f}) · {nmse}"
    )
