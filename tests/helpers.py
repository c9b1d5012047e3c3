"""Constants and helpers the tests share."""

import dataclasses
import hashlib
import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh

from gainfarm.broker.queue import LeaseQueue
from gainfarm.broker.service import Broker
from gainfarm.edges.ask import ask
from gainfarm.edges.parts import reply_part
from gainfarm.models.urdf import description
from gainfarm.schemas import EpisodeMetadata, EpisodeSpec, PDGains, TrajectorySpec, keys
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.mcap_episode import episode_bytes
from gainfarm.schemas.robot import TORQUE_LIMITS, Friction, PlantSpec, Sensors
from gainfarm.schemas.wire import (
    Job,
    JobStatus,
    Lease,
    LeaseReply,
    LeaseRequest,
    Result,
    Submission,
    SubmitReply,
    Timings,
    Verdict,
    WireScores,
    decode,
)

# Set by .ci/run, which installs the Debian packages some tests need: there a missing one fails
# the test; on a machine without them it is skipped, saying which (pytest -rs lists them).
SYSTEM_TESTS = "GAINFARM_SYSTEM_TESTS"


def needs(present: bool, what: str) -> None:
    """Skip the test, saying `what` it needs, unless it is `present`; fail instead where the
    system's packages are required (SYSTEM_TESTS=required: CI)."""
    if present:
        return
    if os.environ.get(SYSTEM_TESTS) == "required":
        pytest.fail(f"{what}; {SYSTEM_TESTS}=required (.ci/run installs them)")
    pytest.skip(what)


TRACKING_GAINS = PDGains(kp=(2000, 2000, 1200, 1200, 400, 200, 100), kd=(60, 60, 40, 40, 10, 5, 2))
SOFT_GAINS = PDGains(kp=(200, 200, 120, 120, 40, 20, 10), kd=(20, 20, 12, 12, 4, 2, 1))
WEAK_GAINS = PDGains(kp=(5,) * 7, kd=(1,) * 7)  # too soft to hold the arm up without FRI


def maximal_job(number: int = 0) -> Job:
    """The largest Job's JSON there is: every name and list at its longest, every choice its
    longest spelling, every number as long as its bounds let it be (a float's repr is 24
    characters at most, 23 if it may not be negative; tests/schemas/test_wire.py checks that no
    field is left unbounded)."""
    tiny, seven = 2.2250738585072014e-308, (2.2250738585072014e-308,) * 7
    spec = EpisodeSpec(
        gains=PDGains(kp=seven, kd=seven),
        trajectory=TrajectorySpec(
            kind="k" * 32,
            duration=0.10000000000000002,  # the longest of 0.1 to 120
            seed=2**63 - 1,
            center=(-tiny,) * 3,
            size=tiny,
            turns=tiny,
            waypoints=50,
            twist=tiny,
            harmonics=10,
        ),
        plant=PlantSpec(
            inertials="open",
            stiffness=seven,
            spring_damping=seven,
            rotor_inertia=seven,
            friction=Friction(viscous=seven, coulomb=seven, smoothing=tiny),
            delay=50,
            sensors=Sensors(
                resolution=tiny,
                noise=tiny,
                velocity_window=50,
                torque_noise=tiny,
                seed=2**63 - 1,
            ),
            substeps=50,
        ),
        feedforward="f" * 64,
        objectives=("o" * 32, "p" * 32),
    )
    return Job(job_id=f"{number:064d}", spec=spec, avoid=[f"w{n:063d}" for n in range(64)])


# --- the farm: real Zenoh sessions on loopback ----------------------------------------------


def wait_for(condition: Callable[[], object], timeout: float = 10.0, what: str = "it") -> None:
    """Poll until `condition()` is true; fail the test (not hang it) if it never is."""
    give_up = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > give_up:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


def short_spec(duration: float = 0.5, gains: PDGains = TRACKING_GAINS, **trajectory) -> EpisodeSpec:
    """A short episode; a fourier excitation unless `kind` says otherwise, because it fits the
    iiwa's limits at any duration (a Cartesian path needs some 3 s)."""
    trajectory.setdefault("kind", "fourier")
    return EpisodeSpec(gains=gains, trajectory=TrajectorySpec(duration=duration, **trajectory))


def query(session: zenoh.Session, key: str, payload: bytes | None = None) -> tuple[bool, bytes]:
    """(ok, payload) of the broker's reply to a query; fails the test if it does not answer."""
    answer = ask(session, key, payload, timeout=5.0)
    if answer is None:
        raise AssertionError(f"no reply on {key}")
    if answer.payload is not None:
        return True, answer.payload
    return False, (answer.error or "").encode()


