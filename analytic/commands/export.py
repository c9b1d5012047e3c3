"""`analytic export`: a run's controller, out of the run."""

from pathlib import Path

import click

from gainfarm.cli.app import CliError
from gainfarm.cli.options import LazyChoice


def _formats() -> tuple[str, ...]:
    from gainfarm.analytic.view.export import FORMATS

    return FORMATS


@click.command()
@click.argument("run_dir", metavar="RUN", type=click.Path(path_type=Path))
@click.option(
    "--member",
    default="recommended",
    show_default=True,
    metavar="recommended|knee|accurate|smooth|N",
    help="which front member: the recommended one (the best compromise among those that "
    "dominate the default gains; refused if none does), the knee (the best compromise of the "
    "whole front), the most accurate, the smoothest, or row N of front.csv (the report's #)",
)
@click.option(
    "--format",
    "fmt",
    type=LazyChoice(_formats),
    default="json",
    show_default=True,
    help="json: what `analytic batch --gains` and `worker episode --gains` read; yaml: the "
    "same document; ros2_control: a controller_manager parameter file running the gains as a "
    "PD on the effort interface",
)
@click.option(
    "--out", type=click.Path(path_type=Path), help="file to write  [default: standard output]"
)
def export(run_dir: Path, member: str, fmt: str, out: Path | None) -> None:
    """Write a run's controller: one front member's gains, with its joints, units, scores and
    the run it came from."""
    from gainfarm.analytic.view.export import BadMember, BadRun, member_text
    from gainfarm.analytic.view.export import controller as exported_controller
    from gainfarm.analytic.view.export import render as render_controller
    from gainfarm.edges.files import write_atomically

    try:
        chosen = exported_controller(run_dir, member)
    except BadRun as error:
        raise CliError(str(error)) from None
    except BadMember as error:
        raise CliError(f"--member: {error}") from None
    content = render_controller(chosen, fmt)
    if out is None:
        click.echo(content.decode(), nl=False)
        return
    if not out.parent.is_dir():
        raise CliError(f"--out: directory {str(out.parent)!r} does not exist")
    try:
        write_atomically(out, content)
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror or error}") from None
    click.echo(
        f"{out}: {chosen.member.selected} of {run_dir} (front.csv row {chosen.member.row}: "
        f"{member_text(chosen.member, name_first=False)}), {fmt}",
        err=True,
    )
