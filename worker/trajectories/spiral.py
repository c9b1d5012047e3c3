"""The spiral kind: a conical helix widening from the centre, the paper's path."""

import numpy as np

from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.trajectories import Kind, placed

# How far a seed turns the spiral, in turns (`placed`): any way, as every turn of it is alike.
SEED_TURNS = 1.0


def spiral(spec: TrajectorySpec, u: np.ndarray) -> np.ndarray:
    """The spiral's path, a conical helix: the radius grows from 0 to `size` while it rises by
    `size`, in `turns` turns; placed by its seed (`placed`)."""
    angle = 2.0 * np.pi * spec.turns * u
    radius = spec.size * u
    helix = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), spec.size * (u - 0.5)])
    return placed(spec, helix, SEED_TURNS)


KIND = Kind(path=spiral)
