"""An evaluator with no farm: every job runs here, one after another, when its results are asked.

By default a job is what a worker makes of it (worker.job.simulate: the MuJoCo episode and its
MCAP log), then what the farm client makes of the log (decoded, scored, kept in
`run_dir/episodes/`), so a run gives the same front here as on a farm. Given `scorer`, a function
of the spec, it simulates nothing and keeps no log: the tuning loop's own tests, and toy problems,
run in milliseconds.
"""

import hashlib
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from gainfarm.analytic.evaluators.evaluator import (
    EpisodeResult,
    EpisodeStatus,
    Fetched,
    Wanted,
    accept_log,
)
from gainfarm.plugins import PluginError
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog
from gainfarm.schemas.wire import JobStatus

if TYPE_CHECKING:
    from gainfarm.models.dynamics import DynamicsModel

WORKER = "in-process"  # the worker name evaluations carry


class InProcessEvaluator:
    trusted = True  # its episodes run in this process: nothing to referee

    def __init__(
        self,
        run_dir: Path | None = None,
        *,
        scorer: Callable[[EpisodeSpec], Scores] | None = None,
        models: Mapping[str, bytes] | None = None,
    ):
        """Keep logs in `run_dir`/episodes/ (none without a run directory); score each job with
        `scorer` instead of simulating it, if given. `models`: the feed-forward model files the
        jobs may name, by SHA-256."""
        self.models = dict(models or {})
        # Made with the first log, not now: `tune(config, out, evaluator=InProcessEvaluator(out))`
        # claims `out` as new or empty after this evaluator is made.
        self.log_dir = Path(run_dir) / "episodes" if run_dir is not None else None
        self.scorer = scorer
        self._pending: dict[str, EpisodeSpec] = {}

    def __enter__(self) -> "InProcessEvaluator":
        return self

    def __exit__(self, *exc: object) -> None:
        self._pending.clear()  # as a farm client drops its study's queued jobs when it closes

    @property
    def capacity(self) -> int:
        return 1

    @property
    def pending(self) -> int:
        return len(self._pending)

    def submit(
        self, specs: Mapping[str, EpisodeSpec], avoid: Mapping[str, Sequence[str]] | None = None
    ) -> None:
        """`avoid` has no meaning here: this process is the one worker."""
        clash = sorted(set(specs) & set(self._pending))
        if clash:
            raise ValueError(f"job ids already pending: {', '.join(clash[:5])}")
        self._pending.update(specs)

    def distrust(self, worker: str) -> None:
        """Nothing to do: this process is the one worker, and nobody replicates it."""

    def cancel(self, job_ids: Iterable[str]) -> None:
        for job_id in job_ids:
            self._pending.pop(job_id, None)

    def results(self, timeout: float | None = None) -> Iterator[EpisodeResult]:
        """Run the pending jobs in the order submitted (jobs submitted meanwhile included).
        `timeout` has no meaning here: every job runs when it is asked for."""
        while self._pending:
            job_id = next(iter(self._pending))
            yield self._evaluate(job_id, self._pending.pop(job_id))

    def fetch(
        self, wanted: Mapping[str, Wanted], simulate_again: bool = True
    ) -> dict[str, Fetched]:
        """Every log is kept here as it is made, so a fetch only scores it again; one pruned
        since, or never kept (no run directory), is simulated again (`simulate_again`: else a
        Fetched without a log). A scorer keeps no logs."""
        fetched = {}
        for job_id, want in wanted.items():
            if self.scorer is not None:
                fetched[job_id] = Fetched(None, None, None, "scored without an episode: no log")
                continue
            path = self.log_dir / f"{job_id}.mcap" if self.log_dir is not None else None
            if path is not None and path.exists():
                content = path.read_bytes()
            elif not simulate_again:
                fetched[job_id] = Fetched(None, None, None, "not kept here")
                continue
            else:
                from gainfarm.worker.job import simulate  # start-up: MuJoCo, only to simulate

                content = simulate(want.spec, self._model).content
            try:
                scores = accept_log(content, want.spec, path, f"episode of {job_id}")
            except NotAnEpisodeLog as error:
                fetched[job_id] = Fetched(None, None, None, str(error))
                continue
            digest = hashlib.sha256(content).hexdigest()
            fetched[job_id] = Fetched(path, scores, digest, source=WORKER)
        return fetched

    def _model(self, wanted: str) -> "DynamicsModel":
        # start-up: as MuJoCo, loaded only when an episode is simulated
        from gainfarm.models.dynamics import feedforward_from_bytes
        from gainfarm.worker.feedforward import ModelUnavailable

        if wanted not in self.models:
            raise ModelUnavailable(f"feed-forward model {wanted[:12]} was not given")
        return feedforward_from_bytes(self.models[wanted])

    def _evaluate(self, job_id: str, spec: EpisodeSpec) -> EpisodeResult:
        common = dict(job_id=job_id, spec=spec, worker=WORKER, attempts=1)
        if self.scorer is not None:
            scores = self.scorer(spec)
            status = EpisodeStatus.diverged if scores.diverged else EpisodeStatus.ok
            return EpisodeResult(
                **common, status=status, scores=scores, log=None, reason="", timings=None
            )
        from gainfarm.worker.job import simulate  # start-up: MuJoCo, only to simulate

        outcome = simulate(spec, self._model)
        if outcome.status == JobStatus.refused:  # this process lacks a plug-in the job names
            raise PluginError(f"job {job_id} refused: {outcome.reason}")
        if outcome.status == JobStatus.failed:
            return EpisodeResult(
                **common,
                status=EpisodeStatus.failed,
                scores=None,
                log=None,
                reason=outcome.reason,
                timings=outcome.timings,
            )
        log = self.log_dir / f"{job_id}.mcap" if self.log_dir is not None else None
        if log is not None:
            log.parent.mkdir(parents=True, exist_ok=True)
        try:
            scores = accept_log(outcome.content, spec, log, f"episode of {job_id}")
        except NotAnEpisodeLog as error:  # a bug here, not a transport fault: say so, go on
            return EpisodeResult(
                **common,
                status=EpisodeStatus.failed,
                scores=None,
                log=None,
                reason=f"unusable episode log: {error}",
                timings=outcome.timings,
            )
        return EpisodeResult(
            **common,
            status=EpisodeStatus(outcome.status.value),
            scores=scores,
            log=log,
            reason=outcome.reason,
            timings=outcome.timings,
            digest=outcome.digest,
        )
