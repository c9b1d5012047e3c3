"""Constants and helpers the tests share."""

import time
from collections.abc import Callable

import zenoh

from broker.service import Broker
from schemas import EpisodeSpec, PDGains, TrajectorySpec, keys
from schemas.wire import (
    Job,
    JobStatus,
    Lease,
    LeaseReply,
    LeaseRequest,
    Result,
    Submission,
    SubmitReply,
    Timings,
    decode,
)

TRACKING_GAINS = PDGains(kp=(2000, 2000, 1200, 1200, 400, 200, 100), kd=(60, 60, 40, 40, 10, 5, 2))
SOFT_GAINS = PDGains(kp=(200, 200, 120, 120, 40, 20, 10), kd=(20, 20, 12, 12, 4, 2, 1))
WEAK_GAINS = PDGains(kp=(5,) * 7, kd=(1,) * 7)  # too soft to hold the arm up


# --- the farm: real Zenoh sessions on loopback ----------------------------------------------


def wait_for(condition: Callable[[], object], timeout: float = 10.0, what: str = "it") -> None:
    """Poll until `condition()` is true; fail the test (not hang it) if it never is."""
    give_up = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > give_up:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


def short_spec(duration: float = 0.5, gains: PDGains = TRACKING_GAINS, **trajectory) -> EpisodeSpec:
    return EpisodeSpec(gains=gains, trajectory=TrajectorySpec(duration=duration, **trajectory))


def query(session: zenoh.Session, key: str, payload: bytes | None = None) -> tuple[bool, bytes]:
    """(ok, payload) of the one reply to a query; fails the test if nobody answers."""
    for reply in session.get(key, payload=payload, timeout=5.0):
        if reply.ok is not None:
            return True, reply.ok.payload.to_bytes()
        return False, reply.err.payload.to_bytes()
    raise AssertionError(f"no reply on {key}")


def open_study(session: zenoh.Session, broker: Broker, study: str) -> zenoh.LivelinessToken:
    """Hold `study`'s liveliness token, as an analytic process does, until the broker knows it.

    Keep the token: Zenoh undeclares it when it is garbage-collected."""
    token = session.liveliness().declare_token(keys.alive_study(study))
    wait_for(lambda: broker.queue.has_study(study), what=f"the broker to open {study}")
    return token


def submit(session: zenoh.Session, study: str, specs: dict[str, EpisodeSpec]) -> SubmitReply:
    jobs = [Job(job_id=job_id, episode=spec) for job_id, spec in specs.items()]
    ok, payload = query(session, keys.SUBMIT, Submission(study=study, jobs=jobs).to_bytes())
    assert ok, payload
    return decode(SubmitReply, payload)


def result_for(study: str, job_id: str, worker: str = "w", **fields: object) -> Result:
    """A Result as a worker would send it, made by hand; `fields` override the defaults."""
    defaults: dict[str, object] = {
        "lease_id": "by-hand",
        "status": JobStatus.ok,
        "episode_bytes": 0,
        "timings": Timings(simulate_s=0.0, encode_s=0.0),
    }
    return Result(study=study, job_id=job_id, worker=worker, **{**defaults, **fields})


def ask_for_work(session: zenoh.Session, worker: str) -> Lease | None:
    ok, payload = query(session, keys.LEASE, LeaseRequest(worker=worker).to_bytes())
    assert ok, payload
    return decode(LeaseReply, payload).lease
