"""A frozen release: its files, a content hash that verifies and changes with any byte, stats over
train only, fixed splits, the loader, and the LeRobot copy read back by a reader of our own
written from LeRobot's v3.0 layout (LeRobot itself requires PyTorch, not installable here).

One release is built, from a real tuning run on a real local farm, and shared by the tests."""

import hashlib
import itertools
import json
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from gainfarm.analytic import TickDataset, load_dataset
from gainfarm.analytic.data.release import (
    LerobotLayout,
    build_release,
    content_hash,
    verify,
)
from gainfarm.analytic.evaluators.local import local_farm
from gainfarm.models import robot_of
from gainfarm.schemas.robot import JOINT_NAMES
from gainfarm.schemas.trajectory import TrajectorySpec
from tests.analytic.data.test_dataset import CONFIG, UR5E_RUN, farm_at, tune
from tests.helpers import analytic

NAME = "iiwa14-sim_0.1"
KINDS = ("plant", "rigid", "linear")  # cheap: no network is trained
# Rerun on the run's plant and a variant; its split (test, by the split seed's hash) gives the
# release a test_variants split.
VARIED = TrajectorySpec(kind="fourier", seed=7, duration=1.0)
# Small files, few to a chunk: the export's chunking is exercised on a small dataset.
LAYOUT = LerobotLayout(chunks_size=3, file_frames=4000)
SIGNALS = {
    "q": "q",
    "qd": "qd",
    "qdd": "qdd_sg",
    "u": "u_motor",
    "tau": "tau",
    "theta": "theta",
    "theta_d": "theta_d",
    "q_des": "q_des",
    "qd_des": "qd_des",
}


@pytest.fixture(scope="module")
def endpoint() -> Iterator[str]:
    with local_farm(workers=2) as endpoint:
        yield endpoint


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory, endpoint: str) -> Path:
    return tune(tmp_path_factory.mktemp("runs") / "generic", CONFIG, endpoint)


@pytest.fixture(scope="module")
def release(
    run_dir: Path, endpoint: str, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, dict]:
    """The front on its run's trajectories, and once more on a short excitation (a test
    trajectory) on its plant and on a variant of it: every kind of split has episodes."""
    out = tmp_path_factory.mktemp("releases") / NAME
    _, record = build_release(
        [run_dir], out, NAME, kinds=KINDS, format="lerobot", layout=LAYOUT,
        rerun_trajectories=[VARIED], rerun_plants=1, farm=farm_at(endpoint),
        infeasible=True, include_rough=True,  # a toy run's front, kept whatever it does
    )  # fmt: skip
    return out, record


def ticks(directory: Path) -> dict[str, np.ndarray]:
    table = pq.read_table(directory / "ticks.parquet")
    return {name: table[name].to_numpy(zero_copy_only=False) for name in table.column_names}


def episodes(directory: Path) -> list[dict[str, Any]]:
    return pq.read_table(directory / "episodes.parquet").to_pylist()


def independent_hashes(directory: Path) -> tuple[dict[str, str], str]:
    """Every Parquet table and MCAP log's SHA-256, and the hash of `sha256sum`'s lines for
    them sorted by path: recomputed here, not by the code under test."""
    paths = [p for p in directory.iterdir() if p.suffix == ".parquet"]
    paths += [p for p in (directory / "episodes").iterdir() if p.suffix == ".mcap"]
    hashes = {
        p.relative_to(directory).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in paths
    }
    lines = "".join(f"{hashes[path]}  {path}\n" for path in sorted(hashes))
    return hashes, hashlib.sha256(lines.encode()).hexdigest()


