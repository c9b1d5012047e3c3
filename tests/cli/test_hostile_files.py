"""Hostile files handed to the commands: each is refused in one line naming its option (or the
file, for an argument), with a non-zero exit, no traceback and nothing written.

The real console scripts run as subprocesses, several at a time. The bombs (billion laughs, an
MCAP chunk that inflates to 4 GiB) run under an address-space limit, so that a regression fails
here rather than eats the machine. No timing is asserted.
"""

import itertools
import json
import resource
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest
import tomli_w

from gainfarm.models import resolve
from gainfarm.models.dynamics import MAX_FILE_BYTES as MAX_MODEL_BYTES
from gainfarm.schemas.documents import MAX_DEPTH, MAX_TEXT_BYTES
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.plant_file import PlantFile
from gainfarm.schemas.robot import PlantSpec
from tests.schemas.test_hostile_decoding import BOMB_BYTES, written, zstd_bomb

BIN = Path(sys.executable).parent
MEMORY = 3 << 29  # 1.5 GiB of address space for a bomb's process: MuJoCo and numpy fit in it
# Nothing listens here: a command that got as far as its farm would fail on it, not hang.
NO_FARM = ("--connect", "tcp/127.0.0.1:9")
KP = ("--kp", "100,100,100,100,50,50,20", "--kd", "10,10,10,10,5,5,2")
DEEP = MAX_DEPTH * 1000


def laughs() -> str:
    """YAML's billion laughs: 9 aliases of 9 aliases ... nine levels down, 9^9 "lol"s."""
    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    names = "abcdefghi"
    for before, name in itertools.pairwise(names):
        lines.append(f"{name}: &{name} [{', '.join(['*' + before] * 9)}]")
    return "\n".join([*lines, "kp: *i", "kd: *i", ""])


def plant_toml(**plant: object) -> str:
    """A plant file of the default plant, with `plant`'s fields replaced (any value at all)."""
    table = json.loads(PlantFile(plant=PlantSpec()).model_dump_json(exclude_none=True))
    table["plant"].update(plant)
    return tomli_w.dumps(table)


def stiff_plant() -> str:
    # tomli_w writes 1e308 as it is: the file a person would write.
    return plant_toml(stiffness=[1e308, *resolve(PlantSpec()).stiffness[1:]])


@dataclass(frozen=True)
class Case:
    name: str
    command: tuple[str, ...]  # FILE stands for the hostile file, OUT for where to write
    content: str | bytes | int | None  # int: a sparse file of that size; None: the bomb
    said: str  # in the error line, after the option
    bomb: bool = False
    suffix: str = ""


