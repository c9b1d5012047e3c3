"""Files appear whole or not at all: every file gainfarm writes goes through here."""

import os
import tempfile
from pathlib import Path


def write_atomically(path: Path, content: bytes, mode: int = 0o644) -> None:
    """Write `content` to a temporary file beside `path`, then rename it into place.

    A reader (or a crash) never sees a half-written file, and a failed write leaves nothing behind.
    The default mode lets the rest of the farm read the file; private keys pass 0o600.
    """
    path = Path(path)
    fd, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as stream:
            stream.write(content)
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
