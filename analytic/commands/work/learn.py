"""`analytic learn` once it runs: what its function in analytic/commands/learn.py does."""

from pathlib import Path

import click

from gainfarm.analytic.data.learning import LearnError, OutUnwritable
from gainfarm.analytic.data.learning import learn as learn_model
from gainfarm.analytic.data.learning_report import mean_joints, span
from gainfarm.cli.app import CliError


def learn(dataset_dir: Path, out: Path, target: str, kind: str, seed: int) -> None:
    """`analytic learn` with its options as parsed (analytic/commands/learn.py)."""
    try:
        scores = learn_model(dataset_dir, out, target, kind, seed)
    except OutUnwritable as error:
        raise CliError(f"--out: {error}") from None
    except LearnError as error:
        raise CliError(str(error)) from None
    nmse = " ".join(f"{joint} {value:.3f}" for joint, value in scores["nmse"].items())
    averaged = span(mean_joints(tuple(scores["nmse"])))  # A1-A6 on the iiwa 14
    calm = scores["calm"]
    calm_text = f", calm {calm['nmse_mean']:.4f}" if calm and calm["rows"] < scores["rows"] else ""
    click.echo(
        f"{out}: {kind} {target} model, test nMSE {scores['nmse_mean']:.4f}{calm_text} "
        f"(mean over {averaged}; the plant's own dynamics {scores['floor']['nmse_mean']:.4f}, the "
        f"rigid prior {scores['prior']['nmse_mean']:.3f}, the mean "
        f"{scores['mean_predictor_nmse']:.2f}) · {nmse}"
    )
