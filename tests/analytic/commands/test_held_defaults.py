"""The defaults and choices a command's declaration holds, so that parsing and --help load
nothing heavy, are their sources' (a change there fails here, not silently in --help)."""

import inspect

from gainfarm.analytic.commands import batch, dashboard, dataset, export, learn, replay, shared
from gainfarm.analytic.data.dataset import DEFAULT_SPLIT
from gainfarm.analytic.data.learning import learn as learn_dynamics
from gainfarm.analytic.evaluators.farm import DEFAULT_DEADLINE
from gainfarm.analytic.tuning.records import CONFIG_JSON
from gainfarm.analytic.view import replay as replaying
from gainfarm.analytic.view.dashboard import DASHBOARD_PORT
from gainfarm.analytic.view.export import FORMATS
from gainfarm.models.dynamics import KINDS, TARGETS


def test_the_commands_held_defaults_are_their_sources() -> None:
    assert shared.RUN_FILE == CONFIG_JSON
    assert batch.DEADLINE == DEFAULT_DEADLINE
    assert dashboard.PORT == DASHBOARD_PORT
    assert dataset.SPLIT == DEFAULT_SPLIT
    assert export.FORMATS == FORMATS
    assert (learn.TARGETS, learn.KINDS) == (TARGETS, KINDS)
    defaults = inspect.signature(learn_dynamics).parameters
    assert tuple(defaults[name].default for name in ("target", "kind", "seed")) == (
        learn.TARGET,
        learn.KIND,
        learn.SEED,
    )
    assert (replay.FPS, replay.WIDTH, replay.HEIGHT) == (
        replaying.DEFAULT_FPS,
        replaying.DEFAULT_WIDTH,
        replaying.DEFAULT_HEIGHT,
    )