def open_study(session: zenoh.Session, broker: Broker, study: str) -> zenoh.LivelinessToken:
    """Hold `study`'s liveliness token, as an analytic process does, until the broker knows it.

    Keep the token: Zenoh undeclares it when it is garbage-collected."""
    token = session.liveliness().declare_token(keys.alive_study(study))
    wait_for(lambda: study in open_studies(broker.queue), what=f"the broker to open {study}")
    return token


def open_studies(queue: LeaseQueue) -> set[str]:
    """The names of the studies a broker's queue has open."""
    return {state.name for state in queue.study_states()}


def submit(session: zenoh.Session, study: str, specs: dict[str, EpisodeSpec]) -> SubmitReply:
    jobs = [Job(job_id=job_id, spec=spec) for job_id, spec in specs.items()]
    ok, payload = query(session, keys.submit(study), Submission(study=study, jobs=jobs).to_bytes())
    assert ok, payload
    return decode(SubmitReply, payload)


def serve_log(
    session: zenoh.Session, study: str, worker: str, content: bytes, digest: str | None = None
) -> object:
    """Serve `content` on `session` as `worker`'s kept log of `study` (under its SHA-256, or
    `digest`), in parts, as a worker does; the queryable (undeclared when dropped or when the
    session closes)."""
    key = keys.log(study, worker, digest or hashlib.sha256(content).hexdigest())
    return session.declare_queryable(key, lambda query: reply_part(query, content))


def result_for(study: str, job_id: str, worker: str = "w", **fields: object) -> Result:
    """A Result as a worker would send it, made by hand; `fields` override the defaults."""
    defaults: dict[str, object] = {
        "lease_id": "by-hand",
        "status": JobStatus.ok,
        "episode_bytes": 0,
        "digest": hashlib.sha256(b"").hexdigest(),
        "timings": Timings(simulate_s=0.0, encode_s=0.0),
    }
    merged = {**defaults, **fields}
    if "scores" not in fields and merged["status"] != JobStatus.failed:
        merged["scores"] = HAND_MADE_SCORES  # a job that ran has scores (the wire's rule)
    return Result(study=study, job_id=job_id, worker=worker, **merged)


HAND_MADE_SCORES = WireScores(
    f_acc=0.01,
    f_t=0.1,
    max_error=0.02,
    saturated_fraction=0.0,
    diverged=False,
    ticks=1,
    torque_step=0.01,
    speed=0.5,
    chatter=0.001,
    lag=0.006,
    damping=0.05,
)


def ask_for_work(session: zenoh.Session, worker: str) -> Lease | None:
    """One lease, or None if the broker has no work for a while."""
    ok, payload = query(session, keys.lease(worker), LeaseRequest(worker=worker).to_bytes())
    assert ok, payload
    leases = decode(LeaseReply, payload).leases
    assert len(leases) <= 1, leases
    return leases[0] if leases else None


def hand_in(session: zenoh.Session, result: Result) -> Verdict:
    """Hand a result in to the broker, asking for no more work, as a stopping worker does."""
    request = LeaseRequest(worker=result.worker, want=0, results=[result])
    ok, payload = query(session, keys.lease(result.worker), request.to_bytes())
    assert ok, payload
    (verdict,) = decode(LeaseReply, payload).verdicts
    return verdict


# --- an episode log made by hand ------------------------------------------------------------


def crafted_log(planned: int = 3, diverged: bool = False) -> EpisodeLog:
    """Three ticks with errors 0.3, 0.4 and 0 m and command steps small enough to add by hand."""
    u = np.zeros((3, 7))
    u[1, 0] = 3.0  # step 1: (3)² = 9
    u[2, 0], u[2, 6] = 3.0, 40.0  # step 2: (40)² = 1600, and A7 at its limit
    ee_des = np.zeros((3, 3))
    ee = np.array([[0.3, 0.0, 0.0], [0.0, 0.4, 0.0], [0.0, 0.0, 0.0]])
    zeros = np.zeros((3, 7))
    metadata = EpisodeMetadata(
        spec=EpisodeSpec(gains=PDGains(kp=(1,) * 7, kd=(1,) * 7)),
        ticks_planned=planned,
        ticks_run=3,
        torque_limits=TORQUE_LIMITS,
        diverged=diverged,
        versions={},
    )
    return EpisodeLog(
        t=np.arange(3) * 0.002,
        q=zeros,
        qd=zeros,
        tau=u,
        u=u,
        theta=zeros,
        theta_d=zeros,
        q_des=zeros,
        qd_des=zeros,
        ee=ee,
        ee_des=ee_des,
        metadata=metadata,
    )


def log_bytes(log: EpisodeLog) -> bytes:
    """`log` as the worker encodes it: MCAP, with the iiwa drawn for ROS tools."""
    return episode_bytes(log, description())


