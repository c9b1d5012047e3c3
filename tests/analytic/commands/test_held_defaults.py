"""The defaults and choices a command's declaration holds, so that parsing and --help load
nothing heavy, are their sources' (a change there fails here, not silently in --help)."""

import inspect

from gainfarm.analytic.commands import batch, dashboard, dataset, export, learn, replay
from gainfarm.analytic.data.dataset import DEFAULT_SPLIT
from gainfarm.analytic.data.learning import learn as learn_dynamics
from gainfarm.analytic.evaluators.farm import DEFAULT_DEADLINE
from gainfarm.analytic.view import replay as replaying
from gainfarm.analytic.view.dashboard import DASHBOARD_PORT
from gainfarm.analytic.view.export import FORMATS
from gainfarm.cli import options
from gainfarm.models.dynamics import KINDS, TARGETS
from gainfarm.schemas.robot import PLANTS, ModelSpec
from gainfarm.schemas.trajectory import TrajectorySpec


def test_the_commands_held_defaults_are_their_sources() -> None:
    assert batch.DEADLINE == DEFAULT_DEADLINE
    assert dashboard.PORT == DASHBOARD_PORT
    assert dataset.SPLIT == DEFAULT_SPLIT
    assert export.FORMATS == FORMATS
    assert (learn.TARGETS, learn.KINDS) == (TARGETS, KINDS)
    defaults = inspect.signature(learn_dynamics).parameters
    assert (learn.TARGET, learn.KIND, learn.SEED) == tuple(
        defaults[name].default for name in ("target", "kind", "seed")
    )
    assert (replay.FPS, replay.WIDTH, replay.HEIGHT) == (
        replaying.DEFAULT_FPS,
        replaying.DEFAULT_WIDTH,
        replaying.DEFAULT_HEIGHT,
    )


def test_the_shared_options_held_defaults_are_the_contract_s() -> None:
    trajectory = TrajectorySpec()
    assert (options.TRAJECTORY_KIND, options.DURATION, options.TRAJECTORY_SEED) == (
        trajectory.kind,
        trajectory.duration,
        trajectory.seed,
    )
    assert (options.CENTER, options.SIZE) == (trajectory.center, trajectory.size)
    assert options.PLANTS == tuple(PLANTS)
    assert PLANTS[options.PLANT] == ModelSpec()
    assert options.JOINTS == tuple(ModelSpec.model_fields["joints"].annotation.__args__)
    assert options.JOINT == ModelSpec().joints
