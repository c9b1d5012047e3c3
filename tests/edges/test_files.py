"""Files that say one thing together are written together: a Ctrl-C waits for the block. A file
or a directory built in place appears whole, with the mode of any other, or not at all."""

import os
import signal
import stat
from pathlib import Path

import pytest

from gainfarm.edges.files import interrupts_deferred, staging_directory, write_atomically


def test_a_ctrl_c_inside_the_block_arrives_once_the_block_is_done() -> None:
    done = []
    with pytest.raises(KeyboardInterrupt), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        done.append("the rest of the block")
    assert done == ["the rest of the block"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_without_a_ctrl_c_the_block_runs_and_the_handler_is_restored() -> None:
    with interrupts_deferred():
        pass
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_the_callers_own_handler_receives_the_held_ctrl_c() -> None:
    received = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        with interrupts_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            assert received == []
        assert received == [signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
def test_a_staging_directory_is_made_with_the_umask_s_mode(tmp_path: Path, umask: int) -> None:
    """What a dataset or a learned model is built in, then renamed to: readable by whoever the
    umask lets read it (tempfile.mkdtemp's 0700 would keep it from the rest of the farm)."""
    previous = os.umask(umask)
    try:
        made = [staging_directory(tmp_path / "dataset") for _ in range(3)]
    finally:
        os.umask(previous)
    assert len(set(made)) == 3
    for path in made:
        assert path.parent == tmp_path and path.is_dir() and not any(path.iterdir())
        assert path.name.startswith(".dataset.") and path.name.endswith(".part")
        assert stat.S_IMODE(path.stat().st_mode) == 0o777 & ~umask


def test_a_file_is_replaced_whole_and_a_failed_write_leaves_nothing(tmp_path: Path) -> None:
    target = tmp_path / "episode.mcap"
    target.write_bytes(b"old")
    write_atomically(target, b"new")
    assert target.read_bytes() == b"new" and os.listdir(tmp_path) == ["episode.mcap"]
    assert stat.S_IMODE(target.stat().st_mode) == 0o644
    with pytest.raises(TypeError):
        write_atomically(target, "not bytes")  # type: ignore[arg-type]  # fails mid-write
    assert target.read_bytes() == b"new" and os.listdir(tmp_path) == ["episode.mcap"]
    # The error names the file asked for, not the temporary one beside it.
    with pytest.raises(FileNotFoundError) as missing:
        write_atomically(tmp_path / "gone" / "episode.mcap", b"x")
    assert missing.value.filename == str(tmp_path / "gone" / "episode.mcap")
