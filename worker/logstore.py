"""The episode logs a worker keeps for the studies that may fetch them. No Zenoh here.

A result goes out without its log; the worker keeps the log in memory, bounded, and serves it by
its digest, in parts, to the study whose job made it (keys.log). The least recently used logs go
first when a new one needs the room: a study fetches the logs it wants soon after their results
arrive (a study that keeps every log, at once: Job.keep_log), or not at all.
"""

import threading
from collections import OrderedDict


class LogStore:
    """Kept logs by (study, digest), at most `max_bytes` in all; thread-safe (a Zenoh queryable
    reads while the serve loop keeps)."""

    def __init__(self, max_bytes: int):
        if max_bytes < 0:
            raise ValueError(f"a log store of {max_bytes} bytes")
        self.max_bytes = max_bytes
        self._logs: OrderedDict[tuple[str, str], bytes] = OrderedDict()  # oldest use first
        self._bytes = 0
        self._lock = threading.Lock()

    def keep(self, study: str, digest: str, content: bytes) -> None:
        """Keep `content` for `study` under `digest`, evicting the least recently used logs to
        make room; a log larger than the whole store is not kept."""
        if len(content) > self.max_bytes:
            return
        with self._lock:
            key = (study, digest)
            previous = self._logs.pop(key, None)
            if previous is not None:
                self._bytes -= len(previous)
            while self._logs and self._bytes + len(content) > self.max_bytes:
                _, evicted = self._logs.popitem(last=False)
                self._bytes -= len(evicted)
            self._logs[key] = content
            self._bytes += len(content)

    def get(self, study: str, digest: str) -> bytes | None:
        """The log `study`'s job made with that digest, if it is still kept (it counts as used)."""
        with self._lock:
            content = self._logs.get((study, digest))
            if content is not None:
                self._logs.move_to_end((study, digest))
            return content

    def __len__(self) -> int:
        with self._lock:
            return len(self._logs)

    @property
    def bytes(self) -> int:
        """The kept logs' total size."""
        with self._lock:
            return self._bytes
