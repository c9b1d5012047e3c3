"""Every built-in trajectory kind passes the conformance kit a plug-in's author runs
(gainfarm.testing.trajectories): the project's own kinds are checked as a third party's are.
Seeds other than 0 too, as the spiral and the pyramid are turned by theirs."""

import pytest

from gainfarm import plugins
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.testing.trajectories import TrajectoryChecks

SENSIBLE = [
    TrajectorySpec(kind=kind, duration=3.0, seed=seed)
    for kind in plugins.builtin_names(plugins.TRAJECTORIES)
    for seed in (0, 3)
]


class TestEveryBuiltInKind(TrajectoryChecks):
    @pytest.fixture(name="spec", params=SENSIBLE, ids=lambda spec: f"{spec.kind}-{spec.seed}")
    def _spec(self, request: pytest.FixtureRequest) -> TrajectorySpec:
        return request.param