RANGE = """[x]
field = "stiffness"
per_joint = true
draw = "uniform"
low = 1
high = 1e308
why = "a range so wide its variants overflow"
"""
CASES = [
    # worker episode --gains: JSON or YAML
    Case("deep-json", ("worker", "episode", "--gains", "FILE", "--out", "OUT"),
         "[" * DEEP + "]" * DEEP, f"--gains: 'FILE': nesting deeper than {MAX_DEPTH} levels"),
    Case("deep-yaml", ("worker", "episode", "--gains", "FILE", "--out", "OUT"),
         "kp:\n" + "[" * DEEP + "]" * DEEP + "\n",
         f"--gains: 'FILE': nesting deeper than {MAX_DEPTH} levels", suffix=".yaml"),
    Case("digits", ("worker", "episode", "--gains", "FILE", "--out", "OUT"),
         '{"kp": [%s, 1, 1, 1, 1, 1, 1], "kd": [1, 1, 1, 1, 1, 1, 1]}' % ("9" * 5000),
         "--gains: 'FILE': an integer of more than 4300 digits"),
    Case("laughs", ("worker", "episode", "--gains", "FILE", "--out", "OUT"), laughs(),
         "--gains: 'FILE': an alias at line 2", bomb=True, suffix=".yaml"),
    Case("oversized", ("worker", "episode", "--gains", "FILE", "--out", "OUT"),
         " " * (MAX_TEXT_BYTES + 1) + "{}",
         f"--gains: 'FILE': {MAX_TEXT_BYTES + 3} bytes, more than the {MAX_TEXT_BYTES}"),
    Case("laughs-batch", ("analytic", "batch", "--gains", "FILE", *NO_FARM, "--run-dir", "OUT"),
         laughs(), "--gains: 'FILE': an alias at line 2", bomb=True, suffix=".yaml"),
    Case("deep-batch", ("analytic", "batch", "--gains", "FILE", *NO_FARM, "--run-dir", "OUT"),
         "[" * DEEP + "]" * DEEP, f"--gains: 'FILE': nesting deeper than {MAX_DEPTH} levels"),
    Case("oversized-model",
         ("worker", "episode", *KP, "--feedforward", "FILE", "--out", "OUT"),
         MAX_MODEL_BYTES + 1,
         f"--feedforward: 'FILE': {MAX_MODEL_BYTES + 1} bytes, more than the {MAX_MODEL_BYTES}",
         suffix=".npz"),
    # --plant FILE: TOML
    Case("stiffness", ("worker", "episode", "--plant", "FILE", *KP, "--out", "OUT"),
         stiff_plant(), "--plant: 'FILE': plant.stiffness.0: must be at most 10000000, got 1e+308",
         suffix=".toml"),
    Case("deep-plant", ("worker", "episode", "--plant", "FILE", *KP, "--out", "OUT"),
         "a = " + "[" * DEEP + "]" * DEEP + "\n",
         f"--plant: 'FILE': nesting deeper than {MAX_DEPTH} levels", suffix=".toml"),
    Case("dotted-plant", ("worker", "episode", "--plant", "FILE", *KP, "--out", "OUT"),
         ".".join(["a"] * DEEP) + " = 1\n",
         f"--plant: 'FILE': nesting deeper than {MAX_DEPTH} levels", suffix=".toml"),
    Case("stiffness-start", ("analytic", "start", "--plant", "FILE", *NO_FARM, "--out", "OUT"),
         stiff_plant(), "--plant: 'FILE': plant.stiffness.0: must be at most", suffix=".toml"),
    # analytic start --limits (JSON), --uncertainty (TOML)
    Case("deep-limits", ("analytic", "start", "--limits", "FILE", *NO_FARM, "--out", "OUT"),
         '{"chatter": ' + "[" * DEEP + "]" * DEEP + "}",
         f"--limits: 'FILE': nesting deeper than {MAX_DEPTH} levels"),
    Case("digits-limits", ("analytic", "start", "--limits", "FILE", *NO_FARM, "--out", "OUT"),
         '{"torque_step": %s}' % ("9" * 5000),
         "--limits: 'FILE': an integer of more than 4300 digits"),
    Case("deep-uncertainty",
         ("analytic", "start", "--uncertainty", "FILE", *NO_FARM, "--out", "OUT"),
         "a = " + "[" * DEEP + "]" * DEEP + "\n",
         f"--uncertainty: 'FILE': nesting deeper than {MAX_DEPTH} levels", suffix=".toml"),
    Case("digits-uncertainty",
         ("analytic", "start", "--uncertainty", "FILE", *NO_FARM, "--out", "OUT"),
         "[x]\nlow = %s\n" % ("9" * 5000),
         "--uncertainty: 'FILE': an integer of more than 4300 digits", suffix=".toml"),
    Case("huge-range",
         ("analytic", "start", "--uncertainty", "FILE", "--plants", "4", *NO_FARM, "--out", "OUT"),
         RANGE, "--uncertainty: 'FILE': a variant is no plant (stiffness.0: must be",
         suffix=".toml"),
    Case("stiff-range",
         ("analytic", "start", "--uncertainty", "FILE", "--plants", "4", *NO_FARM, "--out", "OUT"),
         RANGE.replace("1e308", "3000").replace("low = 1", "low = 2500"),
         "--uncertainty: 'FILE': a variant is no plant (stiffness.0: must be at most 10000000",
         suffix=".toml"),
    Case("digits-excite", ("analytic", "excite", "--uncertainty", "FILE", "--out", "OUT"),
         "[x]\nlow = %s\n" % ("9" * 5000),
         "--uncertainty: 'FILE': an integer of more than 4300 digits", suffix=".toml"),
    # MCAP logs: a bomb handed to calibrate and validate, an oversized log to evaluate
    Case("bomb-calibrate", ("analytic", "calibrate", "FILE", "--out", "OUT"), None,
         "'FILE': a chunk claims 4294967296 bytes uncompressed", bomb=True, suffix=".mcap"),
    Case("deep-played",
         ("analytic", "validate", "TWIN", "FILE", "--played", "FILE", "--out", "OUT"),
         "[" * DEEP + "]" * DEEP, f"--played: 'FILE': nesting deeper than {MAX_DEPTH} levels"),
    Case("bomb-validate", ("analytic", "validate", "TWIN", "FILE", "--out", "OUT"), None,
         "'FILE': a chunk claims 4294967296 bytes uncompressed", bomb=True, suffix=".mcap"),
]  # fmt: skip


@pytest.fixture(scope="module")
def bomb(tracking_log: EpisodeLog) -> bytes:
    """An episode log whose one chunk of messages is a 131 kB zstd frame inflating to 4 GiB."""
    return written(
        tracking_log, lambda records: zstd_bomb(BOMB_BYTES, True), uncompressed_size=BOMB_BYTES
    )


def limited() -> None:  # in the child, before exec: a bomb fails rather than eats the machine
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))


