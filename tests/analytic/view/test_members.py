"""A run's members as the dashboard shows them (analytic.view.members), on a real run: the table
is front.csv's rows with their picks, checks and held-out results; a member's files are `analytic
export`'s bytes; its episode is its kept log, or the same episode simulated again."""

import base64
import dataclasses
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from gainfarm.analytic.tuning.check import advice_of, read_check
from gainfarm.analytic.tuning.picks import picks
from gainfarm.analytic.tuning.records import read_front, read_run
from gainfarm.analytic.view.export import FORMATS, baseline_of
from gainfarm.analytic.view.members import (
    Slot,
    episode,
    export_links,
    robustness_text,
    series,
    slots,
    table,
)
from gainfarm.analytic.view.members import (
    columns as member_columns,
)
from gainfarm.cli.words import counted
from gainfarm.models import robot_of
from gainfarm.schemas.mcap_episode import read_episode
from gainfarm.schemas.robot import JOINT_NAMES
from tests.helpers import analytic

# Two trajectories' worth of slots: one trajectory on the nominal plant and a variant, and a
# held-out check on one more plant.
TUNING = (
    "--trajectory", "fourier", "--duration", "0.5", "--pop", "4", "--generations", "2",
    "--plants", "1", "--check-plants", "1", "--local",
)  # fmt: skip


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    here = tmp_path_factory.mktemp("members")
    ran = analytic("start", *TUNING, "--out", "run", cwd=here)
    assert ran.returncode == 0, ran.stderr
    return here / "run"


def test_the_table_is_front_csv_with_each_rows_picks_checks_and_held_out_results(
    run_dir: Path,
) -> None:
    record = read_run(run_dir)
    check = read_check(run_dir)
    assert check is not None
    defaults = robot_of(record.config.plant).default_gains  # the run arm's
    named = picks(record.front, baseline_of(run_dir, defaults), advice_of(check))
    columns = table(record.front, named, record.config, check)
    assert list(columns) == list(member_columns(JOINT_NAMES))
    front = read_front(run_dir / "front.csv")
    assert columns["row"] == list(range(1, len(front) + 1))
    for k, member in enumerate(front):
        assert columns["f_acc_mm"][k] == member.f_acc * 1000
        assert [columns[f"kp_A{j}"][k] for j in range(1, 8)] == list(member.kp)
        assert [columns[f"kd_A{j}"][k] for j in range(1, 8)] == list(member.kd)
        assert columns["limits"][k] == "within"  # the front keeps to the run's limits
        assert columns["validation"][k] == "not checked ×2"  # two episodes, a trusted farm
    for pick in named:
        assert pick.name in columns["picked"][pick.row - 1].split(", ")
    checked = [row for row, text in zip(columns["row"], columns["held_out"], strict=True) if text]
    assert checked and set(checked) <= {item["row"] for item in check["controllers"]}
    said = robustness_text(named, check, 1)
    errors = (
        r"error [\d.]+ mm median, [\d.]+ mm worst on 1 plant; [01] broke a limit, [01] diverged"
    )
    if named[0].name == "closest":  # the check kept the default gains
        assert re.fullmatch(
            rf"Held-out check: no member held against the default gains; keep them \({errors}\)\.",
            said,
        ), said
    else:
        assert re.fullmatch(
            rf"Held-out check of row {named[0].row} \(recommended\): {errors}; the default "
            rf"gains: {errors}\.",
            said,
        ), said
    assert "of the 3 asked: the check's budget" in robustness_text(named, check, 3)
    assert robustness_text(named, None, 0).startswith("Held-out check: not run")
    assert robustness_text(named, None, 4) == (
        "Held-out check: not written (`analytic resume RUN` runs it)."
    )