@pytest.mark.slow
def test_the_release_holds_its_files_and_its_content_hash_verifies(
    release: tuple[Path, dict],
) -> None:
    out, record = release
    for name in ("release.json", "stats.json", "baselines.json", "README.md", "ticks.parquet"):
        assert (out / name).is_file(), name
    assert json.loads((out / "release.json").read_text()) == record
    hashes, expected = independent_hashes(out)
    assert {entry["path"]: entry["sha256"] for entry in record["files"]} == hashes
    assert len(hashes) == 3 + len(episodes(out))  # the three tables and every log
    assert record["content_hash"] == expected
    assert verify(out) == []
    assert record["name"] == NAME and record["dataset_version"] == "5"
    assert record["robot_type"] == "kuka_iiwa14"
    assert record["control_rate_hz"] == 500 and record["control_period_s"] == 0.002
    # The plants: the episodes' distinct models, the run's own nominal, the variant's not.
    models = {json.dumps(json.loads(row["model"]), sort_keys=True) for row in episodes(out)}
    assert {json.dumps(p["model"], sort_keys=True) for p in record["plants"]} == models
    assert [p["role"] for p in record["plants"]] == ["nominal", "variant"]
    variant = [row for row in episodes(out) if row["split"].endswith("_variants")]
    assert record["plants"][1]["episodes"] == len(variant) > 0
    assert all(json.loads(row["model"]) == record["plants"][1]["model"] for row in variant)
    # The export's files are listed with their hashes, apart from the content hash.
    exported = {entry["path"]: entry["sha256"] for entry in record["exports"]}
    assert "lerobot/meta/info.json" in exported
    for path, digest in exported.items():
        assert hashlib.sha256((out / path).read_bytes()).hexdigest() == digest
    # Nothing of the staging directory is left beside the release.
    assert [p.name for p in out.parent.iterdir()] == [NAME]


@pytest.mark.slow
def test_a_changed_byte_changes_the_content_hash(
    release: tuple[Path, dict], tmp_path: Path
) -> None:
    out, record = release
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)  # a copy: the logs are hard links to the run's
    path = copy / "ticks.parquet"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    hashes, recomputed = independent_hashes(copy)
    assert recomputed != record["content_hash"]
    assert verify(copy) == ["changed: ticks.parquet"]
    files = [{"path": path, "sha256": digest} for path, digest in hashes.items()]
    assert content_hash(files) == recomputed != record["content_hash"]


@pytest.mark.slow
def test_the_stats_are_over_the_train_split_only(release: tuple[Path, dict]) -> None:
    out, _ = release
    stats = json.loads((out / "stats.json").read_text())
    columns = ticks(out)
    train = columns["split"] == "train"
    assert 0 < train.sum() < len(train)
    numeric = [name for name, values in columns.items() if values.dtype.kind in "fi"]
    assert set(stats) == set(numeric)
    for name in numeric:
        values = columns[name][train].astype(float)
        finite = values[np.isfinite(values)]
        entry = stats[name]
        assert entry["count"] == finite.size
        for statistic, expected in (
            ("mean", finite.mean()),
            ("std", finite.std()),
            ("min", finite.min()),
            ("max", finite.max()),
        ):
            assert entry[statistic] == pytest.approx(expected, rel=1e-12, abs=1e-12), name
    # Not the whole table's: the test trajectories move the arm elsewhere.
    assert stats["q_A1"]["mean"] != pytest.approx(np.nanmean(columns["q_A1"]), rel=1e-6)
    assert stats["u_motor_A2"]["unit"] == "N*m"


@pytest.mark.slow
def test_the_splits_cover_every_episode_once_and_test_calm_is_calm_test(
    release: tuple[Path, dict],
) -> None:
    out, record = release
    rows = {row["episode_id"]: row for row in episodes(out)}
    splits = record["splits"]
    assert list(splits) == ["train", "validation", "test", "test_variants", "test_calm"]
    ids = {split: [e["episode_id"] for e in part["episodes"]] for split, part in splits.items()}
    whole = ("train", "validation", "test", "test_variants")
    parts = [set(ids[split]) for split in whole]
    assert sum(len(part) for part in parts) == len(rows) and set().union(*parts) == set(rows)
    # One plant per part: the variant's episodes on the test trajectory the plant's own are on.
    assert len(ids["test_variants"]) == sum("-rerun-" in i for i in ids["test"]) > 0
    assert all("-rerun-p1-" in i for i in ids["test_variants"])
    assert {t["trajectory_id"] for t in splits["test_variants"]["trajectories"]} <= {
        t["trajectory_id"] for t in splits["test"]["trajectories"]
    }
    assert set(ids["test_calm"]) == {i for i in ids["test"] if rows[i]["calm"]}
    assert set(ids["test_calm"]) <= set(ids["test"])
    trajectories = [
        {t["trajectory_id"] for t in splits[split]["trajectories"]}
        for split in ("train", "validation", "test")
    ]
    assert not (trajectories[0] & trajectories[1] or trajectories[0] & trajectories[2])
    assert not trajectories[1] & trajectories[2]
    for split, part in splits.items():
        for entry in part["episodes"]:
            row = rows[entry["episode_id"]]
            assert row["split"] == (split if split != "test_calm" else "test")
            assert (entry["trajectory_id"], entry["ticks"]) == (row["trajectory_id"], row["ticks"])
        assert part["ticks"] == sum(e["ticks"] for e in part["episodes"])
    assert sum(splits[s]["ticks"] for s in whole) == len(ticks(out)["t"])


