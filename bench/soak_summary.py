"""The soak's figures, from what it recorded: its memory samples, its ledger of jobs, its tally of
workers.

    python bench/soak_summary.py SAMPLES.csv [SAMPLES.csv ...] [--warm-up-minutes M]
        [--resident NAME]

bench/soak.py prints every figure at its end with this module; run on its own, on the CSV a soak
wrote with `--out` (while it ran, or after it ended or crashed), it prints the memory figures
(the job and worker counts are kept in the soak's process only).

Memory: RSS at the first sample, at the first sample after the warm-up and at the last, with its
slope after the warm-up (least squares over those samples, MiB/hour), and the same for its
anonymous and shared-memory parts, of the broker, the client and the resident worker; the
highest of the workers' RSS in any sample, and the mean of their per-sample mean.

Jobs: submitted; completed (any status but lost); lost (reported lost after every attempt, or
still unanswered after the drain); duplicated (results the client received for a job it had
evaluated already, plus any evaluation handed out twice); retried (evaluated only after a
resubmission at the deadline); throughput (jobs completed over the time from the soak's start to
the drain's end).
"""

import csv
import io
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import click
import numpy as np

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, EpisodeStatus
from gainfarm.schemas.wire import BrokerStatus

SAMPLE_COLUMNS = ("seconds", "role", "name", "pid", "rss_mib", "anon_mib", "shmem_mib")


# --- memory ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Sample:
    """One process's memory at one time; role "workers" (name "max" or "mean", pid 0) is the
    workers' aggregate at that time."""

    seconds: float  # since the soak's start
    role: str  # broker, client, worker, workers
    name: str
    pid: int
    rss_mib: float
    anon_mib: float
    shmem_mib: float


def samples_csv(samples: list[Sample]) -> bytes:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(SAMPLE_COLUMNS)
    for s in samples:
        mib = (f"{value:.2f}" for value in (s.rss_mib, s.anon_mib, s.shmem_mib))
        writer.writerow([f"{s.seconds:.1f}", s.role, s.name, s.pid, *mib])
    return text.getvalue().encode()


def read_samples(path: Path) -> list[Sample]:
    with path.open(newline="") as file:
        return [
            Sample(
                seconds=float(row["seconds"]),
                role=row["role"],
                name=row["name"],
                pid=int(row["pid"]),
                rss_mib=float(row["rss_mib"]),
                anon_mib=float(row["anon_mib"]),
                shmem_mib=float(row["shmem_mib"]),
            )
            for row in csv.DictReader(file)
        ]


def series(
    samples: list[Sample], role: str, name: str, column: str = "rss_mib"
) -> tuple[np.ndarray, np.ndarray]:
    """(seconds, MiB) of one process, or of one aggregate row."""
    rows = [(s.seconds, getattr(s, column)) for s in samples if s.role == role and s.name == name]
    array = np.array(rows, dtype=float).reshape(-1, 2)
    return array[:, 0], array[:, 1]


def slope(seconds: np.ndarray, mib: np.ndarray) -> str:
    """Least-squares MiB per hour, as text."""
    if seconds.size < 3 or np.ptp(seconds) == 0:
        return "n/a"
    return f"{np.polyfit(seconds / 3600, mib, 1)[0]:+.1f} MiB/h"


def memory(samples: list[Sample], role: str, name: str, warm_up: float) -> str | None:
    """RSS at start, after the warm-up and at the end, and its slope after the warm-up; the
    same for its anonymous and shared-memory parts. None if the process was never sampled."""
    seconds, rss = series(samples, role, name)
    if seconds.size == 0:
        return None
    late = seconds >= warm_up
    if not late.any():
        late[-1] = True
    _, anon = series(samples, role, name, "anon_mib")
    _, shmem = series(samples, role, name, "shmem_mib")
    return (
        f"{rss[0]:.1f} MiB at start, {rss[late][0]:.1f} after warm-up, {rss[-1]:.1f} at end "
        f"(anonymous {anon[-1]:.1f}, shared memory {shmem[-1]:.1f}); slope after warm-up "
        f"{slope(seconds[late], rss[late])} (anonymous {slope(seconds[late], anon[late])}, "
        f"shared memory {slope(seconds[late], shmem[late])})"
    )


def memory_lines(samples: list[Sample], resident: str, warm_up: float) -> list[str]:
    lines = []
    for role, name, label in (
        ("broker", "broker", "broker RSS"),
        ("client", "client", "client RSS"),
        ("worker", resident, f"resident worker {resident} RSS"),
    ):
        found = memory(samples, role, name, warm_up)
        if found is not None:
            lines.append(f"{label}: {found}")
    _, peaks = series(samples, "workers", "max")
    _, means = series(samples, "workers", "mean")
    if peaks.size:
        workers = len({s.pid for s in samples if s.role == "worker"})
        lines.append(
            f"worker RSS: peak {peaks.max():.1f} MiB, mean {means.mean():.1f} MiB "
            f"over {workers} workers"
        )
    return lines


# --- jobs and workers --------------------------------------------------------------------------


