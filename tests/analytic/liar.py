"""Workers that lie, each runs every episode honestly first:

- a liar (the default) changes one torque sample in the log it returns (a valid log, with the
  scores that log has: almost the same);
- `--scores`: a boaster returns its honest log and claims scores 10 % better than the log's;
- `--forge`: a forger returns a log it made up, self-consistent: the error and the torque steps
  cut to 0.3 of what they were, and the scores of that log (every such episode looks better);
- `--sabotage`: a saboteur keeps its honest log and claims scores 5 times worse (its
  candidates lose, so none reaches the front, where the referee looks before a run reports).

Run as `python -m tests.analytic.liar ENDPOINT NAME [--scores | --forge | --sabotage]` by the
replication tests."""

import dataclasses
import hashlib
import signal
import sys
import threading
from collections.abc import Callable

from gainfarm.models.dynamics import DynamicsModel
from gainfarm.models.urdf import description
from gainfarm.schemas.mcap_episode import decode_episode, episode_bytes
from gainfarm.schemas.objectives import score
from gainfarm.schemas.wire import Lease, Result, WireScores
from gainfarm.worker import service
from gainfarm.worker.job import Simulate, execute, simulate


def lying_execute(
    lease: Lease,
    name: str,
    model: Callable[[str], DynamicsModel] | None = None,
    run: Simulate = simulate,
) -> tuple[Result, bytes]:
    result, content = execute(lease, name, model, run)
    if not content:
        return result, content
    log = decode_episode(content)
    u = log.u.copy()
    u[len(u) // 2, 3] += 0.01  # N·m: one sample of one joint's command
    altered = episode_bytes(dataclasses.replace(log, u=u), description())
    digest = hashlib.sha256(altered).hexdigest()
    scores = WireScores(**score(decode_episode(altered)).model_dump())
    update = {"episode_bytes": len(altered), "digest": digest, "scores": scores}
    return result.model_copy(update=update), altered


def forging_execute(
    lease: Lease,
    name: str,
    model: Callable[[str], DynamicsModel] | None = None,
    run: Simulate = simulate,
) -> tuple[Result, bytes]:
    result, content = execute(lease, name, model, run)
    if not content:
        return result, content
    log = decode_episode(content)
    u = log.u[:1] + 0.3 * (log.u - log.u[:1])  # each torque step 0.3 of what it was
    ee = log.ee_des + 0.3 * (log.ee - log.ee_des)  # and the error
    forged = episode_bytes(dataclasses.replace(log, u=u, ee=ee), description())
    scores = WireScores(**score(decode_episode(forged)).model_dump())
    digest = hashlib.sha256(forged).hexdigest()
    update = {"episode_bytes": len(forged), "digest": digest, "scores": scores}
    return result.model_copy(update=update), forged


def sabotaging_execute(
    lease: Lease,
    name: str,
    model: Callable[[str], DynamicsModel] | None = None,
    run: Simulate = simulate,
) -> tuple[Result, bytes]:
    result, content = execute(lease, name, model, run)
    if result.scores is None:
        return result, content
    worse = {"f_acc": 5 * result.scores.f_acc, "f_t": 5 * result.scores.f_t}
    return result.model_copy(update={"scores": result.scores.model_copy(update=worse)}), content


def boasting_execute(
    lease: Lease,
    name: str,
    model: Callable[[str], DynamicsModel] | None = None,
    run: Simulate = simulate,
) -> tuple[Result, bytes]:
    result, content = execute(lease, name, model, run)
    if result.scores is None:
        return result, content
    better = {"f_acc": 0.9 * result.scores.f_acc, "f_t": 0.9 * result.scores.f_t}
    return result.model_copy(update={"scores": result.scores.model_copy(update=better)}), content


def main() -> None:
    endpoint, name = sys.argv[1:3]
    how = {
        "--scores": boasting_execute,
        "--forge": forging_execute,
        "--sabotage": sabotaging_execute,
    }
    service.execute = next((how[flag] for flag in sys.argv[3:] if flag in how), lying_execute)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with service.CobotWorker([endpoint], name) as cobot:
        cobot.serve(stop)


if __name__ == "__main__":
    main()
