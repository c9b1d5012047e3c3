"""`analytic replay`: a real episode rendered by MuJoCo offscreen (EGL, software), encoded as an
MP4 by a real process, decoded again by FFmpeg (PyAV): the right frames, the arm in them, the
reference path drawn; bad input is one line and leaves nothing behind."""

import ctypes.util
import os
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import pytest

from gainfarm.analytic.view import replay
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.mcap_episode import read_episode
from tests.helpers import analytic, needs, write_log

FPS, WIDTH, HEIGHT = 5, 480, 360


@pytest.fixture(autouse=True)
def offscreen_opengl() -> None:
    """These tests draw with MuJoCo offscreen: Mesa's EGL, from Debian's packages."""
    needs(
        ctypes.util.find_library("EGL") is not None,
        f"analytic replay's tests need offscreen OpenGL: Debian's {replay.DEBIAN_PACKAGES}",
    )


def colours(frame: np.ndarray) -> dict[str, int]:
    """How many pixels of each colour the video can hold: the reference path's green, the path
    taken's magenta, the arm's orange (none of the floor's greys or the sky's blue-greys)."""
    r, g, b = (frame[..., channel].astype(int) for channel in range(3))
    return {
        "green": int(((g > 150) & (r < 110) & (b < 110)).sum()),
        "magenta": int(((r > 150) & (b > 150) & (g < 110)).sum()),
        "orange": int(((r > 150) & (g > 60) & (g < 140) & (b < 80)).sum()),
    }


