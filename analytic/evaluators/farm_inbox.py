"""What reaches the farm client on Zenoh's thread, and what it holds there: each sample on the
study's results key read (its small attachment, a Result) and held only for a job it waits for,
with no payload, while the results held unconfirmed stay within MAX_HELD_BYTES; everything else is
dropped and counted. Beside it, the results the broker said it took that have not come yet
(`taken`), and the jobs a result was dropped for. The lock that guards them never leaves here."""

import logging
import queue
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import zenoh

from gainfarm.analytic.evaluators.farm_jobs import Pending
from gainfarm.schemas.wire import MAX_MESSAGE_BYTES, Accepted, BadMessage, Result, decode

log = logging.getLogger("gainfarm.analytic")

# The bytes of results held before the broker says which it took (in the inbox and arrived): a
# result is its attachment alone (a Result: about a kilobyte, at most a wire message), so this
# holds thousands; a flood of well-formed forgeries for pending jobs fills it, and what comes
# then is dropped until the broker has been asked (each inbox drain confirms at once).
MAX_HELD_BYTES = 4 * MAX_MESSAGE_BYTES
DROPS_LOGGED_EVERY = 10.0  # s: samples dropped are logged at most this often, with their count


@dataclass(frozen=True)
class Arrival:
    """A result as it arrived, waiting for the broker to confirm it."""

    result: Result
    held: int  # bytes counted against MAX_HELD_BYTES until it is let go
    taken: Accepted | None = None  # the result the broker said it took, if this is that one


