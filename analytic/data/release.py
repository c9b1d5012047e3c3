"""A frozen release of a dataset (analytic/data/dataset.py): what a paper cites and a learner
trains on, the same bytes for everyone.

`analytic dataset RUN... --out DIR --release NAME` builds the dataset as ever and adds, in its
staging directory before it is renamed into place (so the release appears whole or not at all):

    release.json    name, version, the content hash and every data file's SHA-256, the fixed
                    splits (train, validation, test, test_calm) by episode and trajectory with
                    their ticks, the control rate, the robot type, the plants
    stats.json      per-column normalisation statistics of ticks.parquet over TRAIN only
    baselines.json  baselines.benchmark: every baseline model fitted on train, scored on test
    lerobot/        with --format lerobot: the same ticks in LeRobot's v3.0 layout (lerobot.py)

and a release section and the baselines' table in the card (README.md).

The content hash is the SHA-256 of the lines `sha256sum` prints for the data files (the Parquet
tables and the MCAP logs), sorted by path: `sha256sum *.parquet episodes/*.mcap | LC_ALL=C
sort -k2 | sha256sum` in the directory recomputes it, and release.json's per-file hashes say
which file changed if it does not match (`verify`). The files made from the data (stats,
baselines, card, LeRobot copy) are not in it, so a release's hash is the same whatever its
--format.
"""

import hashlib
import importlib.util
import json
import math
import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from gainfarm.analytic.data import baselines, learning, lerobot
from gainfarm.analytic.data.arm import robot_type, title
from gainfarm.analytic.data.dataset import (
    DATASET_VERSION,
    build,
    check_split,
    interface_text,
)
from gainfarm.analytic.data.dataset_columns import JOINTS_BEFORE, ROBOT_BEFORE
from gainfarm.analytic.data.learning_report import (
    PUBLISHED_JOINTS,
    PUBLISHED_RMSE,
    PUBLISHED_ROBOT,
    mean_joints,
    span,
)
from gainfarm.analytic.data.lerobot import DEFAULT_LAYOUT, LerobotLayout
from gainfarm.analytic.data.loader import ALL_SPLITS, VARIANTS, dataset_arm
from gainfarm.analytic.view.export import plant_name
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import CONTROL_PERIOD

RELEASE_JSON, STATS_JSON, BASELINES_JSON, CARD = (
    "release.json",
    "stats.json",
    "baselines.json",
    "README.md",
)
TICKS, EPISODES = "ticks.parquet", "episodes.parquet"
LEROBOT_DIR = "lerobot"
RELEASE_FORMAT = "1"  # of release.json itself
RELEASE_SPLITS = (*ALL_SPLITS, "test_calm")
CONTROL_RATE = round(1 / CONTROL_PERIOD)  # Hz: 500
# Short and safe as a directory name, a file name and a URL path segment: no leading dot (a
# hidden file, or ".."), no separators, no spaces.
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
Format = Literal["gainfarm", "lerobot"]
FORMATS: tuple[Format, ...] = ("gainfarm", "lerobot")
# The learn extra's modules the baselines import: scikit-learn's networks, Pinocchio's regressor.
LEARN_MODULES = {"sklearn": "scikit-learn", "pinocchio": "Pinocchio"}
STATS_COLUMNS_AT_ONCE = 16  # ticks.parquet is read this many columns at a time for the stats
HASH_BLOCK = 1 << 20


class BadRelease(ValueError):
    """A release that cannot be made as asked; the message is one line for the user."""


class MissingExtra(BadRelease):
    """The learn extra, which the baselines need, is not installed."""


def check_name(name: str) -> str:
    if not NAME_PATTERN.fullmatch(name):
        raise BadRelease(
            f"{name!r} is not a release name: 1 to 64 letters, digits, '-', '_' or '.', "
            "starting with a letter or digit"
        )
    return name


def check_learn_extra() -> None:
    """The baselines fit Pinocchio's regressor and scikit-learn's networks: say so before
    anything is built, not after minutes of it."""
    missing = [name for module, name in LEARN_MODULES.items() if not _installed(module)]
    if missing:
        raise MissingExtra(
            f"a release's baselines need {' and '.join(missing)}: pip install 'gainfarm[learn]'"
        )