@pytest.mark.slow
def test_load_dataset_gives_the_parquet_columns(release: tuple[Path, dict], tmp_path: Path) -> None:
    out, _ = release
    columns = ticks(out)
    stats = json.loads((out / "stats.json").read_text())
    calm = {row["episode_id"]: row["calm"] for row in episodes(out)}
    for split in ("train", "validation", "test", "test_calm", "test_variants"):
        loaded = load_dataset(out, split)
        rows = columns["split"] == (split if split != "test_calm" else "test")
        if split == "test_calm":
            rows &= np.array([calm[e] for e in columns["episode_id"]])
        assert len(loaded) == rows.sum() > 0
        np.testing.assert_array_equal(loaded.episode_id, columns["episode_id"][rows])
        np.testing.assert_array_equal(loaded.t, columns["t"][rows])
        for attribute, column in SIGNALS.items():
            expected = np.column_stack([columns[f"{column}_{j}"][rows] for j in JOINT_NAMES])
            np.testing.assert_array_equal(getattr(loaded, attribute), expected)
        np.testing.assert_array_equal(loaded.inputs(), np.hstack([loaded.q, loaded.qd, loaded.qdd]))
        np.testing.assert_array_equal(loaded.targets(), loaded.u)
        assert loaded.stats == stats
        mean = np.array([stats[f"u_motor_{j}"]["mean"] for j in JOINT_NAMES])
        std = np.array([stats[f"u_motor_{j}"]["std"] for j in JOINT_NAMES])
        np.testing.assert_allclose(loaded.targets(normalised=True), (loaded.u - mean) / std)
    # Normalised by train's statistics, the train inputs are centred and of unit spread.
    train = load_dataset(out).inputs(normalised=True)
    finite = np.isfinite(train).all(axis=1)
    np.testing.assert_allclose(train[finite].mean(axis=0), 0, atol=0.05)
    with pytest.raises(ValueError, match=r"'tset'.*train, validation, test, test_calm, train_var"):
        load_dataset(out, "tset")
    # A dataset that is not a release (its tables alone, as `analytic dataset` writes them):
    # the same arrays, no stats.
    plain = tmp_path / "plain"
    plain.mkdir()
    for name in ("ticks.parquet", "episodes.parquet"):
        shutil.copy(out / name, plain / name)
    loaded = load_dataset(plain, "test")
    assert loaded.stats is None
    np.testing.assert_array_equal(loaded.u, load_dataset(out, "test").u)
    with pytest.raises(ValueError, match=r"stats\.json"):
        loaded.inputs(normalised=True)