def run(case: Case, where: Path, bomb: bytes) -> tuple[subprocess.CompletedProcess, Path, Path]:
    where.mkdir()
    file = where / f"hostile{case.suffix or '.json'}"
    content = bomb if case.content is None else case.content
    if isinstance(content, int):
        with file.open("wb") as stream:
            stream.truncate(content)
    else:
        file.write_bytes(content if isinstance(content, bytes) else content.encode())
    (where / "twin.toml").write_text(plant_toml())
    out = where / "out"
    words = {"FILE": str(file), "OUT": str(out), "TWIN": str(where / "twin.toml")}
    program, *arguments = case.command
    command = [str(BIN / program), *(words.get(word, word) for word in arguments)]
    done = subprocess.run(
        command,
        capture_output=True,
        text=True,
        cwd=where,
        preexec_fn=limited if case.bomb else None,
        timeout=600,
    )
    return done, file, out


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory, bomb: bytes) -> dict:
    """Every case run once, two at a time (the processes' imports are most of their time)."""
    root = tmp_path_factory.mktemp("hostile")
    with ThreadPoolExecutor(2) as pool:
        futures = {case.name: pool.submit(run, case, root / case.name, bomb) for case in CASES}
        return {name: future.result() for name, future in futures.items()}


@pytest.mark.parametrize("case", CASES, ids=[case.name for case in CASES])
def test_a_hostile_file_is_refused_in_one_line(case: Case, outcomes: dict) -> None:
    done, file, out = outcomes[case.name]
    program = case.command[0]
    assert done.returncode != 0
    assert "Traceback" not in done.stderr
    assert done.stderr.count("\n") == 1, done.stderr[:2000]
    expected = case.said.replace("FILE", str(file))
    assert done.stderr.startswith(f"{program}: error: "), done.stderr
    assert expected in done.stderr, done.stderr
    assert len(done.stderr) < 400  # the input is never echoed whole
    assert not out.exists()
    assert sorted(path.name for path in file.parent.iterdir()) == sorted([file.name, "twin.toml"])


def test_an_oversized_log_is_refused_before_it_is_read(tmp_path: Path) -> None:
    """A log larger than any episode (a sparse file: no disk is used) is refused by its size."""
    from gainfarm.schemas.wire import MAX_EPISODE_BYTES

    log = tmp_path / "huge.mcap"
    with log.open("wb") as stream:
        stream.truncate(MAX_EPISODE_BYTES + 1)
    done = subprocess.run(
        [str(BIN / "analytic"), "evaluate", str(log)],
        capture_output=True,
        text=True,
        preexec_fn=limited,
        timeout=600,
    )
    assert done.returncode != 0 and done.stderr.count("\n") == 1, done.stderr
    assert f"{MAX_EPISODE_BYTES + 1} bytes, more than the {MAX_EPISODE_BYTES}" in done.stderr


# --- a dataset's logs: only from inside its runs ------------------------------------------------

# A finished run in seconds (as tests/analytic/view/test_dashboard.py's).
QUICK = (
    "--trajectory", "fourier", "--duration", "0.5", "--pop", "4", "--generations", "1",
    "--seed", "3", "--local", "--workers", "1",
)  # fmt: skip


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = tmp_path_factory.mktemp("quick") / "run"
    done = subprocess.run(
        [str(BIN / "analytic"), "start", *QUICK, "--out", str(run)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    return run


def with_log(run: Path, copy: Path, log: str) -> Path:
    """A copy of `run` whose first member names `log` as its first episode log."""
    shutil.copytree(run, copy, symlinks=True)
    front = json.loads((copy / "front.json").read_bytes())
    front["members"][0]["logs"] = [log, *front["members"][0]["logs"][1:]]
    (copy / "front.json").write_text(json.dumps(front))
    return copy


@pytest.mark.slow
@pytest.mark.parametrize("how", ["parent", "absolute", "symlink"])
def test_a_dataset_takes_no_log_from_outside_its_runs(
    quick_run: Path, tmp_path: Path, how: str
) -> None:
    secret = tmp_path / "secret.mcap"
    secret.write_bytes(b"not the run's")
    named = {"parent": "../secret.mcap", "absolute": str(secret), "symlink": "episodes/out.mcap"}
    run = with_log(quick_run, tmp_path / "run", named[how])
    if how == "symlink":
        (run / "episodes").mkdir(exist_ok=True)
        (run / "episodes" / "out.mcap").symlink_to(secret)
    out = tmp_path / "dataset"
    done = subprocess.run(
        [str(BIN / "analytic"), "dataset", str(run), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert done.stderr.count("\n") == 1, done.stderr
    assert "lies outside the run: refused" in done.stderr
    assert not out.exists()
    assert secret.stat().st_nlink == 1  # never hard-linked into a dataset
