"""The defaults and choices the command lines' declarations hold, so that parsing and --help load
nothing heavy, are their sources' (a change there fails here, not silently in --help)."""

from gainfarm.broker import certs, queue, service
from gainfarm.broker import cli as broker_cli
from gainfarm.cli import options
from gainfarm.schemas.robot import MAX_JOINTS, PLANTS, PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker import cli as worker_cli


def test_the_shared_options_held_defaults_are_the_contract_s() -> None:
    trajectory = TrajectorySpec()
    assert (
        trajectory.kind,
        trajectory.duration,
        trajectory.seed,
    ) == (options.TRAJECTORY_KIND, options.DURATION, options.TRAJECTORY_SEED)
    assert (trajectory.center, trajectory.size) == (options.CENTER, options.SIZE)
    assert tuple(PLANTS) == options.PLANTS
    assert PLANTS[options.PLANT] == PlantSpec()
    assert tuple(PlantSpec.model_fields["joints"].annotation.__args__) == options.JOINTS
    assert PlantSpec().joints == options.JOINT


def test_the_worker_s_and_broker_s_held_defaults_are_their_sources() -> None:
    assert MAX_JOINTS == worker_cli.MAX_JOINTS
    assert service.DEFAULT_LISTEN == broker_cli.LISTEN
    assert (queue.DEFAULT_MAX_QUEUED, queue.DEFAULT_MAX_QUEUED_PER_STUDY) == (
        broker_cli.MAX_QUEUED,
        broker_cli.MAX_QUEUED_PER_STUDY,
    )
    assert (certs.DEFAULT_ANALYTICS, certs.DEFAULT_WORKERS, tuple(certs.DEFAULT_HOSTS)) == (
        broker_cli.ANALYTICS,
        broker_cli.WORKERS,
        broker_cli.HOSTS,
    )