@pytest.mark.slow
def test_the_tick_dataset_gives_float32_rows_a_data_loader_takes(
    release: tuple[Path, dict],
) -> None:
    out, _ = release
    split = load_dataset(out, "train")
    dataset = TickDataset(split)
    inputs, targets = split.inputs(), split.targets()
    finite = np.isfinite(inputs).all(axis=1) & np.isfinite(targets).all(axis=1)
    assert len(dataset) == finite.sum() > 0
    for index in (0, len(dataset) // 2, len(dataset) - 1):
        x, y = dataset[index]
        assert x.dtype == y.dtype == np.float32 and x.shape == (21,) and y.shape == (7,)
        row = np.flatnonzero(finite)[index]
        np.testing.assert_array_equal(x, inputs[row].astype(np.float32))
        np.testing.assert_array_equal(y, targets[row].astype(np.float32))
    normalised = TickDataset(split, normalised=True)
    np.testing.assert_allclose(
        normalised[0][1], split.targets(normalised=True)[np.flatnonzero(finite)[0]], rtol=1e-6
    )


@pytest.mark.slow
def test_the_baselines_are_every_kind_on_the_frozen_test_split(
    release: tuple[Path, dict],
) -> None:
    out, _ = release
    baselines = json.loads((out / "baselines.json").read_text())
    assert list(baselines) == list(KINDS)
    test_rows = sum(
        1
        for s, q in zip(ticks(out)["split"], ticks(out)["qdd_sg_A1"], strict=True)
        if s == "test" and np.isfinite(q)
    )
    assert all(scores["rows"] == test_rows for scores in baselines.values())
    # The floor is the floor: no baseline beats the plant's own dynamics, on the test split's
    # plant nor on the variant's (the floor there its own plant, no longer the run's).
    for split in (None, "variants"):
        scored = {kind: s[split] if split else s for kind, s in baselines.items()}
        assert all(s["nmse_mean"] >= scored["plant"]["nmse_mean"] for s in scored.values())
    variant_rows = sum(
        1
        for s, q in zip(ticks(out)["split"], ticks(out)["qdd_sg_A1"], strict=True)
        if s == "test_variants" and np.isfinite(q)
    )
    assert all(s["variants"]["rows"] == variant_rows > 0 for s in baselines.values())
    card = (out / "README.md").read_text()
    section = card[card.index("## Baselines") :]
    for kind, scores in baselines.items():
        assert f"{scores['nmse_mean']:.3g}" in section, kind
    assert "plant's own dynamics (the floor)" in section and "0.14 N·m" in section
    best = min(
        (s for kind, s in baselines.items() if kind not in ("plant", "rigid")),
        key=lambda s: s["rmse_a1_a4"],
    )
    ratio = best["nmse_mean"] / baselines["plant"]["nmse_mean"]
    assert f"test nMSE is {ratio:.2g} times the floor's" in section
    assert f"## Release `{NAME}`" in card and record_hash(out) in card
    assert "kuka_iiwa14" in card and "500 Hz" in card and "FRI" in card
    assert "| test_calm |" in card and "| test_variants |" in card
    assert "nMSE test_variants" in section


def record_hash(out: Path) -> str:
    return json.loads((out / "release.json").read_text())["content_hash"]


def read_lerobot(root: Path) -> dict[str, Any]:
    """A reader of LeRobot's v3.0 layout written from its definition (info.json's data_path
    template resolved per chunk and file, whole episodes per file, the episodes' metadata
    giving each episode's file and global frame range), checking it as it reads. Returns the
    frames of each episode by index, and the metadata."""
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["video_path"] is None
    features = info["features"]
    for name in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
        assert features[name]["shape"] == [1], name
    meta = pq.read_table(root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
    rows = meta.to_pylist()
    assert [row["episode_index"] for row in rows] == list(range(info["total_episodes"]))
    tasks = pq.read_table(root / "meta" / "tasks.parquet")
    assert tasks["task_index"].to_pylist() == [0] and info["total_tasks"] == 1
    assert json.loads(tasks.schema.metadata[b"pandas"])["index_columns"] == ["task"]
    files: dict[tuple[int, int], pa.Table] = {}
    for row in rows:
        key = (row["data/chunk_index"], row["data/file_index"])
        assert key[1] < info["chunks_size"]
        if key not in files:
            path = root / info["data_path"].format(chunk_index=key[0], file_index=key[1])
            files[key] = pq.read_table(path)
    # Every data file on disk is one the metadata points to.
    on_disk = {p.relative_to(root).as_posix() for p in (root / "data").rglob("*.parquet")}
    assert on_disk == {info["data_path"].format(chunk_index=c, file_index=f) for c, f in files}
    for table in files.values():
        for name, spec in features.items():
            arrow = table.schema.field(name).type
            if spec["shape"] == [1]:
                assert arrow == pa.from_numpy_dtype(np.dtype(spec["dtype"])), name
            else:
                assert pa.types.is_fixed_size_list(arrow), name
                assert arrow.list_size == spec["shape"][0] == len(spec["names"]), name
                assert arrow.value_type == pa.from_numpy_dtype(np.dtype(spec["dtype"])), name
    assert sum(t.num_rows for t in files.values()) == info["total_frames"]
    frames = {}
    for row in rows:
        table = files[(row["data/chunk_index"], row["data/file_index"])]
        mine = table.filter(pc.equal(table["episode_index"], row["episode_index"]))
        assert mine.num_rows == row["length"] == row["dataset_to_index"] - row["dataset_from_index"]
        assert mine["index"].to_pylist() == list(
            range(row["dataset_from_index"], row["dataset_to_index"])
        )
        assert mine["frame_index"].to_pylist() == list(range(row["length"]))
        frames[row["episode_index"]] = mine
    # The global index runs 0..total_frames - 1 over the episodes in order.
    assert rows[0]["dataset_from_index"] == 0
    for before, after in itertools.pairwise(rows):
        assert after["dataset_from_index"] == before["dataset_to_index"]
    assert rows[-1]["dataset_to_index"] == info["total_frames"]
    # The splits: contiguous ranges, disjoint, covering every episode.
    covered: list[int] = []
    for split, text in info["splits"].items():
        start, end = (int(value) for value in text.split(":"))
        assert all(rows[i]["split"] == split for i in range(start, end))
        covered += range(start, end)
    assert sorted(covered) == list(range(info["total_episodes"]))
    return {"info": info, "episodes": rows, "frames": frames}


@pytest.mark.slow
def test_the_lerobot_copy_passes_an_independent_reader(release: tuple[Path, dict]) -> None:
    out, _ = release
    read = read_lerobot(out / "lerobot")
    info = read["info"]
    assert info["robot_type"] == "kuka_iiwa14" and info["fps"] == 500
    columns = ticks(out)
    assert info["total_frames"] == len(columns["t"]) and info["total_episodes"] == len(
        episodes(out)
    )
    assert len({(r["data/chunk_index"], r["data/file_index"]) for r in read["episodes"]}) > 3
    by_id = {row["episode_id"]: row for row in episodes(out)}
    for row in read["episodes"]:
        assert row["split"] == by_id[row["episode_id"]]["split"]
        frames = read["frames"][row["episode_index"]]
        mine = columns["episode_id"] == row["episode_id"]
        for feature, spec in info["features"].items():
            if spec["shape"] == [1]:
                continue
            stored = np.array(frames[feature].to_pylist(), dtype=np.float32)
            expected = np.column_stack([columns[name][mine] for name in spec["names"]])
            np.testing.assert_array_equal(stored, expected.astype(np.float32), err_msg=feature)
        np.testing.assert_array_equal(
            frames["timestamp"].to_numpy(), columns["t"][mine].astype(np.float32)
        )
    # The stats are the train frames'.
    stats = json.loads((out / "lerobot" / "meta" / "stats.json").read_text())
    train = columns["split"] == "train"
    state = np.column_stack(
        [columns[name][train] for name in info["features"]["observation.state"]["names"]]
    ).astype(np.float32)  # the stored values, their statistics in float64
    np.testing.assert_allclose(stats["observation.state"]["mean"], state.mean(0, float), rtol=1e-9)
    np.testing.assert_allclose(stats["observation.state"]["std"], state.std(0, float), rtol=1e-9)
    np.testing.assert_array_equal(stats["observation.state"]["max"], state.max(axis=0))
    assert stats["observation.state"]["count"] == [int(train.sum())]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--release", "../escape"], "--release: '../escape' is not a release name"),
        (["--release", ""], "--release: '' is not a release name"),
        (["--format", "lerobot"], "--format lerobot needs --release NAME"),
        (["--release", "fine", "--split", "0.5,0.5,0"], "--split: a release is scored on"),
        (["--baselines", "plant"], "--baselines needs --release NAME"),
        (["--release", "v1", "--baselines", "plant,wavelet"], "--baselines: expected distinct"),
        (["--release", "v1", "--baselines", "plant,plant"], "--baselines: expected distinct"),
    ],
)
def test_bad_release_options_are_one_line_and_write_nothing(
    run_dir: Path, tmp_path: Path, options: list[str], message: str
) -> None:
    run = analytic("dataset", str(run_dir), "--out", "out", *options, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.startswith(f"analytic: error: {message}"), run.stderr
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr
    assert list(tmp_path.iterdir()) == []


def test_names_made_of_the_allowed_characters_pass() -> None:
    from gainfarm.analytic.data.release import BadRelease, check_name

    for name in ("v1", "iiwa14-sim_0.1", "A" * 64):
        assert check_name(name) == name
    for name in (".hidden", "a b", "a/b", "A" * 65, "ü"):
        with pytest.raises(BadRelease, match=re.escape(repr(name))):
            check_name(name)


@pytest.mark.slow
def test_a_release_that_fails_leaves_nothing(run_dir: Path, tmp_path: Path) -> None:
    from gainfarm.analytic.data.learning import LearnError

    # The dataset is staged whole before its baselines fail: neither appears, nor the staging.
    with pytest.raises(LearnError, match="unknown model 'nonsense'"):
        build_release([run_dir], tmp_path / "out", "v1", kinds=("plant", "nonsense"))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_the_release_command_writes_the_release_the_library_does(
    run_dir: Path, endpoint: str, release: tuple[Path, dict], tmp_path: Path
) -> None:
    """The CLI's release of the module's run is the library's, byte for byte in its data."""
    _, record = release
    (tmp_path / "rerun.json").write_text(f"[{VARIED.model_dump_json()}]")
    run = analytic(
        "dataset", str(run_dir), "--out", "cli", "--release", NAME,
        "--baselines", ",".join(KINDS), "--rerun", "rerun.json", "--plants", "1",
        "--infeasible", "--include-rough", "--connect", endpoint, cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    line = run.stdout.splitlines()[-1]
    assert line.startswith(f"cli: release {NAME} (gainfarm), content hash {record['content_hash']}")
    assert re.search(r"baselines fitted in \d+ s$", line), line
    written = json.loads((tmp_path / "cli" / "release.json").read_text())
    assert written["content_hash"] == record["content_hash"]
    assert written["baselines"]["kinds"] == list(KINDS)


# --- another arm: the UR5e (6 joints) ------------------------------------------------------------


@pytest.fixture(scope="module")
def ur5e_dir(tmp_path_factory: pytest.TempPathFactory, endpoint: str) -> Path:
    return tune(tmp_path_factory.mktemp("ur5e") / "ur5e", UR5E_RUN, endpoint)


@pytest.mark.slow
def test_a_ur5e_release_and_its_lerobot_copy_name_the_arm(ur5e_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "ur5e-sim_0.1"
    _, record = build_release(
        [ur5e_dir], out, "ur5e-sim_0.1", kinds=("plant", "rigid"), format="lerobot",
        layout=LAYOUT, infeasible=True, include_rough=True,
    )  # fmt: skip
    joints = list(robot_of("ur5e").joint_names)
    release = json.loads((out / "release.json").read_text())
    assert release == record
    assert (record["robot"], record["robot_type"]) == ("ur5e", "universal_robots_ur5e")
    assert record["joint_names"] == joints
    read = read_lerobot(out / "lerobot")
    info = read["info"]
    assert info["robot_type"] == "universal_robots_ur5e"
    state = info["features"]["observation.state"]
    assert state["shape"] == [12] and state["names"][:6] == [f"q_{j}" for j in joints]
    assert info["features"]["action"]["names"] == [f"u_motor_{j}" for j in joints]
    columns = ticks(out)
    row = read["episodes"][0]
    mine = columns["episode_id"] == row["episode_id"]
    stored = np.array(read["frames"][row["episode_index"]]["action"].to_pylist(), np.float32)
    expected = np.column_stack([columns[f"u_motor_{j}"][mine] for j in joints]).astype(np.float32)
    np.testing.assert_array_equal(stored, expected)
    card = (out / "README.md").read_text()
    assert "Robot type `universal_robots_ur5e`, a simulated Universal Robots UR5e" in card
    assert "RMSE shoulder_pan_joint-wrist_1_joint all (N·m)" in card
    assert "real iiwa 14" not in card
    split = load_dataset(out, "train")
    assert split.joint_names == tuple(joints) and split.inputs(normalised=True).shape[1] == 18
