"""Evaluate a fixed set of candidate gains on a set of trajectories, through the farm.

The farm's plainest use, and NSGA-II's building block: every (candidate, trajectory) pair is one
job; each evaluation is scored from its log; the run directory ends up with episodes/ and an
evaluations.json that says which file holds what.
"""

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path

from gainfarm.analytic.evaluators.evaluator import EpisodeResult, Evaluator, Wanted
from gainfarm.edges.files import write_atomically
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.robot import PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec

EVALUATIONS = "evaluations.json"


def batch_jobs(
    candidates: Sequence[PDGains],
    trajectories: Sequence[TrajectorySpec],
    plant: PlantSpec,
    feedforward: str | None = None,
) -> dict[str, EpisodeSpec]:
    """Job id → spec, one per pair; ids say which candidate on which trajectory. `feedforward`:
    the SHA-256 of the learned model every episode adds to its PD, if any."""
    return {
        f"c{index:03d}-{number}-{trajectory.kind}": EpisodeSpec(
            gains=gains, trajectory=trajectory, plant=plant, feedforward=feedforward
        )
        for index, gains in enumerate(candidates)
        for number, trajectory in enumerate(trajectories)
    }


def run_batch(
    evaluator: Evaluator,
    jobs: dict[str, EpisodeSpec],
    run_dir: Path,
    on_evaluation: Callable[[EpisodeResult], None] = lambda _: None,
) -> list[EpisodeResult]:
    """Submit every job, collect every evaluation (in job order), write
    run_dir/evaluations.json. Every log is kept in run_dir/episodes/ and scored here: as it
    comes, or fetched from the worker that keeps it (a farm client that leaves logs with the
    workers)."""
    evaluator.submit(jobs)
    evaluations = {}
    for result in evaluator.results():
        evaluations[result.job_id] = result
        on_evaluation(result)
    elsewhere = {
        job_id: Wanted(result.spec, result.digest, (result.worker,))
        for job_id, result in evaluations.items()
        if result.log is None and result.scores is not None and result.digest
    }
    for job_id, got in evaluator.fetch(elsewhere).items() if elsewhere else ():
        evaluations[job_id] = dataclasses.replace(
            evaluations[job_id],
            log=got.log,
            scores=got.scores if got.log is not None else evaluations[job_id].scores,
            reason=evaluations[job_id].reason or got.reason,
        )
    ordered = [evaluations[job_id] for job_id in jobs if job_id in evaluations]
    records = [evaluation_record(result, run_dir) for result in ordered]
    write_atomically(run_dir / EVALUATIONS, json.dumps(records, indent=1).encode())
    return ordered


def evaluation_record(result: EpisodeResult, run_dir: Path) -> dict[str, object]:
    return {
        "job_id": result.job_id,
        "status": result.status.value,
        "reason": result.reason,
        "scores": result.scores.model_dump() if result.scores else None,
        "episode": str(result.log.relative_to(run_dir)) if result.log else None,
        "spec": result.spec.model_dump(mode="json"),
        "worker": result.worker,
        "attempts": result.attempts,
    }