def _installed(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        while block := stream.read(HASH_BLOCK):
            digest.update(block)
    return digest.hexdigest()


def data_files(directory: Path) -> list[str]:
    """The data files' paths relative to `directory`, sorted: the Parquet tables at its top and
    the MCAP logs in episodes/."""
    tables = [path.name for path in Path(directory).glob("*.parquet")]
    logs = [f"episodes/{path.name}" for path in (Path(directory) / "episodes").glob("*.mcap")]
    return sorted(tables + logs)


def file_hashes(directory: Path, paths: Sequence[str]) -> list[dict[str, Any]]:
    return [
        {
            "path": path,
            "sha256": sha256_of(Path(directory) / path),
            "bytes": (Path(directory) / path).stat().st_size,
        }
        for path in sorted(paths)
    ]


def content_hash(files: Sequence[dict[str, Any]]) -> str:
    """SHA-256 of `sha256sum`'s lines ("<hash>  <path>\\n") for `files`, sorted by path."""
    lines = "".join(
        f"{entry['sha256']}  {entry['path']}\n" for entry in sorted(files, key=lambda e: e["path"])
    )
    return hashlib.sha256(lines.encode()).hexdigest()


def verify(directory: Path) -> list[str]:
    """What differs between a release's data files and its release.json: changed, missing or
    extra files; empty if it verifies (and the content hash is recomputed, not trusted)."""
    record = json.loads((Path(directory) / RELEASE_JSON).read_text(encoding="utf-8"))
    listed = {entry["path"]: entry["sha256"] for entry in record["files"]}
    present = set(data_files(directory))
    problems = [f"missing: {path}" for path in sorted(set(listed) - present)]
    problems += [f"not in the release: {path}" for path in sorted(present - set(listed))]
    found = file_hashes(directory, sorted(present & set(listed)))
    problems += [f"changed: {e['path']}" for e in found if e["sha256"] != listed[e["path"]]]
    if not problems and content_hash(found) != record["content_hash"]:
        problems.append("the content hash does not match its files' hashes")
    return problems


def split_members(directory: Path) -> dict[str, dict[str, Any]]:
    """Each fixed split's episodes and trajectories with their ticks, from episodes.parquet:
    train, validation, test, their *_variants if the dataset has episodes on other plants, and
    test_calm (the test episodes that are calm)."""
    names = pq.read_schema(Path(directory) / EPISODES).names
    columns = ["episode_id", "trajectory_id", "ticks", "split"] + ["calm"] * ("calm" in names)
    rows = pq.read_table(Path(directory) / EPISODES, columns=columns).to_pylist()
    members = {
        split: [row for row in rows if row["split"] == split]
        for split in ALL_SPLITS
        if not split.endswith(VARIANTS) or any(row["split"] == split for row in rows)
    }
    members["test_calm"] = [row for row in rows if row["split"] == "test" and row.get("calm", True)]
    result = {}
    for split, chosen in members.items():
        per_trajectory: Counter[str] = Counter()
        episodes_of: Counter[str] = Counter()
        for row in chosen:
            per_trajectory[row["trajectory_id"]] += int(row["ticks"])
            episodes_of[row["trajectory_id"]] += 1
        result[split] = {
            "ticks": sum(int(row["ticks"]) for row in chosen),
            "episodes": [
                {
                    "episode_id": row["episode_id"],
                    "trajectory_id": row["trajectory_id"],
                    "ticks": int(row["ticks"]),
                }
                for row in sorted(chosen, key=lambda row: row["episode_id"])
            ],
            "trajectories": [
                {"trajectory_id": tid, "episodes": episodes_of[tid], "ticks": ticks}
                for tid, ticks in sorted(per_trajectory.items())
            ],
        }
    return result


def release_plants(directory: Path) -> list[dict[str, Any]]:
    """The distinct plants of the episodes (`learning.plants`): the runs' own ("nominal", in
    train, validation and test) first, then the variants (in the *_variants splits), each with
    its number of episodes there."""
    table = pq.read_table(Path(directory) / EPISODES, columns=["model", "split"])
    pairs = zip(table["split"].to_pylist(), table["model"].to_pylist(), strict=True)
    episodes = [(s.endswith(VARIANTS), PlantSpec.model_validate_json(text)) for s, text in pairs]
    return [
        {
            "role": "variant" if variant else "nominal",
            "name": plant_name(plant),
            "episodes": episodes.count((variant, plant)),
            "model": plant.model_dump(mode="json"),
        }
        for variant in (False, True)
        for plant in learning.plants(directory, variants=variant)
    ]


def train_stats(directory: Path) -> dict[str, dict[str, Any]]:
    """Per numeric column of ticks.parquet, over the train split's rows only: mean, std (the
    population's, ddof 0), min, max and count of its finite values (NaN-aware: qdd's last
    ticks are NaN), and its unit. A statistic of no values is null (JSON has no NaN)."""
    path = Path(directory) / TICKS
    schema = pq.read_schema(path)
    numeric = [
        field
        for field in schema
        if pa.types.is_floating(field.type) or pa.types.is_integer(field.type)
    ]
    stats = {}
    for start in range(0, len(numeric), STATS_COLUMNS_AT_ONCE):
        group = numeric[start : start + STATS_COLUMNS_AT_ONCE]
        table = pq.read_table(
            path, columns=[field.name for field in group], filters=[("split", "==", "train")]
        )
        for field in group:
            values = table[field.name].to_numpy(zero_copy_only=False).astype(float)
            finite = values[np.isfinite(values)]
            count = int(finite.size)
            unit = (field.metadata or {}).get(b"unit", b"").decode()
            stats[field.name] = {
                "mean": float(finite.mean()) if count else None,
                "std": float(finite.std()) if count else None,
                "min": float(finite.min()) if count else None,
                "max": float(finite.max()) if count else None,
                "count": count,
                "unit": unit,
            }
    return stats


def write_json(path: Path, value: Any) -> None:
    write_atomically(path, (json.dumps(value, indent=2, allow_nan=False) + "\n").encode())


def write_release(
    staging: Path,
    name: str,
    kinds: Sequence[str] | None = None,
    seed: int = 0,
    format: Format = "gainfarm",
    layout: LerobotLayout = DEFAULT_LAYOUT,
) -> dict[str, Any]:
    """Make the built dataset at `staging` a release: write release.json, stats.json,
    baselines.json, the card's release sections and, with format lerobot, lerobot/. Returns
    release.json's content. Raises learning.LearnError if the baselines cannot be fitted (no
    test split), one line."""
    staging = Path(staging)
    check_name(name)
    # Hashed first: the data files are final once the dataset is built.
    files = file_hashes(staging, data_files(staging))
    stats = train_stats(staging)
    write_json(staging / STATS_JSON, stats)
    chosen = tuple(kinds) if kinds is not None else learning.BENCHMARK
    table = baselines.benchmark(staging, seed=seed, kinds=chosen)
    write_json(staging / BASELINES_JSON, _json_safe(table))
    splits = split_members(staging)
    plants = release_plants(staging)
    robot, joints = dataset_arm(staging)
    exported: list[dict[str, Any]] = []
    if format == "lerobot":
        written = lerobot.export(staging, staging / LEROBOT_DIR, layout)
        exported = file_hashes(staging, [f"{LEROBOT_DIR}/{path}" for path in written])
    record = {
        "name": name,
        "release_format": RELEASE_FORMAT,
        "dataset_version": DATASET_VERSION,
        "robot": robot,
        "robot_type": robot_type(robot),
        "joint_names": list(joints),
        "control_rate_hz": CONTROL_RATE,
        "control_period_s": CONTROL_PERIOD,
        "content_hash": content_hash(files),
        "content_hash_of": "SHA-256 of the lines `sha256sum` prints for `files`, sorted by path",
        "files": files,
        "splits": splits,
        "plants": plants,
        "normalisation": {"file": STATS_JSON, "over": "train"},
        "baselines": {
            "file": BASELINES_JSON,
            "seed": seed,
            "kinds": list(chosen),
            "fit_seconds": round(sum(entry["fit_seconds"] for entry in table.values()), 1),
        },
        "formats": ["gainfarm", *(["lerobot"] if format == "lerobot" else [])],
        "exports": exported,
    }
    write_json(staging / RELEASE_JSON, record)
    card = (staging / CARD).read_text(encoding="utf-8")
    text = (
        card.rstrip("\n")
        + "\n\n"
        + release_card(record)
        + "\n"
        + baselines_card(table, robot, joints)
    )
    write_atomically(staging / CARD, text.encode())
    return record


def _json_safe(value: Any) -> Any:
    """NaN and infinity as null: JSON has neither (a joint whose test torque never varies)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(item) for item in value]
    return value


def plant_description(plant: PlantSpec) -> str:
    """What a plant simulates, in the card's words, from its PlantSpec."""
    sensors = plant.sensors
    parts = [
        "elastic joints (a spring between each motor and its link)"
        if plant.joints == "flexible"
        else "rigid joints",
        "motor-side friction (viscous and Coulomb-like)" if plant.friction else "no friction",
        "exact sensors"
        if sensors.exact
        else f"sensor noise ({sensors.noise:.2g} rad on the angles, quantised to "
        f"{sensors.resolution:.2g} rad; {sensors.torque_noise:g} N·m on the torque sensors)",
        f"a command delay of {plant.delay} tick{'s' * (plant.delay != 1)}",
        f"{plant.feedback}-side feedback",
        f"{plant.inertials} inertials",
    ]
    if plant.load is not None:
        parts.append(f"a {plant.load.mass:g} kg load the robot is told of")
    if plant.payload:
        parts.append(f"a {plant.payload:g} kg payload")
    if any(scale != 1 for scale in plant.mass_scale):
        parts.append("link masses scaled (" + ", ".join(f"{s:g}" for s in plant.mass_scale) + ")")
    return ", ".join(parts) + "; " + interface_text(plant)


def release_card(record: dict[str, Any]) -> str:
    """The card's section on the release: its identity, the robot, the plants, the splits."""
    arm = title(record.get("robot", ROBOT_BEFORE))  # a release from before names no robot
    plants = "\n".join(
        f"- {plant['role']} ({plant['name']} plant, {plant['episodes']} episodes): "
        + plant_description(PlantSpec.model_validate(plant["model"]))
        for plant in record["plants"]
    )
    splits = "\n".join(
        f"| {split} | {len(part['episodes'])} | {len(part['trajectories'])} | {part['ticks']:,} |"
        for split, part in record["splits"].items()
    )
    lerobot = (
        f"\n- `{LEROBOT_DIR}/`: the same ticks in LeRobot's v3.0 dataset layout (`meta/info.json`, "
        "`data/chunk-*/file-*.parquet`), episodes ordered by split."
        if "lerobot" in record["formats"]
        else ""
    )
    return f"""## Release `{record["name"]}`

A frozen release: dataset version {record["dataset_version"]}, content hash
`{record["content_hash"]}`: the SHA-256 of the lines `sha256sum` prints for its
{len(record["files"])} data files (the Parquet tables and the MCAP logs) sorted by path, which

    sha256sum *.parquet episodes/*.mcap | LC_ALL=C sort -k2 | sha256sum

recomputes in this directory; `release.json` lists every file's SHA-256.

Robot type `{record["robot_type"]}`, a simulated {arm} in MuJoCo, controlled at
{record["control_rate_hz"]} Hz (period {record["control_period_s"]} s).

The plants (`model` in `episodes.parquet`; the nominal ones are the runs' own, in train,
validation and test; the variants' episodes are in the `*_variants` splits):

{plants}

The fixed splits (by trajectory; `test_calm` is the test episodes whose `calm` is true),
listed by episode and trajectory in `release.json`:

| split | episodes | trajectories | ticks |
|---|---|---|---|
{splits}

- `release.json`: the name, versions, content hash, files, splits, control rate, robot, plants.
- `stats.json`: per numeric column of `ticks.parquet`, its mean, std, min, max and count over
  the train split only (NaN left out), so that normalising leaks nothing of validation or test.
- `baselines.json`: the baselines below, every score.{lerobot}
"""


def baselines_card(
    table: dict[str, dict[str, Any]],
    robot: str = ROBOT_BEFORE,
    joints: Sequence[str] = JOINTS_BEFORE,
) -> str:
    """The card's table of every baseline on the frozen test split, all and calm episodes, of
    `robot`'s dataset (its `joints`)."""
    averaged, first = span(mean_joints(joints)), span(joints[:PUBLISHED_JOINTS])
    labels = {
        "plant": "plant's own dynamics (the floor)",
        "rigid": "rigid prior (untrained)",
    }
    lines = [
        "## Baselines",
        "",
        "Inverse dynamics (q, q̇, `qdd_sg` → `u_motor`), each model fitted on the train split and "
        f"scored on the frozen test split: nMSE is the mean over {averaged} of the MSE over the "
        f"measured torque's variance; RMSE is the mean over {first}, in N·m; calm: the test "
        "episodes whose `calm` is true. No learned model can beat the plant's own dynamics but "
        "by chance: only the sensors' noise separates it from the data.",
        "",
    ]
    variants = any("variants" in scores for scores in table.values())
    header = f"| model | nMSE all | nMSE calm | RMSE {first} all (N·m) | RMSE {first} calm (N·m) |"
    header += " nMSE test_variants |" * variants
    lines += [f"{header} fit (s) |", "|---|---|---|---|---|" + "---|" * variants + "---|"]
    for kind, scores in table.items():
        calm = scores.get("calm") or {}
        shift = f" {_shown((scores.get('variants') or {}).get('nmse_mean'), '.3g')} |" * variants
        lines.append(
            f"| {labels.get(kind, kind)} | {_shown(scores['nmse_mean'], '.3g')} | "
            f"{_shown(calm.get('nmse_mean'), '.3g')} | {_shown(scores['rmse_a1_a4'], '.3g')} | "
            f"{_shown(calm.get('rmse_a1_a4'), '.3g')} |{shift} {scores['fit_seconds']:.2f} |"
        )
    if variants:
        lines += [
            "",
            "nMSE test_variants: the same models, fitted on the runs' own plants, on the test "
            "trajectories' episodes on the other plants; the floor there is each episode's own "
            "plant, what a model that is not told the plant cannot reach.",
        ]
    learned = {kind: s for kind, s in table.items() if kind not in labels}
    best = min(learned.items(), key=lambda item: item[1]["rmse_a1_a4"], default=None)
    floor = table.get("plant")
    said = []
    if best is not None:
        said.append(f"the best learned model's here ({best[0]}) is {best[1]['rmse_a1_a4']:.3g} N·m")
    if floor is not None:
        said.append(f"the floor's {floor['rmse_a1_a4']:.3g} N·m")
    placed = f"RMSE over {first}: " + " and ".join(said) + ". Set them"
    placed = placed if said else "Set these RMSEs"
    lines.append("")
    if best is not None and floor is not None and floor["nmse_mean"] > 0:
        ratio = best[1]["nmse_mean"] / floor["nmse_mean"]
        lines += [
            f"The best learned model's test nMSE is {ratio:.2g} times the floor's "
            f"({best[1]['nmse_mean']:.3g} against {floor['nmse_mean']:.3g}).",
            "",
        ]
    if robot == PUBLISHED_ROBOT:  # the one published figure is of the iiwa 14
        lines += [
            f"{placed[0].upper()}{placed[1:]} beside the {PUBLISHED_RMSE} N·m published for a "
            "model learned on a real iiwa 14 (Çallar and Böttger, RA-L 2022): this is a "
            "simulated plant with its noise, not that robot.",
            "",
        ]
    elif said:
        lines += [f"{placed.removesuffix('. Set them')}.", ""]
    return "\n".join(lines)


def _shown(value: float | None, spec: str) -> str:
    return "–" if value is None or not math.isfinite(value) else format(value, spec)


def build_release(
    run_dirs: Sequence[Path],
    out: Path,
    name: str,
    *,
    kinds: Sequence[str] | None = None,
    seed: int = 0,
    format: Format = "gainfarm",
    layout: LerobotLayout = DEFAULT_LAYOUT,
    **build_options: Any,
) -> tuple[dict[str, int], dict[str, Any]]:
    """`dataset.build` with its staged directory made a release (`write_release`) before it is
    renamed to `out`: the dataset and its release appear together or not at all. Refuses a bad
    name, an unknown format, a split without test trajectories and a missing learn extra before
    anything is written. Returns the dataset's counts and release.json's content."""
    check_name(name)
    if format not in FORMATS:
        raise BadRelease(f"unknown format {format!r}: one of {', '.join(FORMATS)}")
    if "split" in build_options and check_split(build_options["split"])[2] <= 0:
        raise BadRelease("a release is scored on its test split: give it a positive fraction")
    check_learn_extra()
    record: dict[str, Any] = {}

    def finish(staging: Path, counts: dict[str, int]) -> None:
        record.update(write_release(staging, name, kinds, seed, format, layout))

    counts = build(run_dirs, out, finish=finish, **build_options)
    return counts, record
