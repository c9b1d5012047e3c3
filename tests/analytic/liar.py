"""A worker that lies subtly: it runs each episode honestly, then changes one torque sample in
the log it returns (a valid log, scored almost the same). Run as
`python -m tests.analytic.liar ENDPOINT NAME` by the replication tests."""

import dataclasses
import hashlib
import signal
import sys
import threading
from collections.abc import Callable

import worker.service
from models.dynamics import DynamicsModel
from schemas.mcap_episode import decode_episode, episode_bytes
from schemas.wire import Lease, Result
from worker.job import execute


def lying_execute(
    lease: Lease, name: str, model: Callable[[str], DynamicsModel] | None = None
) -> tuple[Result, bytes]:
    result, content = execute(lease, name, model)
    if not content:
        return result, content
    log = decode_episode(content)
    u = log.u.copy()
    u[len(u) // 2, 3] += 0.01  # N·m: one sample of one joint's command
    altered = episode_bytes(dataclasses.replace(log, u=u))
    digest = hashlib.sha256(altered).hexdigest()
    return result.model_copy(update={"episode_bytes": len(altered), "digest": digest}), altered


def main() -> None:
    endpoint, name = sys.argv[1:3]
    worker.service.execute = lying_execute
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with worker.service.CobotWorker([endpoint], name) as cobot:
        cobot.serve(stop)


if __name__ == "__main__":
    main()
