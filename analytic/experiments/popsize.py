"""The paper's population-size experiment: for each population size, `reps` runs (seed = rep)
on the base trajectory, each to its own stop; their final hypervolumes (in one normalised space,
"all runs") and the evaluations each took, each size against the next smaller one.

Written: results.csv (a row per run), stats.csv, normalisation.json, popsize.png and report.md.
"""

import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path

from gainfarm.analytic.experiments import statistics as stats
from gainfarm.analytic.experiments.base import (
    Experiment,
    ExperimentSpec,
    Option,
    Point,
    attainment_panel,
    front_points,
    levels_off,
    markdown_table,
    numbers,
    step_comparisons,
)
from gainfarm.analytic.tuning import defaults
from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.view.figures import new_figure, save_png

NAME = "popsize"
SIZES = (10, 20, 30, 50, 80)
FIGURE = "popsize.png"
SPACE = "all runs"  # the one problem: normalisation.json's key


def run(experiment: Experiment, base: RunConfig, reps: int, sizes: Sequence[int] = SIZES) -> None:
    """Evaluations to converge and final hypervolume, for each population size."""
    plan = {
        (size, rep): (f"pop{size}-rep{rep}", base.model_copy(update={"pop": size, "seed": rep}))
        for size in sizes
        for rep in range(reps)
    }
    tuned = experiment.tune_many(dict(plan.values()))
    runs = {key: tuned[name] for key, (name, _) in plan.items()}
    fronts = {key: front_points(record) for key, record in runs.items()}
    normalisation = experiment.normalisation(list(fronts.values()))
    experiment.write_normalisation({SPACE: normalisation})
    rows = [
        {
            "pop": size,
            "rep": rep,
            "seed": rep,
            "evaluations": record.evaluations,
            "hypervolume": normalisation.hypervolume(fronts[(size, rep)]),
            "wall_seconds": record.wall_seconds,
            "stopped": record.stopped,
        }
        for (size, rep), record in runs.items()
    ]
    experiment.write_results(rows)
    by_size = {size: [row for row in rows if row["pop"] == size] for size in sizes}
    hypervolumes = {s: [float(r["hypervolume"]) for r in by_size[s]] for s in sizes}
    evaluations = {s: [int(r["evaluations"]) for r in by_size[s]] for s in sizes}
    figure(
        experiment.out / FIGURE,
        hypervolumes,
        evaluations,
        {s: [fronts[(s, rep)] for rep in range(reps)] for s in sizes},
    )
    medians = {
        s: (statistics.median(hypervolumes[s]), statistics.median(evaluations[s])) for s in sizes
    }
    # Each size against the next smaller one: does the larger population gain?
    compared = step_comparisons(hypervolumes)
    experiment.write_stats(
        [
            stats.StatsRow(NAME, f"pop {large} vs pop {small}", "hypervolume", result)
            for (small, large), result in compared.items()
        ]
        + [
            stats.StatsRow(NAME, f"pop {large} vs pop {small}", "evaluations", result)
            for (small, large), result in step_comparisons(evaluations).items()
        ]
    )
    experiment.write_report(
        "Population size",
        base,
        reps,
        table(medians),
        verdict(compared, reps),
        [FIGURE],
        {SPACE: normalisation},
        populations=sizes,
    )


def verdict(compared: Mapping[tuple[int, int], stats.Comparison], reps: int) -> str:
    """Where the hypervolume levels off, against the paper's population near 30."""
    found = levels_off(compared, reps, "the hypervolume", "population size")
    finding = found.text
    if found.rising:
        finding += (
            " The paper found a population near 30 the best trade-off: weigh the gains above "
            "against the evaluations each size costs."
        )
    elif found.level is not None:
        finding += " The paper found a population near 30 the best trade-off: " + (
            "this holds here." if 20 <= found.level <= 50 else "here it lies elsewhere."
        )
    lines = [
        f"- pop {large} against pop {small}: "
        + stats.decide(result, f"pop {large}", f"pop {small}")
        for (small, large), result in compared.items()
    ]
    return "\n".join(
        [finding, "", "Each size against the next smaller (two-sided, alpha 0.05):", *lines]
    )


def table(medians: Mapping[int, tuple[float, float]]) -> list[str]:
    """Population size → (median hypervolume, median evaluations), as a Markdown table."""
    return markdown_table(
        ["population", "median hypervolume", "median evaluations"],
        ([s, f"{hv:.4f}", f"{evaluations:.0f}"] for s, (hv, evaluations) in medians.items()),
        text_columns=0,
    )


def figure(
    path: Path,
    hypervolumes: Mapping[int, list[float]],
    evaluations: Mapping[int, list[int]],
    fronts: Mapping[int, list[list[Point]]] | None = None,
) -> None:
    """Box plots per population size: final hypervolume, and evaluations to stop; and each
    size's median attainment surface, if `fronts` (per size, one front per repetition)."""
    canvas = new_figure((15 if fronts else 10, 4))
    panels = canvas.subplots(1, 3 if fronts else 2)
    left, right = panels[0], panels[1]
    labels = [str(size) for size in hypervolumes]
    left.boxplot(list(hypervolumes.values()), tick_labels=labels)
    left.set(
        xlabel="population size",
        ylabel="hypervolume (experiment normalised)",
        title="final hypervolume",
    )
    right.boxplot([evaluations[size] for size in hypervolumes], tick_labels=labels)
    right.set(xlabel="population size", ylabel="evaluations", title="evaluations to stop")
    if fronts:
        attainment_panel(
            panels[2], {f"pop {s}": sets for s, sets in fronts.items()}, "fronts per size"
        )
    save_png(canvas, path)


def population_sizes(text: str) -> list[int]:
    """--sizes: comma-separated population sizes, each one a run may have."""
    sizes = numbers(int)(text)
    for size in sizes:
        if not defaults.POP_MIN <= size <= defaults.POP_MAX:
            raise ValueError(
                f"{size} is not a population size ({defaults.POP_MIN}-{defaults.POP_MAX})"
            )
    return sizes


EXPERIMENT = ExperimentSpec(
    name=NAME,
    summary="the paper's population sizes: evaluations to converge and final hypervolume",
    run=run,
    options=(
        Option(
            "--sizes",
            "sizes",
            "population sizes, comma-separated",
            ",".join(map(str, SIZES)),
            population_sizes,
            "N,N,...",
        ),
    ),
)
