"""A run's report: pareto.png, hypervolume.png and report.md, drawn from where the run stands.

The loop (analytic.tuning.run) only keeps records; what composes a run (`tune`, an
experiment's runner) draws them when it ends, and again whenever asked: the figures are a
function of the records.
"""

from collections.abc import Sequence

from gainfarm.analytic.tuning.check import (
    CHECK_SHARE,
    CheckPlan,
    advice_in,
    advice_of,
    read_check,
)
from gainfarm.analytic.tuning.declared import column_title, declarations, shown_unit
from gainfarm.analytic.tuning.evolution import hypervolume
from gainfarm.analytic.tuning.picks import picks
from gainfarm.analytic.tuning.records import HYPERVOLUME_PNG, PARETO_PNG, REPORT_MD, FrontMember
from gainfarm.analytic.tuning.run import TuningRun
from gainfarm.analytic.view.export import joints_of
from gainfarm.analytic.view.figures import plot_hypervolume, plot_pareto
from gainfarm.analytic.view.reports import run_setup, run_title, write_report
from gainfarm.cli.words import counted
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.episode import DEFAULT_OBJECTIVES
from gainfarm.schemas.limits import DAMPING, MEASURED, MEASURES, UNITS, Limits, tally


def write_run_report(run: TuningRun, figures: bool = True) -> None:
    """`run`'s figures (unless `figures` is False: drawn already, by `draw_figures`) and
    report.md: its front with the recommended member (or the one closest to dominating the
    default gains), the knee, the most accurate and the smoothest member marked, beside the
    default gains if they were evaluated (baseline.json). The run must be open: its directory
    is written."""
    run.check_open()
    if figures:
        draw_figures(run)
    front, baseline = run.front(), run.baseline()
    record = read_check(run.directory)
    chosen = picks(front, baseline, advice_of(record))
    limits = run.config.limits
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
        advice=advice_text(record),
        joints=joints_of(run.config.plant, len(front[0].kp) if front else None),
    )
    report = run.directory / REPORT_MD
    sections = [
        *limits_section(limits, run.state.measured, len(front)),
        *damping_section(front, limits),
        *check_section(record),
    ]
    section = "\n".join(sections)
    write_atomically(report, report.read_bytes().rstrip(b"\n") + b"\n\n" + section.encode())


def draw_figures(run: TuningRun) -> None:
    """`run`'s pareto.png and hypervolume.png: what they show is settled once its evolution
    has ended and its default gains have run (baseline.json), so they may be drawn while its
    held-out check runs. The run must be open."""
    run.check_open()
    front, title, baseline = run.front(), run_title(run.config), run.baseline()
    chosen = picks(front, baseline, advice_in(run.directory))
    limits = run.config.limits
    # The cloud of candidates within the limits: the others are not controllers to use.
    within = [
        point
        for point, values in zip(run.state.evaluated, run.state.measured, strict=True)
        if not limits.violated(values)
    ]
    plot_pareto(
        run.directory / PARETO_PNG,
        front,
        within,
        title=title,
        picks=chosen,
        baseline=baseline,
        infeasible=len(run.state.evaluated) - len(within),
        names=run.config.objectives,
    )
    level = None
    if baseline is not None and not baseline.diverged:
        level = hypervolume([baseline.objectives], run.config.reference_point)
    plot_hypervolume(run.directory / HYPERVOLUME_PNG, run.state.history, title, level)


def limits_line(limits: Limits, measured: Sequence[Sequence[float]], front: int) -> str:
    """How many candidates broke the limits, and which: one line, for the report and stderr."""
    infeasible, counts = tally(limits, measured)
    why = ", ".join(f"{name} {count}" for name, count in counts.items() if count)
    line = f"{infeasible} of {counted(len(measured), 'candidate')} broke a safety limit"
    line += f" ({why})" if why else ""
    if measured and not front:
        line += "; none met them all: the front is empty"
    return line


def limits_section(limits: Limits, measured: Sequence[Sequence[float]], front: int) -> list[str]:
    """report.md's section on the safety limits: what each candidate was checked against, and
    how many broke each (docs/limits.md)."""
    _, counts = tally(limits, measured)
    lines = [
        "## Safety limits",
        "",
        f"{limits_line(limits, measured, front)}. A candidate that breaks one on any episode is "
        "infeasible: it is on no front, in no export and in no dataset (docs/limits.md). Each "
        "limit, and how many candidates broke it:",
        "",
        "| limit | allowed | unit | candidates beyond it |",
        "|---|---|---|---|",
    ]
    for name, limit in zip(MEASURES, limits.values(), strict=True):
        shown = "not checked" if limit is None else f"at most {limit:g}"
        lines.append(f"| {name} | {shown} | {UNITS[name]} | {counts[name]} |")
    bound = limits.min_damping
    shown = "not checked" if bound is None else f"at least {bound:g}"
    lines.append(f"| {DAMPING} | {shown} | {UNITS[DAMPING]} | {counts.get(DAMPING, 0)} |")
    return [*lines, ""]


