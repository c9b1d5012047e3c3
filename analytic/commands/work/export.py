"""`analytic export` once it runs: what its function in analytic/commands/export.py does."""

from pathlib import Path

import click

from gainfarm.analytic.tuning.records import CONFIG_JSON
from gainfarm.cli.app import CliError
from gainfarm.edges.files import write_atomically


def export(run_dir: Path, member: str, fmt: str, out: Path | None, robot: str | None) -> None:
    """`analytic export` with its options as parsed (analytic/commands/export.py)."""
    if not (run_dir / CONFIG_JSON).is_file():
        raise CliError(f"{str(run_dir)!r} holds no run (no {CONFIG_JSON})")
    if out is not None and not out.parent.is_dir():
        raise CliError(f"--out: directory {str(out.parent)!r} does not exist")
    # start-up: the run's records load (pymoo, MuJoCo) once the options are checked
    from gainfarm.analytic.view import export as exporting

    try:
        chosen = exporting.controller(run_dir, member)
    except exporting.BadRun as error:
        raise CliError(str(error)) from None
    except exporting.BadMember as error:
        raise CliError(f"--member: {error}") from None
    if robot is not None and robot != chosen.robot:
        raise CliError(f"--robot: {str(run_dir)!r} is a run of {chosen.robot}, not of {robot}")
    content = exporting.render(chosen, fmt)
    if out is None:
        click.echo(content.decode(), nl=False)
        return
    try:
        write_atomically(out, content)
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror or error}") from None
    click.echo(
        f"{out}: {chosen.member.selected} of {run_dir} (front.csv row {chosen.member.row}: "
        f"{exporting.member_text(chosen.member, name_first=False)}), {fmt}",
        err=True,
    )