def test_a_members_files_are_the_export_commands_bytes(run_dir: Path) -> None:
    row = len(read_front(run_dir / "front.csv"))  # the last row: any row, not only a pick
    link = r'download="([^"]+)" href="data:[^;]+;base64,([^"]+)"'
    links = dict(re.findall(link, export_links(run_dir, row)))
    assert len(links) == len(FORMATS)
    for fmt, (name, encoded) in zip(FORMATS, links.items(), strict=True):
        exported = analytic(
            "export", str(run_dir), "--member", str(row), "--format", fmt, cwd=run_dir.parent
        )
        assert exported.returncode == 0, exported.stderr
        assert base64.b64decode(encoded) == exported.stdout.encode(), name
    assert export_links(run_dir, row + 1) == (
        f"row {row + 1}: row {row + 1} is out of range: front.csv has {counted(row, 'member')} "
        f"(1-{row})"
    )


def test_an_episode_is_its_kept_log_or_else_the_same_episode_simulated_again(
    run_dir: Path, tmp_path: Path
) -> None:
    record = read_run(run_dir)
    member = sorted(record.front, key=lambda m: m.f_acc)[0]
    assert slots(record.config) == [Slot(0, 0), Slot(0, 1)]
    assert [slot.label() for slot in slots(record.config)] == [
        "trajectory 1 (0.5 s fourier) on the nominal plant",
        "trajectory 1 (0.5 s fourier) on plant variant 1",
    ]
    for slot, log in zip(slots(record.config), member.logs, strict=True):
        found, where = episode(run_dir, record.config, member, slot)
        assert where == f"its log, {log}"
        kept = read_episode(run_dir / log)
        assert found is not None and np.array_equal(found.q, kept.q)
        # The same run without its logs: the episode is simulated again, to the same numbers.
        bare = tmp_path / f"bare{slot.plant}"
        shutil.copytree(run_dir, bare, ignore=shutil.ignore_patterns("*.mcap"))
        again, why = episode(bare, record.config, member, slot)
        assert why.startswith("simulated again here")
        assert again is not None
        drawn, redrawn = series(kept), series(again)
        assert drawn == redrawn
        assert drawn["error"]["error_mm"] == list(
            np.linalg.norm(kept.ee - kept.ee_des, axis=1) * 1000
        )
        assert len(drawn["joints"]["t"]) == kept.ticks and len(drawn["torques"]) == 15


def test_an_episode_simulated_again_is_cached_and_simulated_one_at_a_time(
    run_dir: Path, tmp_path: Path
) -> None:
    """The dashboard asks for an episode at every click: one simulated again is kept (the
    latest few), and while one is being simulated another is refused at once, not queued."""
    from gainfarm.analytic.view import members

    record = read_run(run_dir)
    bare = tmp_path / "bare"
    shutil.copytree(run_dir, bare, ignore=shutil.ignore_patterns("*.mcap"))
    member, (first, second) = record.front[0], slots(record.config)
    found, why = episode(bare, record.config, member, first)
    assert found is not None and why.startswith("simulated again here")
    again, _ = episode(bare, record.config, member, first)
    assert again is found  # the cached episode, not a second simulation
    with members._SIMULATING:  # another click's simulation under way
        busy, said = episode(bare, record.config, member, second)
        cached, _ = episode(bare, record.config, member, first)
    assert busy is None and said == members.BUSY
    assert cached is found  # a cached episode needs no simulation: shown even then
    for step in range(members.CACHED_EPISODES + 1):  # more distinct episodes than are kept
        other = dataclasses.replace(member, kp=tuple(k * (1 + step / 100) for k in member.kp))
        assert episode(bare, record.config, other, second)[0] is not None
    assert len(members._SIMULATED) == members.CACHED_EPISODES
    assert episode(bare, record.config, member, first)[0] is not found  # the oldest went


def test_a_kept_log_named_outside_the_run_is_not_read(run_dir: Path, tmp_path: Path) -> None:
    record = read_run(run_dir)
    log = Path(record.front[0].logs[0])  # episodes/<job id>.mcap: its name says its slot
    shutil.copyfile(run_dir / log, tmp_path / log.name)
    outside = f"../{log.name}"
    member = dataclasses.replace(record.front[0], logs=(outside,))
    run = tmp_path / "run"
    run.mkdir()
    found, why = episode(run, record.config, member, slots(record.config)[0])
    assert found is None and why == f"{outside!r} lies outside the run: not read"
