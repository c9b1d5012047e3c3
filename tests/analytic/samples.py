"""A run's records, made by hand, for the tests of the files that hold them."""

from pathlib import Path

from gainfarm.analytic.tuning.records import FrontMember, HistoryRow

KP = (2000.0, 2000.0, 1200.0, 1200.0, 400.0, 200.0, 100.0)
KD = (20.0, 20.0, 15.0, 15.0, 4.0, 2.0, 1.0)

# A run's records for the tests of its files: deliberately out of order, with values that a
# rounded format would not round-trip.
SAMPLE_FRONT = (
    FrontMember(kp=KP, kd=KD, objectives=(0.0123456789012345, 0.1 + 0.2)),
    FrontMember(kp=tuple(k / 3 for k in KP), kd=KD, objectives=(0.045, 1e-3 / 7)),
    FrontMember(
        kp=tuple(k * 1.5 for k in KP),
        kd=tuple(k / 7 for k in KD),
        objectives=(0.002, 4.2e4),
        diverged=True,
    ),
)
SAMPLE_HISTORY = (
    HistoryRow(1, 30, 0.5, (0.05, 10.0), 12.5),
    HistoryRow(2, 60, 0.75 + 1e-12, (0.01, 1.0), 3700.25),
    HistoryRow(3, 90, 0.8, (0.002, 1e-3 / 7), 7300.0),
)
SAMPLE_CONVERGED = "converged after 90 evaluations (hypervolume gain < 0.1% over 3 generations)"


def leftovers(directory: Path) -> list[Path]:
    """Temporary files an atomic write left behind (there should be none)."""
    return [path for path in directory.iterdir() if path.name.endswith(".part")]
