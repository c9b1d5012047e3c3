"""The feed-forward models a worker has: fetched from the farm once, kept on disk by content hash.

A job names its model by SHA-256 (EpisodeSpec.feedforward), not by path: no shared file system is
assumed. The first job that needs a model asks the farm for it (the study that submitted the job
serves it); bytes that do not hash to the job's digest are refused, whoever sent them, so a model
cannot be swapped on the way. Fetched models are written to the cache directory (whole or not at
all) and so survive the worker's restarts, at most DISK_BYTES of them: the least recently used go
first (a file's mtime is its last use). No Zenoh here: the caller gives the fetch.
"""

import os
import re
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

from gainfarm.edges.files import write_atomically
from gainfarm.models.dynamics import BadDynamicsModel, DynamicsModel, digest, feedforward_from_bytes

MEMORY = 8  # models kept decoded: a study uses one, a worker serving a few studies a few
# Bytes of model files kept on disk: a network is well under 1 MB, the largest file a worker
# accepts 64 MiB (models.dynamics.MAX_FILE_BYTES); any study may have a worker fetch models, so
# what they leave on its disk is bounded.
DISK_BYTES = 512 * 2**20
_FILE = re.compile(r"[0-9a-f]{64}\.npz")  # the cache's own files: nothing else is removed


class ModelUnavailable(ValueError):
    """The job's model could not be had: the job fails with this reason, the worker goes on."""


def default_cache() -> Path:
    """$XDG_CACHE_HOME/gainfarm/models, or ~/.cache/gainfarm/models."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "gainfarm" / "models"


class ModelCache:
    def __init__(self, directory: Path | None = None, max_bytes: int = DISK_BYTES):
        self.directory = Path(directory) if directory is not None else default_cache()
        self.max_bytes = max_bytes
        self.fetched = 0  # models that came over the farm, not from the disk
        self._decoded: OrderedDict[str, DynamicsModel] = OrderedDict()

    def model(self, wanted: str, fetch: Callable[[str], bytes | None]) -> DynamicsModel:
        """The inverse-dynamics model whose file hashes to `wanted`: from memory, from the
        cache directory, or else from `fetch(wanted)` (None if nobody served it)."""
        if wanted in self._decoded:
            self._decoded.move_to_end(wanted)
            return self._decoded[wanted]
        name = wanted[:12]
        raw = self._read(wanted)
        if raw is None:
            raw = fetch(wanted)
            if raw is None:
                raise ModelUnavailable(f"feed-forward model {name}: nobody on the farm serves it")
            served = digest(raw)
            if served != wanted:
                raise ModelUnavailable(
                    f"feed-forward model {name}: the bytes served hash to {served[:12]}, refused"
                )
            model = self._decode(raw, name)
            self._write(wanted, raw)
            self.fetched += 1
        else:
            model = self._decode(raw, name)
        self._decoded[wanted] = model
        if len(self._decoded) > MEMORY:
            self._decoded.popitem(last=False)
        return model

    def _read(self, wanted: str) -> bytes | None:
        path = self.directory / f"{wanted}.npz"
        try:
            raw = path.read_bytes()
            os.utime(path)  # used now: the last to go
        except OSError:
            return None
        return raw if digest(raw) == wanted else None  # a corrupted copy is fetched again

    def _write(self, wanted: str, raw: bytes) -> None:
        if len(raw) > self.max_bytes:
            return  # larger than the whole cache: fetched again after a restart
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            write_atomically(self.directory / f"{wanted}.npz", raw)
            self._trim(keep=f"{wanted}.npz")
        except OSError:
            pass  # an unwritable cache costs a fetch per restart, not the job

    def _trim(self, keep: str) -> None:
        """Remove the least recently used model files until at most max_bytes are left."""
        files = []
        for path in self.directory.iterdir():
            if _FILE.fullmatch(path.name):
                try:
                    stat = path.stat()
                except OSError:
                    continue  # removed meanwhile (another worker sharing the directory)
                files.append((stat.st_mtime_ns, path.name, stat.st_size))
        total = sum(size for _, _, size in files)
        for _, name, size in sorted(files):  # the oldest use first
            if total <= self.max_bytes:
                break
            if name != keep:
                (self.directory / name).unlink(missing_ok=True)
                total -= size

    @staticmethod
    def _decode(raw: bytes, name: str) -> DynamicsModel:
        try:
            return feedforward_from_bytes(raw)
        except BadDynamicsModel as error:
            raise ModelUnavailable(f"feed-forward model {name}: {error}") from None