def damping_section(front: Sequence[FrontMember], limits: Limits) -> list[str]:
    """report.md's section on each front member's damping margin (worker.stability): the least
    damping ratio of its closed loop over the poses of all its episodes."""
    damping = MEASURED.index(DAMPING)
    objectives = declarations(front[0].names if front else DEFAULT_OBJECTIVES)
    checked = (
        "not a constraint of this run (`--min-damping` makes it one)"
        if limits.min_damping is None
        else f"a constraint of this run: at least {limits.min_damping:g}"
    )
    lines = [
        "## Damping margin",
        "",
        "Each front member's least damping ratio: its closed loop linearised at poses along "
        "each of its references, the least over their modes (≤ 0: unstable there; "
        f"docs/limits.md). It is {checked}.",
        "",
        f"| # | {' | '.join(column_title(o) for o in objectives)} | least damping ratio |",
        "|---|---|---|---|",
    ]
    for row, member in enumerate(front, start=1):  # front.csv's rows, as every table
        least = member.measures[damping] if len(member.measures) > damping else None
        shown = "not measured" if least is None else f"{least:.4f}"
        values = " | ".join(
            f"{member.named[o.name] * shown_unit(o)[1]:{'.2f' if o.unit == 'm' else '.4g'}}"
            for o in objectives
        )
        lines.append(f"| {row} | {values} | {shown} |")
    return [*lines, ""]


def _mm(metres: float) -> str:
    return f"{metres * 1e3:.2f}"


def _controller(record: dict, which: str) -> dict | None:
    """The checked controller named `which` (its pick's name, "default gains"), if any."""
    return next((item for item in record.get("controllers", ()) if item["name"] == which), None)


def advice_text(record: dict | None) -> str | None:
    """report.md's first line from the held-out check: the controller to use with its held-out
    errors in mm beside the default gains', or that the default gains are, and why; None for
    no check, or one from before the check gave advice (the run's own recommendation then)."""
    if not record or "advice" not in record:
        return None
    default = _controller(record, "default gains")
    if default is None:
        return None
    on = check_plants_text(record["plants"], record.get("asked"))
    theirs = (
        f"the default gains' {_mm(default['median_f_acc'])} mm and {_mm(default['worst_f_acc'])} mm"
    )
    if default["nominal_failed"]:
        theirs += " (their nominal episode failed)"
    chosen = _controller(record, "recommended")
    if chosen is not None:
        return (
            f"**Use front.csv row {chosen['row']}**: on {on} its mean error is "
            f"{_mm(chosen['median_f_acc'])} mm at the median and {_mm(chosen['worst_f_acc'])} mm "
            f"at worst, against {theirs}; it broke no limit and diverged on none, and on the "
            f"nominal plant it dominates them ({_mm(chosen['nominal_f_acc'])} mm, "
            f"{chosen['nominal_f_t']:.4g} against {_mm(default['nominal_f_acc'])} mm, "
            f"{default['nominal_f_t']:.4g})."
        )
    tried = [item for item in record["controllers"] if item["name"] == "candidate"]
    if not tried:
        return (
            f"**Keep the default gains** ({_mm(default['median_f_acc'])} mm median, "
            f"{_mm(default['worst_f_acc'])} mm worst on {on}): no member of the front but them "
            "beats them on the run's own plants."
        )
    best = tried[0]
    return (
        f"**Keep the default gains**: of the members that beat them on the run's own plants, "
        f"the {counted(len(tried), 'one')} checked on {on} did not hold against "
        f"{theirs} (median and worst error). The first, row {best['row']}: "
        f"{'; '.join(best['failed'])}."
    )