def write_log(log: EpisodeLog, path: Path) -> int:
    """Write `log` to `path` as `worker episode --out` does; return its size."""
    content = log_bytes(log)
    Path(path).write_bytes(content)
    return len(content)


def perfect_log(spec: EpisodeSpec) -> bytes:
    """A well-made episode log of `spec` claiming no error and no torque change at all."""
    log = crafted_log()
    flat = np.zeros_like(log.u)
    return log_bytes(
        dataclasses.replace(
            log,
            tau=flat,
            u=flat,
            ee=log.ee_des.copy(),
            # and a stable loop: a worker's log carries its margin (worker.stability)
            metadata=log.metadata.model_copy(update={"spec": spec, "damping": 0.1}),
        )
    )


def analytic(*arguments: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """`python -m analytic ARGUMENTS` in `cwd`, its output captured (wide, for rich's lines)."""
    return subprocess.run(
        [sys.executable, "-m", "gainfarm.analytic", *arguments],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "COLUMNS": "200"},
    )


def held_out_closing(run_dir: Path, row: int | None) -> list[str]:
    """The closing lines on how the controller at front.csv `row` (None: the default gains) did
    on the held-out plants, from check.json (none without one): its figures as the file has
    them, beside the default gains' for a member."""
    path = run_dir / "check.json"
    if not path.exists():
        return []
    record = json.loads(path.read_text())
    [item] = [item for item in record["controllers"] if item["row"] == row]
    [default] = [item for item in record["controllers"] if item["row"] is None]
    plants, asked = record["plants"], record["asked"]
    on = (
        f"{plants} of the {asked} plants asked"
        if plants < asked
        else f"{plants} plant{'' if plants == 1 else 's'}"
    )
    lines = [
        f"held out, on {on}: error {item['median_f_acc'] * 1e3:.2f} mm median, "
        f"{item['worst_f_acc'] * 1e3:.2f} mm worst"
    ]
    if row is not None:
        lines.append(
            f"  (default gains: {default['median_f_acc'] * 1e3:.2f} mm, "
            f"{default['worst_f_acc'] * 1e3:.2f} mm)"
        )
    if plants < asked:
        lines.append("  (the check may take at most half the run's own episodes)")
    plural = "plant" if item["violations"] == 1 else "plants"
    lines.append(
        f"held out: {item['violations']} {plural} broke a limit, {item['diverged']} diverged"
    )
    return lines


def ends_with_closing_lines(lines: list[str], run_dir: Path) -> int:
    """Assert that `lines` (a command's standard error) end as `analytic start` and `resume` end
    a run, saying what its report.md's first line says: the controller to use and how to export
    it, or that none beats the default gains (none held on the held-out check: keep them), the
    closest and where to read more. Returns how many closing lines there are."""
    verdict = (run_dir / "report.md").read_text(encoding="utf-8").splitlines()[2]
    scores = r"\(([\d.]+) mm, (f_t\w*) (\S+) \(N·m\)²\)"  # f_t or f_t_joint, by name
    if checked := re.match(r"\*\*Use front\.csv row (\d+)\*\*: on ", verdict):
        row, used = checked.group(1), True
        expected = [
            f"controller to use: row {row} of front.csv: ",
            f"its gains: analytic export {run_dir.name}",
        ]
    elif used := re.match(rf"\*\*Use front\.csv row (\d+)\*\* {scores}", verdict):
        row, error, torque, smoothness = used.groups()
        expected = [
            f"controller to use: row {row} of front.csv: {error} mm, {torque} {smoothness} (N·m)²",
            f"its gains: analytic export {run_dir.name}",
        ]
    elif verdict.startswith("**Keep the default gains**"):
        row, used = None, False
        expected = [
            "controller to use: the default gains; no member held against them",
            "closest on the check: row ",
            f"what to do: {run_dir.name}/report.md",
        ]
    else:
        closest = re.search(rf"Closest to dominating them: row (\d+) {scores}", verdict)
        assert verdict.startswith("**No member of the front dominates") and closest, verdict
        row, error, torque, smoothness = closest.groups()
        expected = [
            "controller to use: none, no member beats the default gains",
            f"closest to them: row {row} of front.csv: {error} mm, {torque} {smoothness} (N·m)²",
            f"what to do: {run_dir.name}/report.md",
        ]
    held_out = held_out_closing(run_dir, None if row is None else int(row))
    at = 1 if used else 2  # after the line that names the controller
    expected[at:at] = held_out
    # A member sharing its scores, or diverged, says so after them.
    closing = lines[-len(expected) :]
    assert all(line.startswith(want) for line, want in zip(closing, expected, strict=True)), lines
    return len(expected)
