"""A run's report: pareto.png, hypervolume.png and report.md, drawn from where the run stands.

The loop (analytic.tuning.run) only keeps records; what composes a run (`tune`, an
experiment's runner) draws them when it ends, and again whenever asked: the figures are a
function of the records.
"""

from gainfarm.analytic.tuning.picks import picks
from gainfarm.analytic.tuning.records import HYPERVOLUME_PNG, PARETO_PNG, REPORT_MD
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.view.figures import plot_hypervolume, plot_pareto
from gainfarm.analytic.view.reports import run_setup, run_title, write_report


def write_run_report(run: TuningRun) -> None:
    """`run`'s figures and report.md: its front with the recommended member (or the one closest
    to dominating the default gains), the knee, the most accurate and the smoothest member
    marked, beside the default gains if they were evaluated (baseline.json). The run must be
    open: its directory is written."""
    run.check_open()
    front, title, baseline = run.front(), run_title(run.config), run.baseline()
    chosen = picks(front, baseline)
    plot_pareto(
        run.directory / PARETO_PNG,
        front,
        run.state.evaluated,
        title=title,
        picks=chosen,
        baseline=baseline,
    )
    plot_hypervolume(run.directory / HYPERVOLUME_PNG, run.state.history, title=title)
    write_report(
        run.directory / REPORT_MD,
        title=f"gainfarm run {run.directory.name}",
        config_lines=run_setup(run.config),
        history=run.state.history,
        front=front,
        converged=run.state.stopped or "stopped before it ended",
        picks=chosen,
        baseline=baseline,
        run_dir=str(run.directory),
        validation=run.validation(),
    )