@dataclass
class SoakLedger:
    """What came back for each job. Job ids are serial numbers, and times seen are kept in a
    bytearray, one byte per job: a set of ids would grow the soak's process by megabytes an hour
    and blur the client's own memory slope."""

    submitted: int = 0
    seen: bytearray = field(default_factory=bytearray)
    statuses: Counter[str] = field(default_factory=Counter)
    evaluated_twice: int = 0
    retried: list[str] = field(default_factory=list)  # job ids evaluated after a resubmission
    lost_reasons: list[str] = field(default_factory=list)
    duplicate_results: int = 0  # FarmClient's: results received for a job evaluated already
    ignored: int = 0  # FarmClient's: results it could not read
    # Logs fetched from the workers that keep them: from the worker that ran the job, simulated
    # again elsewhere (that worker was gone), or failed (which counts as a job lost).
    fetches: Counter[str] = field(default_factory=Counter)

    def next_ids(self, count: int) -> list[str]:
        ids = [f"j{self.submitted + index}" for index in range(count)]
        self.submitted += count
        self.seen.extend(bytes(count))
        return ids

    def record(self, result: EpisodeResult) -> None:
        index = int(result.job_id.removeprefix("j"))
        if self.seen[index]:
            self.evaluated_twice += 1
        self.seen[index] = min(self.seen[index] + 1, 255)
        self.statuses[result.status] += 1
        if result.attempts > 1:
            self.retried.append(f"{result.job_id} (from {result.worker or '-'})")
        if result.status == EpisodeStatus.lost:
            self.lost_reasons.append(f"{result.job_id}: {result.reason}")

    @property
    def completed(self) -> int:
        return sum(n for status, n in self.statuses.items() if status != EpisodeStatus.lost)

    def unanswered(self) -> int:
        return self.seen.count(0)

    @property
    def lost(self) -> int:
        return self.statuses[EpisodeStatus.lost] + self.unanswered() + self.fetches["failed"]

    @property
    def duplicated(self) -> int:
        return self.duplicate_results + self.evaluated_twice


def job_lines(ledger: SoakLedger, warnings: Counter[str], seconds: float) -> list[str]:
    """The job counts; `warnings` counts the client's warnings by message, and `seconds` is the
    time the jobs completed in."""
    completed = ", ".join(
        f"{status} {n:,}"
        for status, n in sorted(ledger.statuses.items())
        if status != EpisodeStatus.lost
    )
    retried = f" ({', '.join(ledger.retried[:10])})" if ledger.retried else ""
    return [
        f"jobs submitted: {ledger.submitted:,}",
        f"jobs completed: {ledger.completed:,} ({completed})",
        f"jobs lost: {ledger.lost} ({ledger.statuses[EpisodeStatus.lost]} reported lost, "
        f"{ledger.unanswered()} never answered, {ledger.fetches['failed']} logs not fetched)",
        f"logs fetched: {ledger.fetches['from its worker']:,} from the worker that ran the job, "
        f"{ledger.fetches['simulated again']:,} simulated again (that worker was gone), "
        f"{ledger.fetches['failed']} failed",
        f"jobs duplicated: {ledger.duplicated} ({ledger.duplicate_results} duplicate results "
        f"received, {ledger.evaluated_twice} evaluations of a job already evaluated)",
        f"jobs retried after the deadline: {len(ledger.retried)}{retried}; "
        f"results ignored: {ledger.ignored}",
        "client warnings: "
        + (", ".join(f"{n} x {message!r}" for message, n in warnings.items()) or "none"),
        f"throughput: {ledger.completed / seconds:.1f} jobs/s over {seconds:.0f} s",
    ]


@dataclass
class WorkerTally:
    """What became of the soak's workers."""

    starts: int = 0
    stops: int = 0  # SIGTERMs
    kills: int = 0  # SIGKILLs
    stop_codes: Counter[int] = field(default_factory=Counter)  # exit statuses after a SIGTERM
    died: list[str] = field(default_factory=list)  # exited without being told to
    hung: list[str] = field(default_factory=list)  # did not finish within STOP_SECONDS of SIGTERM

    def line(self) -> str:
        return (
            f"workers: {self.starts} starts, {self.stops} SIGTERM stops, {self.kills} SIGKILLs; "
            f"stop statuses {dict(self.stop_codes)}; died unbidden: {self.died or 0}; "
            f"hung on SIGTERM: {self.hung or 0}"
        )


def broker_line(status: BrokerStatus, exit_status: int | None) -> str:
    return (
        f"broker: {status.jobs_done:,} jobs done, {status.requeued} requeued, "
        f"{status.rejected} rejected; exit status {exit_status}"
    )


# --- on its own --------------------------------------------------------------------------------


@click.command(help=__doc__.split("\n\n")[0])
@click.argument(
    "paths",
    metavar="SAMPLES.csv...",
    nargs=-1,
    required=True,
    type=click.Path(exists=True, dir_okay=False, path_type=Path),
)
@click.option(
    "--warm-up-minutes",
    type=click.FloatRange(min=0),
    help="memory before this is left out of the slopes  [default: a fifth of the time sampled, "
    "≤ 5; the soak's is a fifth of its --minutes]",
)
@click.option(
    "--resident",
    metavar="NAME",
    help="the worker that served the whole soak  [default: the first worker sampled]",
)
def main(paths: tuple[Path, ...], warm_up_minutes: float | None, resident: str | None) -> None:
    for path in paths:
        samples = read_samples(path)
        if not samples:
            raise click.ClickException(f"{path}: no samples")
        span = max(s.seconds for s in samples)
        warm_up = 60 * warm_up_minutes if warm_up_minutes is not None else min(span / 5, 300.0)
        name = resident
        if name is None:  # the soak starts its resident before any other worker
            name = next((s.name for s in samples if s.role == "worker"), "")
        click.echo(f"{path}: {len(samples):,} samples over {span:.0f} s, warm-up {warm_up:.0f} s")
        click.echo("\n".join(memory_lines(samples, name, warm_up)))


if __name__ == "__main__":
    main()
