"""`analytic dataset`: tuned controllers' episodes gathered into a dataset."""

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import click

from gainfarm.analytic.commands.shared import (
    check_farm,
    farm,
    farm_options,
    farm_problem,
    refuse_under_a_file,
    study_name,
)
from gainfarm.cli.app import CliError, parse_numbers
from gainfarm.cli.options import Later

if TYPE_CHECKING:
    from gainfarm.analytic.evaluators.evaluator import Evaluator


def _split() -> str:
    from gainfarm.analytic.data.dataset import DEFAULT_SPLIT

    return ",".join(f"{value:g}" for value in DEFAULT_SPLIT)


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
    default=Later(_split),
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
def dataset(
    run_dirs: tuple[Path, ...],
    out: Path,
    selection: str,
    split_text: str,
    split_seed: int,
    rerun_file: Path | None,
    excitations: int,
    plants: int,
    infeasible: bool,
    include_rough: bool,
    release_name: str | None,
    release_format: str,
    baselines_text: str | None,
    connect: tuple[str, ...],
    tls: Path | None,
    participant: str | None,
    local: bool,
    workers: int | None,
) -> None:
    """Gather tuned controllers' episodes into a dataset: MCAP logs, Parquet tables, a card."""
    from gainfarm.analytic.data.dataset import (
        BadRerun,
        BadSplit,
        DuplicateEpisodes,
        NoEpisodes,
        RerunFailed,
        UnreadableRun,
        canonical_json,
        check_split,
        read_rerun,
    )
    from gainfarm.analytic.data.dataset import build as build_dataset
    from gainfarm.analytic.data.dataset import excitations as excitation_trajectories
    from gainfarm.analytic.evaluators.farm import FarmClient
    from gainfarm.analytic.tuning.records import CONFIG_JSON
    from gainfarm.cli.words import counted
    from gainfarm.schemas.wire import BadMessage

    identity = check_farm(connect, local, tls, participant)
    reruns = rerun_file is not None or excitations > 0
    if not reruns and (connect or local):  # saying so beats ignoring the option
        raise CliError(
            "--connect and --local need --rerun or --excitations: only a rerun runs episodes"
        )
    if plants and not reruns:
        raise CliError("--plants needs --rerun or --excitations: only a rerun runs episodes")
    for run_dir in run_dirs:
        if not (run_dir / CONFIG_JSON).is_file():
            raise CliError(f"{str(run_dir)!r} holds no run (no {CONFIG_JSON})")
    if out.exists():
        raise CliError(f"--out: {str(out)!r} already exists")
    refuse_under_a_file(out, "--out")
    try:
        split = check_split(parse_numbers("--split", split_text, 3))
        trajectories = read_rerun(rerun_file) if rerun_file is not None else []
    except BadSplit as error:
        raise CliError(f"--split: {error}") from None
    except BadRerun as error:
        raise CliError(f"--rerun: {error}") from None
    known = {canonical_json(trajectory) for trajectory in trajectories}
    trajectories += [  # an excitation the file lists already is not run twice
        trajectory
        for trajectory in excitation_trajectories(excitations)
        if canonical_json(trajectory) not in known
    ]
    if release_format != "gainfarm" and release_name is None:
        raise CliError(
            f"--format {release_format} needs --release NAME: only a release is exported"
        )
    if baselines_text is not None and release_name is None:
        raise CliError("--baselines needs --release NAME: only a release scores baselines")
    kinds = None
    if baselines_text is not None:
        from gainfarm.analytic.data.learning import BENCHMARK

        kinds = tuple(kind.strip() for kind in baselines_text.split(",") if kind.strip())
        unknown = [kind for kind in kinds if kind not in BENCHMARK]
        if unknown or not kinds or len(set(kinds)) < len(kinds):
            raise CliError(
                f"--baselines: expected distinct kinds among {', '.join(BENCHMARK)}, got "
                f"{baselines_text!r}"
            )
    # A release's modules (the learning's, matplotlib's) load only for a release.
    release_errors: tuple[type[Exception], ...] = ()
    if release_name is not None:
        from gainfarm.analytic.data.learning import LearnError
        from gainfarm.analytic.data.release import (
            BadRelease,
            MissingExtra,
            build_release,
            check_learn_extra,
            check_name,
        )

        release_errors = (BadRelease, LearnError)
        try:
            check_name(release_name)
        except BadRelease as error:
            raise CliError(f"--release: {error}") from None
        if split[2] <= 0:
            raise CliError(
                "--split: a release is scored on its test split: give it a positive fraction"
            )
        try:
            check_learn_extra()
        except MissingExtra as error:
            raise CliError(f"--release: {error}") from None

    @contextlib.contextmanager
    def rerun_farm(directory: Path) -> Iterator["Evaluator"]:
        """The rerun's farm, as `analytic batch` has it (started only once all is checked)."""
        with farm(connect, workers) as endpoints:
            try:
                client = FarmClient(
                    endpoints, study_name(directory, identity), directory, identity=identity
                )
            except (ValueError, ConnectionError) as error:
                raise CliError(farm_problem(connect, error)) from None
            with client:
                yield client

    options = {
        "selection": selection,
        "split": split,
        "split_seed": split_seed,
        "rerun_trajectories": trajectories,
        "rerun_plants": plants,
        "farm": rerun_farm,
        "infeasible": infeasible,
        "include_rough": include_rough,
    }
    record: dict[str, object] = {}
    try:
        if release_name is None:
            counts = build_dataset(list(run_dirs), out, **options)  # type: ignore[arg-type]
        else:
            counts, record = build_release(
                list(run_dirs),
                out,
                release_name,
                format=release_format,  # type: ignore[arg-type]  # click's choice
                kinds=kinds,
                **options,
            )
    except BadSplit as error:  # too few trajectories for the parts asked for
        raise CliError(f"--split: {error}") from None
    except BadRerun as error:  # a trajectory the robot cannot follow
        raise CliError(f"--rerun: {error}") from None
    except (NoEpisodes, UnreadableRun, DuplicateEpisodes, RerunFailed, BadMessage) as error:
        raise CliError(str(error)) from None
    except release_errors as error:  # a bad release, or baselines that could not be fitted
        what = "the baselines: " if isinstance(error, release_errors[1]) else ""
        raise CliError(f"--release: {what}{error}") from None
    except ConnectionError as error:  # the farm's, not the disk's
        raise CliError(farm_problem(connect, error)) from None
    except OSError as error:
        raise CliError(f"--out: cannot write {str(out)!r}: {error.strerror}") from None
    rerun = (
        f", {counts['rerun']} of them rerun in {counts['rerun_seconds']} s"
        if counts["rerun"]
        else ""
    )
    if counts["rough_left_out"]:
        rerun += f" ({counts['rough_left_out']} rough ones left out)"
    elif counts["rough"]:
        rerun += f" ({counts['rough']} of them rough, kept)"
    click.echo(
        f"{out}: {counted(counts['episodes'], 'episode')}{rerun}, {counts['ticks']:,} ticks, "
        f"{counted(counts['controllers'], 'controller')} from {counted(counts['runs'], 'run')}, "
        f"{counted(counts['trajectories'], 'trajectory')} ({counts['train']} train, "
        f"{counts['validation']} validation, {counts['test']} test)"
    )
    if record:
        formats = " and ".join(str(f) for f in record["formats"])  # type: ignore[attr-defined]
        fitted = record["baselines"]["fit_seconds"]  # type: ignore[index]
        click.echo(
            f"{out}: release {record['name']} ({formats}), content hash {record['content_hash']}, "
            f"baselines fitted in {fitted:.0f} s"
        )
