"""`analytic export` once it runs: what its function in analytic/commands/export.py does."""

from pathlib import Path

import click

from gainfarm.analytic.view.export import BadMember, BadRun
from gainfarm.analytic.view.export import controller as exported_controller
from gainfarm.analytic.view.export import render as render_controller
from gainfarm.cli.app import CliError
from gainfarm.edges.files import write_atomically


def export(run_dir: Path, member: str, fmt: str, out: Path | None) -> None:
    """`analytic export` with its options as parsed (analytic/commands/export.py)."""
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
        f"{chosen.member.f_acc * 1000:.3f} mm, f_t {chosen.member.f_t:.4g} (N·m)²), {fmt}",
        err=True,
    )