class Inbox:
    """The study's inbox: arrivals and broker markers in order, for the client's thread."""

    def __init__(self, study: str, pending: Mapping[str, Pending], max_held_bytes: int):
        self.study = study
        self.pending = pending  # the client's pending jobs, by job id (read here, never changed)
        self.max_held_bytes = max_held_bytes
        self.duplicates = 0
        self.ignored = 0
        self.unconfirmed = 0  # results the broker did not take: forged, or from a stale lease
        self.unheard = 0  # results the broker took that never came: taken from its record
        self.dropped = 0  # results for pending jobs not held: max_held_bytes was full
        self.held_bytes = 0  # bytes of results held now, before the broker confirms them
        self.peak_held_bytes = 0
        # What the broker said it took, for jobs whose result has not come (yet), and when.
        self._taken: dict[str, tuple[Accepted, float]] = {}
        self._dropped_for: set[str] = set()  # jobs a result was dropped for: ask the broker
        self._lock = threading.Lock()  # the above and the counters, shared with Zenoh's thread
        self._drops_logged = 0.0
        self._queue: queue.SimpleQueue[Arrival | str] = queue.SimpleQueue()

    # --- the queue ----------------------------------------------------------------------------

    def put(self, message: Arrival | str) -> None:
        self._queue.put(message)

    def get(self, timeout: float) -> Arrival | str:
        """The next message, within `timeout` s (queue.Empty if none came)."""
        return self._queue.get(timeout=timeout)

    def drain(self, most: int) -> list[Arrival | str]:
        """Whatever else is in the inbox now, `most` at most: its results are confirmed in one
        question."""
        messages = []
        while len(messages) < most:
            try:
                messages.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return messages

    def qsize(self) -> int:
        return self._queue.qsize()

    # --- on Zenoh's thread --------------------------------------------------------------------

    def on_result(self, sample: zenoh.Sample) -> None:
        """Runs on Zenoh's thread for every sample on the study's keys, whoever put it: reads
        the attachment (a Result, at most MAX_MESSAGE_BYTES) and holds it only for a pending
        job, with no payload (a result carries no log), within max_held_bytes. Never raises:
        whatever the sample, it is held or dropped."""
        attachment = sample.attachment
        try:
            if attachment is None:
                raise BadMessage("no attachment")
            if len(attachment) > MAX_MESSAGE_BYTES:
                raise BadMessage(f"a {len(attachment)}-byte attachment")
            if len(sample.payload):
                raise BadMessage(f"a {len(sample.payload)}-byte payload: a result carries no log")
            raw = attachment.to_bytes()
            result = decode(Result, raw)
        except BadMessage as error:
            return self._drop("ignored", f"not a result ({error})")
        if result.study != self.study:
            return self._drop("ignored", f"a result of study {result.study[:64]!r}")
        pending = self.pending.get(result.job_id)
        if pending is None:  # already evaluated (or never submitted here)
            return self._drop("duplicates")
        held = len(raw)
        with self._lock:
            taken = self._taken.get(result.job_id)
            if taken is not None and not matches(result, taken[0]):
                self.unconfirmed += 1  # the broker took another: this one is not held
                return
            if taken is None and self.held_bytes + held > self.max_held_bytes:
                self.dropped += 1
                self._dropped_for.add(result.job_id)
                pending.dropped_here = True
                return self._log_drop(f"a result for {result.job_id}: {self.held_bytes} bytes held")
            if taken is not None:  # the one the broker took: held whatever the budget, once
                del self._taken[result.job_id]
            self.held_bytes += held
            self.peak_held_bytes = max(self.peak_held_bytes, self.held_bytes)
        self._queue.put(Arrival(result, held, taken and taken[0]))

    def _drop(self, counter: str, why: str = "") -> None:
        with self._lock:
            setattr(self, counter, getattr(self, counter) + 1)
            if why:
                self._log_drop(why)

    def _log_drop(self, why: str) -> None:
        """Say why a sample was dropped, at most once a DROPS_LOGGED_EVERY (under the lock)."""
        now = time.monotonic()
        if now >= self._drops_logged + DROPS_LOGGED_EVERY:
            self._drops_logged = now
            log.warning(
                "dropped %s (so far: %d ignored, %d not waited for, %d not held)",
                why,
                self.ignored,
                self.duplicates,
                self.dropped,
            )

    # --- on the client's thread ---------------------------------------------------------------

    def release(self, arrivals: Iterable[Arrival]) -> None:
        freed = sum(arrival.held for arrival in arrivals)
        if freed:
            with self._lock:
                self.held_bytes -= freed

    def duplicate(self) -> None:
        """Count a result that came for a job evaluated or cancelled since."""
        with self._lock:
            self.duplicates += 1

    def not_taken(self, count: int, job_id: str) -> None:
        """Count `count` results for `job_id` that are not the one the broker took."""
        with self._lock:
            self.unconfirmed += count
            self._log_drop(f"{count} results for {job_id}: not the one the broker took")

    def dropped_for(self) -> set[str]:
        """The jobs a result was dropped for since last asked (the broker tells which it took)."""
        with self._lock:
            dropped, self._dropped_for = self._dropped_for, set()
        return dropped

    def told(self) -> set[str]:
        """The jobs the broker said it took a result for, which has not come yet."""
        with self._lock:
            return set(self._taken)

    def remember(self, accepted: Iterable[Accepted], since: float) -> None:
        """The broker forgets what it has told: remember it until that result comes."""
        with self._lock:
            for one in accepted:
                self._taken[one.job_id] = (one, since)

    def forget(self, job_id: str) -> None:
        with self._lock:
            self._taken.pop(job_id, None)

    def claim(self, result: Result) -> Accepted | None:
        """The broker's word that it took `result`, if it said so meanwhile (taken off)."""
        with self._lock:
            told = self._taken.get(result.job_id)
            if told is not None and matches(result, told[0]):
                return self._taken.pop(result.job_id)[0]
        return None

    def overdue(self, patience: float) -> list[Accepted]:
        """The results the broker took that have not come within `patience` s of its saying
        so (taken off)."""
        now = time.monotonic()
        with self._lock:
            lost = [j for j, (_, since) in self._taken.items() if now - since >= patience]
            return [self._taken.pop(job_id)[0] for job_id in lost]


def matches(result: Result, accepted: Accepted) -> bool:
    """Whether `result` is the one the broker took: its lease, its worker, its very log and the
    scores its worker handed in with it."""
    return (result.lease_id, result.worker, result.digest, result.scores) == (
        accepted.lease_id,
        accepted.worker,
        accepted.digest,
        accepted.scores,
    )
