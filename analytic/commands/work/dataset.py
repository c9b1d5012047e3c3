"""`analytic dataset` once it runs: what its function in analytic/commands/dataset.py does."""

import contextlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from gainfarm.analytic.commands.shared import farm_problem, refuse_under_a_file
from gainfarm.analytic.commands.work.common import check_farm
from gainfarm.analytic.commands.work.tuning import farm, study_name
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
from gainfarm.cli.app import CliError, parse_numbers
from gainfarm.cli.words import counted
from gainfarm.schemas.wire import BadMessage

if TYPE_CHECKING:
    from gainfarm.analytic.evaluators.evaluator import Evaluator


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
    """`analytic dataset` with its options as parsed (analytic/commands/dataset.py)."""
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
    kinds, release_errors, build_release = _release(
        release_name, release_format, baselines_text, split
    )

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
        if build_release is None:
            counts = build_dataset(list(run_dirs), out, **options)  # type: ignore[arg-type]
        else:
            counts, record = build_release(  # type: ignore[misc]
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
    _say(out, counts, record)


def _release(
    name: str | None, release_format: str, baselines_text: str | None, split: tuple[float, ...]
) -> tuple[tuple[str, ...] | None, tuple[type[Exception], ...], Callable[..., Any] | None]:
    """A release's options checked (--release, --format, --baselines, the test split): the
    baselines' kinds, the errors building it may raise, and what builds it (None without
    --release)."""
    if release_format != "gainfarm" and name is None:
        raise CliError(
            f"--format {release_format} needs --release NAME: only a release is exported"
        )
    if baselines_text is not None and name is None:
        raise CliError("--baselines needs --release NAME: only a release scores baselines")
    if name is None:
        return None, (), None
    # start-up: a release's modules (the learning's, matplotlib's) load only for a release
    from gainfarm.analytic.data import learning, release

    kinds = None
    if baselines_text is not None:
        kinds = tuple(kind.strip() for kind in baselines_text.split(",") if kind.strip())
        unknown = [kind for kind in kinds if kind not in learning.BENCHMARK]
        if unknown or not kinds or len(set(kinds)) < len(kinds):
            raise CliError(
                f"--baselines: expected distinct kinds among {', '.join(learning.BENCHMARK)}, "
                f"got {baselines_text!r}"
            )
    try:
        release.check_name(name)
    except release.BadRelease as error:
        raise CliError(f"--release: {error}") from None
    if split[2] <= 0:
        raise CliError(
            "--split: a release is scored on its test split: give it a positive fraction"
        )
    try:
        release.check_learn_extra()
    except release.MissingExtra as error:
        raise CliError(f"--release: {error}") from None
    return kinds, (release.BadRelease, learning.LearnError), release.build_release


def _say(out: Path, counts: dict, record: dict[str, object]) -> None:
    """What the dataset (and its release) holds, in a line each."""
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
