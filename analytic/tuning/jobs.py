"""A run's episodes by name: each candidate's job ids (`<candidate>-t<n>[-p<k>]`), the spec each
id stands for, the episodes a run plans, and the objectives a candidate's episodes' scores give.
Pure: functions of the run's config."""

from collections.abc import Sequence

from gainfarm.analytic.tuning.config import RunConfig
from gainfarm.analytic.tuning.declared import declarations
from gainfarm.schemas.episode import EpisodeSpec, Scores
from gainfarm.schemas.gains import PDGains
from gainfarm.schemas.objectives import no_episode, objectives


def job_ids(config: RunConfig, candidate: str) -> list[str]:
    """A candidate's episodes: each trajectory on the nominal plant (`-t<n>`, as before there
    were variants), then on each plant variant (`-t<n>-p<k>`), the order `objectives` takes."""
    variants = len(config.plants)
    return [
        f"{candidate}-t{number}{f'-p{plant}' if plant else ''}"
        for number in range(len(config.trajectories))
        for plant in range(1 + variants)
    ]


def slot_of(job_id: str) -> tuple[int, int]:
    """(trajectory, plant) of a candidate's job id: `<candidate>-t<n>[-p<k>]`."""
    number, _, plant = job_id.rsplit("-t", 1)[1].partition("-p")
    return int(number), int(plant or 0)


def episode_spec(config: RunConfig, gains: PDGains, job_id: str) -> EpisodeSpec:
    """The spec of a candidate's episode, from its job id (`job_ids`)."""
    return config.episode_spec(gains, *slot_of(job_id))


def specs(config: RunConfig, jobs: dict[PDGains, list[str]]) -> dict[str, EpisodeSpec]:
    """The specs of candidates' episodes, by job id."""
    return {
        job_id: episode_spec(config, gains, job_id) for gains, ids in jobs.items() for job_id in ids
    }


def candidate_objectives(config: RunConfig, scores: Sequence[Scores | None]) -> tuple[float, float]:
    """A candidate's objectives from its episodes' scores, in `job_ids`' order."""
    return objectives(
        scores,
        config.objective_weights,
        1 + len(config.plants),
        config.aggregate,
        config.plant_scales,
        no_episode(declarations(config.objectives)),
    )


def planned_episodes(config: RunConfig) -> int:
    """The episodes a run plans: its budget of evaluations (for a run that stops on convergence,
    the fewest it can: the termination's window and one generation more), each an episode per
    trajectory and plant."""
    evaluations = config.budget or (config.termination.window + 1) * config.pop
    return evaluations * len(config.trajectories) * (1 + len(config.plants))
