"""The pyramid kind: the straight edges of a square pyramid, the arm at rest at every corner."""

import numpy as np

from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.trajectories import Kind, cumulative_length, placed

# How far a seed turns the pyramid, in turns (`placed`): by ±30° at most, as beyond about 40° its
# edges lead the arm where the paper's 3 s path is too fast for it (3.3 s needed at 90°,
# measured by worker/reference.py).
SEED_TURNS = 1.0 / 6.0
_BASE_CORNERS = ((1, 1), (-1, 1), (-1, -1), (1, -1))


def pyramid(spec: TrajectorySpec, s: np.ndarray) -> np.ndarray:
    """The pyramid's offsets at its progress `s`, already its arc-length fraction: straight
    edges, the arm at rest at every corner (`corners`), so not a smooth path."""
    vertices = _vertices(spec)
    arc = cumulative_length(vertices)
    target = s * arc[-1]
    return np.column_stack([np.interp(target, arc, vertices[:, i]) for i in range(3)])


def corners(spec: TrajectorySpec) -> np.ndarray:
    """The progress values of its corners, the ends included: where the arm rests."""
    arc = cumulative_length(_vertices(spec))
    return arc / arc[-1]


def _vertices(spec: TrajectorySpec) -> np.ndarray:
    """A square pyramid's edges (base half-width `size`, height `size`), in drawing order,
    placed by its seed (`placed`)."""
    h = spec.size / 2.0
    b0, b1, b2, b3 = ([sx * spec.size, sy * spec.size, -h] for sx, sy in _BASE_CORNERS)
    apex = [0.0, 0.0, h]
    return placed(spec, np.array([b0, apex, b1, b2, apex, b3, b0]), SEED_TURNS)


KIND = Kind(path=pyramid, by_arc_length=True, rests=corners)
