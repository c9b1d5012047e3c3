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
from gainfarm.schemas.robot import ModelSpec
from gainfarm.schemas.trajectory import TrajectorySpec

EVALUATIONS = "evaluations.json"


def batch_jobs(
    candidates: Sequence[PDGains],
    trajectories: Sequence[TrajectorySpec],
    model: ModelSpec,
    feedforward: str | None = None,
) -> dict[str, EpisodeSpec]:
    """Job id → spec, one per pair; ids say which candidate on which trajectory. `feedforward`:
    the SHA-256 of the learned model every episode adds to its PD, if any."""
    return {
        f"c{index:03d}-{number}-{trajectory.kind}": EpisodeSpec(
            gains=gains, trajectory=trajectory, model=model, feedforward=feedforward
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
    for evaluation in evaluator.results():
        evaluations[evaluation.job_id] = evaluation
        on_evaluation(evaluation)
    elsewhere = {
        job_id: Wanted(evaluation.spec, evaluation.digest, (evaluation.worker,))
        for job_id, evaluation in evaluations.items()
        if evaluation.log is None and evaluation.scores is not None and evaluation.digest
    }
    for job_id, got in evaluator.fetch(elsewhere).items() if elsewhere else ():
        evaluations[job_id] = dataclasses.replace(
            evaluations[job_id],
            log=got.log,
            scores=got.scores if got.log is not None else evaluations[job_id].scores,
            reason=evaluations[job_id].reason or got.reason,
        )
    ordered = [evaluations[job_id] for job_id in jobs if job_id in evaluations]
    records = [evaluation_record(evaluation, run_dir) for evaluation in ordered]
    write_atomically(run_dir / EVALUATIONS, json.dumps(records, indent=1).encode())
    return ordered


def evaluation_record(evaluation: EpisodeResult, run_dir: Path) -> dict[str, object]:
    return {
        "job_id": evaluation.job_id,
        "status": evaluation.status.value,
        "reason": evaluation.reason,
        "scores": evaluation.scores.model_dump() if evaluation.scores else None,
        "episode": str(evaluation.log.relative_to(run_dir)) if evaluation.log else None,
        "spec": evaluation.spec.model_dump(mode="json"),
        "worker": evaluation.worker,
        "attempts": evaluation.attempts,
    }
