"""Episode logs from the workers that keep them, in parts (gainfarm/edges/parts.py): each holder
asked in turn, only bytes that hash to the wanted digest taken, whoever answers; a few fetched at
once; written to the run's episodes/ and scored here again (a log a farm's own worker made, its
digest checked, keeps the scores it claimed)."""

import hashlib
import logging
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import zenoh

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Fetched, ReadLog, Wanted
from gainfarm.analytic.evaluators.farm_link import ANSWER_SECONDS, StudyLink
from gainfarm.analytic.evaluators.farm_workers import Workers
from gainfarm.edges.files import write_atomically
from gainfarm.edges.parts import fetch_parts
from gainfarm.schemas import keys
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog
from gainfarm.schemas.wire import MAX_EPISODE_BYTES, BadMessage

log = logging.getLogger("gainfarm.analytic")

# Logs of confirmed results fetched at once (`keep_logs`), each in parts with a few in flight:
# a fetch is a round trip through the router to its worker, and one at a time made a `--keep all`
# run slower than when logs came with their results.
FETCHES_AT_ONCE = 4


class Logs:
    """The logs of a study's jobs, fetched over `link` into `log_dir`."""

    def __init__(
        self, link: StudyLink, workers: Workers, log_dir: Path, read_log: ReadLog, trusted: bool
    ):
        self.link = link
        self.workers = workers
        self.log_dir = log_dir
        self.read_log = read_log
        self.trusted = trusted

    def fetch_log(self, want: Wanted, limit: int = MAX_EPISODE_BYTES) -> tuple[bytes | None, str]:
        """The log's bytes and the holder that had them, or None. Each holder in turn is asked
        for it in parts, `limit` bytes at most; one that answers badly (schemas.parts) or with
        other bytes is skipped."""
        for holder in want.holders:
            try:
                key = keys.log(self.link.study, holder, want.digest)
                content = fetch_parts(self.link.session, key, limit, ANSWER_SECONDS)
            except zenoh.ZError as error:  # e.g. an empty or bad holder name
                log.warning("cannot ask %r for a log: %s", holder, error)
                continue
            except BadMessage as error:
                log.warning("ignored a log from %s: %s", holder, error)
                continue
            if content is None:
                continue  # it has it no more: ask the next holder
            if hashlib.sha256(content).hexdigest() == want.digest:
                return content, holder
            log.warning("ignored a log on %s: its bytes are not the ones the broker took", key)
        return None, ""

    def fetch_at_once(self, wanted: Mapping[str, tuple[Wanted, int]]) -> dict[str, bytes | None]:
        """The logs of these jobs, by job id, fetched at once from their workers (each within
        the size given with it)."""
        if not wanted:
            return {}

        def fetch(job_id: str) -> bytes | None:
            want, limit = wanted[job_id]
            return self.fetch_log(want, limit)[0]

        with ThreadPoolExecutor(max_workers=len(wanted)) as pool:
            return dict(zip(wanted, pool.map(fetch, wanted), strict=True))

    def take(self, wanted: Mapping[str, Wanted]) -> tuple[dict[str, Fetched], dict[str, Wanted]]:
        """The logs of these jobs from their holders, written to episodes/<job id>.mcap and
        scored here (on a farm of this process's own workers, `trusted`, a log wanted with its
        claimed scores keeps them); and those no holder had (or whose bytes were of another
        episode), to be simulated again."""
        fetched: dict[str, Fetched] = {}
        again: dict[str, Wanted] = {}
        for job_id, want in wanted.items():
            content, holder = self.fetch_log(want)
            if content is not None:
                path = self.log_dir / f"{job_id}.mcap"
                if self.trusted and want.scores is not None:
                    # Its own worker's bytes (their digest checked): the scores it claimed are
                    # the log's, and decoding and scoring it again would check nothing.
                    write_atomically(path, content)
                    fetched[job_id] = Fetched(path, want.scores, want.digest, source=holder)
                    continue
                try:
                    scores = self.read_log(content, want.spec, path, f"log of {job_id}")
                except NotAnEpisodeLog as error:  # the right bytes of the wrong episode
                    log.warning("fetched log of %s: %s", job_id, error)
                else:
                    fetched[job_id] = Fetched(path, scores, want.digest, source=holder)
                    continue
            again[job_id] = want
        return fetched, again

    def rerun_log(
        self, job_id: str, result: EpisodeResult, spec: EpisodeSpec, path: Path
    ) -> Scores | None:
        """The log of a job run again, from the worker that ran it (by its digest), kept at
        `path` and scored here; None if it cannot be had. A worker whose log does not score as
        it claimed is distrusted."""
        assert result.digest is not None
        want = Wanted(spec, result.digest, (result.worker,))
        content, _ = self.fetch_log(want)
        if content is None:
            log.warning("%s simulated again: %s no longer has its log", job_id, result.worker)
            return None
        try:
            scores = self.read_log(content, spec, path, f"log of {job_id} simulated again")
        except NotAnEpisodeLog as error:
            log.warning("%s simulated again: %s", job_id, error)
            return None
        if scores != result.scores:
            self.workers.distrusted.add(result.worker)
            log.warning(
                "%s simulated again: %s claimed scores its log has not", job_id, result.worker
            )
        return scores