def check_section(record: dict | None) -> list[str]:
    """report.md's lines on the held-out check (none without one), in absolute terms."""
    if not record:
        return []
    lines = [
        "## Held-out plants",
        "",
        "Each controller below ran every trajectory on the nominal plant and on "
        f"{check_plants_text(record['plants'], record.get('asked'))}, drawn from the "
        "uncertainty ranges on a stream of the seed the run never tuned on (check.json). The "
        "members that beat the default gains on the run's own plants are checked in the knee's "
        "order until one holds: it dominates the defaults on the nominal plant, its median and "
        "worst held-out errors are at most theirs, it breaks no limit and diverges on none "
        "(docs/tuning.md). Errors are the mean Cartesian error of an episode, mm.",
        "",
        "| controller | front.csv row | nominal f_acc | nominal f_t | held-out median | "
        "held-out worst | plants over a limit | plants diverged | tracking ζ | "
        "tracking ζ, command late | delay margin (ticks) | why not |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for item in record["controllers"]:
        if "median_f_acc" not in item:  # a check from before it was absolute
            continue
        row = "–" if item["row"] is None else item["row"]
        nominal = "failed" if item["nominal_failed"] else _mm(item["nominal_f_acc"])
        lines.append(
            f"| {item['name']} | {row} | {nominal} | {item['nominal_f_t']:.4g} | "
            f"{_mm(item['median_f_acc'])} | {_mm(item['worst_f_acc'])} | {item['violations']} | "
            f"{item['diverged']} | {_margins_cells(item.get('margins'))} | "
            f"{'; '.join(item.get('failed', ())) or '–'} |"
        )
    cost = record.get("cost", {})
    episodes = cost.get("episodes")
    spent = "? episodes" if episodes is None else counted(episodes, "episode")
    lines += [
        "",
        "Margins, on the nominal plant (worker.stability, docs/limits.md): the least damping "
        "ratio of the closed loop's tracking modes, at the plant's delay and with the command as "
        "late as the run's latest plant; the delay margin is the extra ticks of delay the "
        "tracking modes take and stay stable (−1: unstable already).",
        "",
        f"It cost {spent}, {cost.get('wall_seconds', '?')} s.",
        "",
    ]
    return lines


def _margins_cells(margins: dict | None) -> str:
    """A checked controller's margins as three table cells."""
    if not margins:
        return "– | – | –"
    late = counted(margins["delay"], "tick")
    return (
        f"{margins['tracking']:.3f} ({margins['tracking_hz']:.1f} Hz) | "
        f"{margins['tracking_at_delay']:.3f} ({late} late) | {margins['delay_margin']}"
    )


# CHECK_SHARE in words, for the line that says why a check ran on fewer plants than asked.
_SHARES = {0.5: "half"}


def check_cap_text() -> str:
    """Why a check can run on fewer held-out plants than asked."""
    share = _SHARES.get(CHECK_SHARE, f"{CHECK_SHARE:.0%} of")
    return f"the check may take at most {share} the run's own episodes"


def check_plants_text(plants: int, asked: int | None = None) -> str:
    """The held-out plants a check ran on: "64 held-out plants", or, when the budget cut them,
    "1 of the 64 held-out plants asked (the check may take at most half the run's own
    episodes)". `asked` is None in a check.json from before it was recorded."""
    if asked is None or plants >= asked:
        return counted(plants, "held-out plant")
    return f"{plants} of the {asked} held-out plants asked ({check_cap_text()})"


def _plants_short(plants: int, asked: int | None) -> str:
    """The terminal's: "64 held-out plants", "1 of the 64 held-out plants asked"."""
    if asked is None or plants >= asked:
        return counted(plants, "held-out plant")
    return f"{plants} of the {asked} held-out plants asked"


def check_start_line(plan: CheckPlan) -> str:
    """The terminal's line as the held-out check starts (within 80 columns)."""
    return (
        f"held-out check: {counted(plan.episodes, 'episode')} on "
        f"{_plants_short(plan.plants, plan.asked)}"
    )


def held_out_lines(record: dict, row: int | None) -> list[str]:
    """The held-out check's result for the controller at front.csv row `row` (None: the
    default gains) beside the default gains', for the terminal's closing lines, each within 80
    columns; none if it was not checked."""
    default = _controller(record, "default gains")
    for item in record.get("controllers", []):
        if item["row"] != row or "median_f_acc" not in item:
            continue
        plants, asked = record["plants"], record.get("asked")
        cut = asked is not None and plants < asked
        on = f"{plants} of the {asked} plants asked" if cut else counted(plants, "plant")
        lines = [
            f"held out, on {on}: error {_mm(item['median_f_acc'])} mm median, "
            f"{_mm(item['worst_f_acc'])} mm worst"
        ]
        if default is not None and row is not None:
            lines.append(
                f"  (default gains: {_mm(default['median_f_acc'])} mm, "
                f"{_mm(default['worst_f_acc'])} mm)"
            )
        if cut:
            lines.append(f"  ({check_cap_text()})")
        lines.append(
            f"held out: {counted(item['violations'], 'plant')} broke a limit, "
            f"{item['diverged']} diverged"
        )
        return lines
    return []
