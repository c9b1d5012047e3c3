"""Files appear whole or not at all: every file gainfarm writes goes through here. And a directory
one process writes at a time: the lock that says which."""

import contextlib
import fcntl
import os
import secrets
import signal
import socket
import tempfile
import threading
import weakref
from collections.abc import Iterator
from pathlib import Path

# A write in progress: `.NAME.RANDOM.part` beside NAME (tempfile.mkstemp's prefix and suffix).
PART_PREFIX = "."
PART_SUFFIX = ".part"


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold a Ctrl-C (SIGINT) until the block is done, then deliver it: files that say one thing
    together (a run's records and its checkpoint) are all written, or none is. Only the main
    thread receives signals; elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[object] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(frame))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        if callable(previous):
            previous(signal.SIGINT, caught[0])
        elif previous != signal.SIG_IGN:
            raise KeyboardInterrupt


def write_atomically(path: Path, content: bytes, mode: int = 0o644) -> None:
    """Write `content` to a temporary file beside `path`, then rename it into place.

    A reader (or a crash) never sees a half-written file, and a failed write leaves nothing behind.
    The default mode lets the rest of the farm read the file; private keys pass 0o600. An OSError
    (disk full, read-only, no permission) names `path`, not the temporary file, so that it can be
    shown to the user as it is.
    """
    path = Path(path)
    temporary = None
    try:
        fd, temporary = tempfile.mkstemp(
            dir=path.parent, prefix=f"{PART_PREFIX}{path.name}.", suffix=PART_SUFFIX
        )
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as stream:
            stream.write(content)
        os.replace(temporary, path)
    except BaseException as error:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
        if isinstance(error, OSError) and error.errno is not None:
            error.filename, error.filename2 = str(path), None
        raise


def staging_directory(target: Path) -> Path:
    """A new, empty directory beside `target`, named as a write in progress (`.NAME.RANDOM.part`),
    to fill and then rename to `target`: the directory appears whole or not at all. Its mode is
    the umask's, as any directory made here (tempfile.mkdtemp would make it 0700, and the
    renamed result unreadable to the rest of the farm)."""
    target = Path(target)
    for _ in range(100):
        path = target.parent / f"{PART_PREFIX}{target.name}.{secrets.token_hex(4)}{PART_SUFFIX}"
        try:
            path.mkdir()  # mode 0o777, less the umask
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"no free name for a temporary directory beside {target}")


def remove_leftovers(directory: Path) -> list[Path]:
    """Delete the temporary files of writes that never finished (a process killed between its
    write and its rename) in `directory` and below; return them. Only the one process that
    writes `directory` may call this, holding its lock: another's write in progress looks the
    same."""
    found = [
        Path(parent) / name
        for parent, _, names in os.walk(directory)  # not into symlinked directories
        for name in names
        if name.startswith(PART_PREFIX) and name.endswith(PART_SUFFIX)
    ]
    for path in found:
        path.unlink(missing_ok=True)  # a symlink itself, never what it points to
    return found


def lock_held(path: Path) -> bool | None:
    """Whether some process holds `path`'s Lock now, read from the kernel's table of locks
    (/proc/locks) without touching the lock: a look that took it, even for an instant, could
    make the run that wants it refuse to start. None where the table cannot be read (no such
    file off Linux)."""
    try:
        status = os.stat(path)
    except FileNotFoundError:
        return False  # a Lock creates its file: none there, none held
    except OSError:
        return None
    try:
        table = Path("/proc/locks").read_text()
    except OSError:
        return None
    device = f"{os.major(status.st_dev):02x}:{os.minor(status.st_dev):02x}:{status.st_ino}"
    # A line: "1: FLOCK  ADVISORY  WRITE 25003 fe:00:2146493 0 EOF" (id, kind, ..., where).
    return any(
        fields[1] == "FLOCK" and fields[5] == device
        for fields in (line.split() for line in table.splitlines())
        if len(fields) >= 6
    )


class Locked(Exception):
    """Another process holds the lock."""

    def __init__(self, path: Path, holder: str):
        self.path = Path(path)
        self.holder = holder  # "process PID on HOST", or "" if it could not be read
        by = f" by {holder}" if holder else ""
        super().__init__(f"{self.path} is held{by}")


class Lock:
    """An exclusive lock on the file `path` (created if missing), taken at once or not at all
    (Locked). It is flock(2)'s: the kernel drops it when the process ends however it ends (kill
    -9 included), so no stale lock ever needs clearing, and it holds across processes of
    different PID namespaces (two containers) that share the file. The file says who holds it,
    for the message of the one refused. Released by `release()`, by `with`, or when the object
    is collected."""

    def __init__(self, path: Path):
        self.path = Path(path)
        # Read-only: the lock needs no write access, and a descriptor open for writing would keep
        # the file system from being remounted read-only under a run. Not inheritable (Python's
        # default), so no child process can keep the lock alive.
        # No following a symlink: the holder's name must not be written through one.
        fd = os.open(self.path, os.O_RDONLY | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip()
            os.close(fd)
            raise Locked(self.path, " ".join(holder.split())) from None
        except BaseException:
            os.close(fd)
            raise
        self._release = weakref.finalize(self, os.close, fd)
        try:  # only now, holding the lock, may the holder's name be replaced
            writing = os.open(self.path, os.O_WRONLY | os.O_TRUNC | os.O_NOFOLLOW)
            with os.fdopen(writing, "w") as stream:
                stream.write(f"process {os.getpid()} on {socket.gethostname()}\n")
        except OSError:  # the holder's name is a courtesy: a full disk must not lose the lock
            pass

    @property
    def held(self) -> bool:
        return self._release.alive

    def release(self) -> None:
        self._release()

    def __enter__(self) -> "Lock":
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
