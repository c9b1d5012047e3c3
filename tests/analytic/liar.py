"""Workers that lie, each runs every episode honestly first:

- a liar (the default) changes one torque sample in the log it returns (a valid log, with the
  scores that log has: almost the same);
- `--scores`: a boaster returns its honest log and claims scores 10 % better than the log's;
- `--forge`: a forger returns a log it made up, self-consistent: the error and the torque steps
  cut to 0.3 of what they were, and the scores of that log (every such episode looks better);
- `--sabotage`: a saboteur keeps its honest log and claims scores 5 times worse (its
  candidates lose, so none reaches the front, where the referee looks before a run reports);
- `--sabotage-good F_ACC`: the same, only on good candidates' episodes (an honest f_acc at most
  F_ACC, in metres), honest on the others;
- `--fail-good F_ACC`: says each good candidate's episode failed (no log, no scores), honest on
  the others;
- `--forge-defaults`: forges only the default gains' episodes, self-consistent logs 3 times worse
  than they ran (the error and the torque steps): every candidate seems to beat them.

Run as `python -m tests.analytic.liar ENDPOINT NAME [FLAG [F_ACC]]` by the replication tests."""

import dataclasses
import hashlib
import signal
import sys
import threading
from collections.abc import Callable, Sequence

from gainfarm.models.dynamics import DynamicsModel
from gainfarm.models.urdf import description
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import decode_episode, episode_bytes
from gainfarm.schemas.objectives import score
from gainfarm.schemas.wire import JobStatus, Lease, Result, WireScores
from gainfarm.worker import service
from gainfarm.worker.job import execute_batch

Executed = list[tuple[Result, bytes]]
ExecuteBatch = Callable[..., Executed]
Lie = Callable[[Result, bytes], tuple[Result, bytes]]
Picks = Callable[[Result, bytes], bool]


def lying(lie: Lie, when: Picks = lambda *_: True) -> ExecuteBatch:
    """A worker's `execute_batch` that runs its batch honestly, then tells `lie` of each job
    `when` picks (the truth of the others)."""

    def execute(
        leases: Sequence[Lease],
        name: str,
        model_of: Callable[[Lease], Callable[[str], DynamicsModel]] | None = None,
        threads: int = 1,
    ) -> Executed:
        ran = execute_batch(leases, name, model_of, threads)
        return [lie(*one) if when(*one) else one for one in ran]

    return execute


def good(f_acc: float) -> Picks:
    """A good candidate's episode: one that ran, with an honest f_acc at most `f_acc`."""
    return lambda result, _: result.scores is not None and result.scores.f_acc <= f_acc


def of_the_default_gains(result: Result, content: bytes) -> bool:
    return bool(content) and decode_episode(content).metadata.spec.gains == DEFAULT_GAINS


def failing(result: Result, content: bytes) -> tuple[Result, bytes]:
    """Says the episode failed: no log, no scores, an ordinary reason."""
    update = {
        "status": JobStatus.failed,
        "scores": None,
        "digest": hashlib.sha256(b"").hexdigest(),  # a failed job's, as worker.job makes it
        "episode_bytes": 0,
        "reason": "the simulation could not run",
    }
    return Result.model_validate(result.model_dump() | update), b""


def altering(
    change: Callable[[EpisodeLog], EpisodeLog], when: Picks = lambda *_: True
) -> ExecuteBatch:
    """Returns the log `change` makes of each honest one, with that log's own scores: a valid,
    self-consistent lie."""

    def lie(result: Result, content: bytes) -> tuple[Result, bytes]:
        if not content:
            return result, content
        altered = episode_bytes(change(decode_episode(content)), description())
        scores = WireScores(**score(decode_episode(altered)).model_dump())
        digest = hashlib.sha256(altered).hexdigest()
        update = {"episode_bytes": len(altered), "digest": digest, "scores": scores}
        return result.model_copy(update=update), altered

    return lying(lie, when)


def claiming(factor: float, when: Picks = lambda *_: True) -> ExecuteBatch:
    """Returns each honest log and claims f_acc and f_t `factor` times what the log has."""

    def lie(result: Result, content: bytes) -> tuple[Result, bytes]:
        if result.scores is None:
            return result, content
        claimed = {"f_acc": factor * result.scores.f_acc, "f_t": factor * result.scores.f_t}
        scores = result.scores.model_copy(update=claimed)
        return result.model_copy(update={"scores": scores}), content

    return lying(lie, when)


def _one_sample_off(log: EpisodeLog) -> EpisodeLog:
    u = log.u.copy()
    u[len(u) // 2, 3] += 0.01  # N·m: one sample of one joint's command
    return dataclasses.replace(log, u=u)


def _flattering(log: EpisodeLog) -> EpisodeLog:
    u = log.u[:1] + 0.3 * (log.u - log.u[:1])  # each torque step 0.3 of what it was
    ee = log.ee_des + 0.3 * (log.ee - log.ee_des)  # and the error
    return dataclasses.replace(log, u=u, ee=ee)


def _disparaging(log: EpisodeLog) -> EpisodeLog:
    u = log.u[:1] + 3.0 * (log.u - log.u[:1])  # each torque step 3 times what it was
    ee = log.ee_des + 3.0 * (log.ee - log.ee_des)  # and the error
    return dataclasses.replace(log, u=u, ee=ee)


lying_execute = altering(_one_sample_off)
forging_execute = altering(_flattering)
boasting_execute = claiming(0.9)
sabotaging_execute = claiming(5.0)


def main() -> None:
    endpoint, name = sys.argv[1:3]
    how = {
        "--scores": boasting_execute,
        "--forge": forging_execute,
        "--sabotage": sabotaging_execute,
    }
    flags = sys.argv[3:]
    picky = {
        "--sabotage-good": lambda f_acc: claiming(5.0, good(f_acc)),
        "--fail-good": lambda f_acc: lying(failing, good(f_acc)),
    }
    if flags and flags[0] in picky:
        service.execute_batch = picky[flags[0]](float(flags[1]))
    elif flags == ["--forge-defaults"]:
        service.execute_batch = altering(_disparaging, of_the_default_gains)
    else:
        service.execute_batch = next((how[flag] for flag in flags if flag in how), lying_execute)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with service.CobotWorker([endpoint], name) as cobot:
        cobot.serve(stop)


if __name__ == "__main__":
    main()