@pytest.fixture(scope="module")
def episode(tracking_log: EpisodeLog, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("replay") / "episode.mcap"
    write_log(tracking_log, path)
    return path


@pytest.mark.slow
def test_replay_shows_the_arm_following_its_reference(episode: Path, tracking_log, tmp_path):
    out = tmp_path / "episode.mp4"
    size = ("--width", str(WIDTH), "--height", str(HEIGHT))
    run = analytic(
        "replay", str(episode), "--out", str(out), "--fps", str(FPS), *size, cwd=tmp_path
    )
    assert run.returncode == 0, run.stderr
    expected = replay.frame_ticks(tracking_log.t, FPS)
    assert len(expected) == 16  # 0 to 3 s at 5 frames a second
    assert run.stdout == f"{out}: 16 frames, {WIDTH}x{HEIGHT} at {FPS} fps\n"
    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264" and stream.average_rate == FPS
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
    assert len(frames) == len(expected)
    assert {frame.shape for frame in frames} == {(HEIGHT, WIDTH, 3)}
    counts = [colours(frame) for frame in frames]
    for frame, count in zip(frames, counts, strict=True):
        assert frame.std() > 15  # a scene, not a blank
        assert count["orange"] > 1_500  # the arm (3,100 to 3,500 pixels)
        assert count["green"] > 10  # the reference path, all of it from the start (30 to 170)
    assert counts[0]["magenta"] == 0 and counts[-1]["magenta"] > 50  # the path taken, as it goes
    assert sorted(os.listdir(tmp_path)) == ["episode.mp4"]  # and no temporary file left


def test_the_colours_counted_are_the_paths(episode: Path, tracking_log, monkeypatch):
    """The control: the same frames drawn without the paths hold none of their colours."""
    ticks = replay.frame_ticks(tracking_log.t, FPS)[[0, -1]]
    with_paths = replay.render(tracking_log, ticks, WIDTH, HEIGHT)
    monkeypatch.setattr(replay, "_add_line", lambda *arguments: None)
    monkeypatch.setattr(replay, "_add_sphere", lambda *arguments: None)
    without = replay.render(tracking_log, ticks, WIDTH, HEIGHT)
    assert colours(with_paths[-1])["green"] > 10 and colours(with_paths[-1])["magenta"] > 50
    for frame in without:
        assert colours(frame)["green"] == colours(frame)["magenta"] == 0
        assert colours(frame)["orange"] > 1_500
    # The close-up in the bottom-right corner shows the paths near the desired point, large.
    corner = (slice(int(HEIGHT * (1 - replay.INSET_SHARE)), HEIGHT),
              slice(int(WIDTH * (1 - replay.INSET_SHARE)), WIDTH))  # fmt: skip
    close_up = colours(with_paths[-1][corner])
    assert close_up["green"] > 10 and close_up["magenta"] > 10, close_up
    assert colours(without[-1][corner])["green"] == 0


def test_frames_show_the_last_tick_at_or_before_their_time() -> None:
    t = np.arange(1501) * 0.002  # 3 s at the control period
    for fps in (1, 7, 30, 120):
        ticks = replay.frame_ticks(t, fps)
        assert len(ticks) == 3 * fps + 1
        times = np.arange(len(ticks)) / fps
        assert np.all(t[ticks] <= times + 1e-9) and np.all(times < t[ticks] + 0.002 - 1e-9)


@pytest.mark.slow
def test_bad_input_is_one_line_and_writes_nothing(episode: Path, tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(np.random.default_rng(0).bytes(4096))
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(episode.read_bytes()[:20_000])
    directory = tmp_path / "somewhere"
    directory.mkdir()
    out = str(tmp_path / "out.mp4")
    cases = [
        (
            (str(tmp_path / "missing.mcap"), "--out", out),
            f"analytic: error: LOG: {str(tmp_path / 'missing.mcap')!r}: no such file\n",
        ),
        (
            (str(directory), "--out", out),
            f"analytic: error: LOG: {str(directory)!r} is a directory, not an episode log (an "
            "MCAP file)\n",
        ),
        ((str(junk), "--out", out), "not an MCAP file"),
        ((str(truncated), "--out", out), "truncated MCAP file"),
        ((str(episode), "--out", str(tmp_path / "nowhere" / "x.mp4")), "--out: no directory"),
        ((str(episode), "--out", str(directory)), "--out: "),
        ((str(episode), "--out", out, "--width", "321"), "--width: must be even"),
    ]
    before = sorted(os.listdir(tmp_path))
    for arguments, message in cases:
        run = analytic("replay", *arguments, cwd=tmp_path)
        assert run.returncode == 2, (arguments, run.stderr)
        assert run.stderr.startswith("analytic: error: ") and run.stderr.count("\n") == 1
        assert message in run.stderr and "Traceback" not in run.stderr
    assert sorted(os.listdir(tmp_path)) == before
    assert os.listdir(directory) == []


@pytest.mark.slow
def test_replay_draws_the_arm_the_log_ran_a_ur5e_of_six_joints(tmp_path: Path) -> None:
    """A UR5e episode (6 joints, written by `worker episode --robot ur5e`) is drawn as the UR5e:
    its log names the arm, whose model draws it; asked for as another arm, it is refused."""
    episode = tmp_path / "ur5e.mcap"
    one_second = ("--trajectory", "fourier", "--duration", "1", "--out", str(episode))
    made = subprocess.run(
        [sys.executable, "-m", "gainfarm.worker", "episode", "--robot", "ur5e", *one_second],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=300,
    )
    assert made.returncode == 0, made.stderr
    out = tmp_path / "ur5e.mp4"
    size = ("--width", str(WIDTH), "--height", str(HEIGHT))
    run = analytic(
        "replay", str(episode), "--out", str(out), "--fps", str(FPS), *size, cwd=tmp_path
    )
    assert run.returncode == 0, run.stderr
    with av.open(str(out)) as container:
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
    assert len(frames) == 6  # 0 to 1 s at 5 frames a second
    for frame in frames:
        assert colours(frame)["orange"] > 1_000  # the UR5e's links (1,300 to 1,600 pixels)
    log = read_episode(episode)
    assert log.metadata.spec.plant.robot == "ur5e" and log.q.shape[1] == 6
    refused = analytic("replay", str(episode), "--out", str(out), "--robot", "iiwa14", cwd=tmp_path)
    assert refused.returncode == 2
    assert refused.stderr == (
        f"analytic: error: --robot: {str(episode)!r} is an episode of ur5e, not of iiwa14\n"
    )
