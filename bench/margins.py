"""The margins a control engineer reads (worker/stability.py `margins`) of real controllers, and
what they cost against an episode. docs/limits.md quotes these numbers.

    python bench/margins.py [--repeats 5] [--split]

Each controller runs the default 5 s spiral on the realistic plant (PlantSpec()): its least
damping (what the log carries), its tracking and elastic modes' least damping with their
frequencies, its tracking damping with the command 2 ticks late (the top of models/
uncertainty.toml's `delay` range; the nominal is 1) and its delay margin in extra ticks. Then
the cost of one `margins` call: cold (the plant's linearisations made, as in the analytic's
process the first time) and warm (as for each further controller on the same plant and path),
against one episode (`run_episode`, the log with its least damping), medians of `--repeats`.

`--split` checks the rule that tells a tracking mode from an elastic one (`tracking_modes`): on
the realistic plant, the ideal plant, one with ten times the rotor inertia and a rigid one, for
each controller below and command delay 0-9, it finds the modes that decide the margins (the
least damped tracking and elastic mode over the five poses) and counts those whose motion is
mixed (|c| < 0.5, c the cosine of the motors' motion with their links'; the rule reads its
sign), with the frequencies each class's deciding modes span; on the spiral and a 2 s fourier path.
"""

import itertools
import statistics
import threading
import time

import click
import numpy as np

from gainfarm.analytic.tuning.search_space import SearchSpace
from gainfarm.schemas.episode import EpisodeSpec
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.robot import IDEAL_PLANT, PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec
from gainfarm.worker.control import PDController
from gainfarm.worker.episode import run_episode
from gainfarm.worker.plant import Plant
from gainfarm.worker.reference import reference_for
from gainfarm.worker.stability import (
    POSES,
    ClosedLoop,
    _linearised,
    _pose_ticks,
    _scratch,
    damping_ratios,
    margins,
    natural_hz,
)

TOP_DELAY = 2  # ticks: the top of models/uncertainty.toml's `delay` range


def scaled(kp: float, kd: float, kd_a1_a2: float = 1.0) -> PDGains:
    """The default gains times (kp, kd), A1's and A2's Kd times `kd_a1_a2` more."""
    kd_factors = (kd * kd_a1_a2,) * 2 + (kd,) * 5
    return PDGains(
        kp=tuple(kp * gain for gain in DEFAULT_GAINS.kp),
        kd=tuple(f * gain for f, gain in zip(kd_factors, DEFAULT_GAINS.kd, strict=True)),
    )


SPACE = SearchSpace()
CONTROLLERS = {
    "default": DEFAULT_GAINS,
    "search top (Kp 3x, Kd 5x)": PDGains(kp=SPACE.kp_high, kd=SPACE.kd_high),
    "soft (Kp, Kd 0.3x)": scaled(0.3, 0.3),
    "stiff (Kp 3x)": scaled(3, 1),
    "A1/A2 Kd 0.1x": scaled(1, 1, 0.1),
    "Kd 0.1x": scaled(1, 0.1),
}


def _hz(value: float | None) -> str:
    return "-" if value is None else f"{value:5.1f}"


def table() -> None:
    print(
        "controller                  least    tracking (Hz)    elastic (Hz)     "
        f"at {TOP_DELAY} ticks (Hz)   delay margin"
    )
    for name, gains in CONTROLLERS.items():
        m = margins(EpisodeSpec(gains=gains, trajectory=TrajectorySpec()), delay=TOP_DELAY)
        elastic = "-" if m.elastic is None else f"{m.elastic:+.3f} ({_hz(m.elastic_hz)})"
        margin = f"{m.delay_margin}{'+' if m.capped else ''}"
        print(
            f"{name:26s} {m.least:+.3f}  {m.tracking:+.3f} ({_hz(m.tracking_hz)})  "
            f"{elastic:15s}  {m.tracking_at:+.3f} ({_hz(m.tracking_at_hz)})    {margin}"
        )


def cost(repeats: int) -> None:
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=TrajectorySpec())
    run_episode(spec)  # warm: the model compiled, the reference cached
    cold, warm, episode = [], [], []
    for _ in range(repeats):  # interleaved: each meets the same load
        _linearised.cache_clear()
        began = time.perf_counter()
        margins(spec, delay=TOP_DELAY)
        cold.append(time.perf_counter() - began)
        began = time.perf_counter()
        margins(spec, delay=TOP_DELAY)
        warm.append(time.perf_counter() - began)
        _linearised.cache_clear()  # the episode's least damping linearises, as on a worker
        began = time.perf_counter()
        run_episode(spec)
        episode.append(time.perf_counter() - began)
    c, w, e = (statistics.median(times) for times in (cold, warm, episode))
    print(
        f"\ncost, default gains, 5 s spiral, realistic plant, medians of {repeats}: margins cold "
        f"{c * 1e3:.0f} ms ({100 * c / e:.0f} % of an episode), warm {w * 1e3:.0f} ms "
        f"({100 * w / e:.0f} %); one episode {e * 1e3:.0f} ms"
    )


def split() -> None:
    """How clear-cut the modes that make the margins are, per plant (the module's docstring)."""
    rotor = PlantSpec(rotor_inertia=tuple(10 * r for r in PlantSpec().rotor_inertia))
    plants = {
        "realistic": PlantSpec(),
        "ideal": IDEAL_PLANT,
        "rotor 10x": rotor,
        "rigid": PlantSpec(joints="rigid"),
    }
    paths = {"spiral": TrajectorySpec(), "fourier": TrajectorySpec(kind="fourier", duration=2.0)}
    print(
        "\npath     plant       deciding modes  mixed (|c| < 0.5)  least |c|  tracking Hz  "
        "elastic Hz   mixed under"
    )
    for (path, trajectory), (name, model) in itertools.product(paths.items(), plants.items()):
        reference = reference_for(trajectory)
        plant, gravity = _scratch(model, threading.get_ident())
        deciding: list[tuple[float, float, bool, str]] = []  # (c, Hz, tracking, controller)
        for gains_name, gains in CONTROLLERS.items():
            controller = PDController.from_gains(gains, plant.torque_limits)
            for delay in range(10):
                loop = ClosedLoop(plant, controller, gravity, delay=delay)
                least: dict[bool, tuple[float, float, float]] = {}  # tracking? -> (ζ, c, Hz)
                for tick in _pose_ticks(reference, POSES):
                    pose = (reference.q[tick], reference.qd[tick], reference.qdd[tick])
                    matrix = loop.closed(_linearised(model, *(p.tobytes() for p in pose)))
                    z, vectors = np.linalg.eig(matrix)
                    ratios, hz, c = damping_ratios(z), natural_hz(z), _cosines(plant, vectors)
                    for index in range(len(z)):
                        tracking = bool(c[index] >= 0) or not np.isfinite(c[index])
                        if tracking not in least or ratios[index] < least[tracking][0]:
                            least[tracking] = (ratios[index], c[index], hz[index])
                for tracking, (_, c_value, hz_value) in least.items():
                    deciding.append((c_value, hz_value, tracking, gains_name))
        mixed = [d for d in deciding if abs(d[0]) < 0.5]
        least_c = min((abs(d[0]) for d in deciding if np.isfinite(d[0])), default=1.0)
        bands = []
        for tracking in (True, False):
            hz = [d[1] for d in deciding if d[2] == tracking]
            bands.append(f"{min(hz):.0f}-{max(hz):.0f}" if hz else "-")
        under = sorted({d[3] for d in mixed})
        print(
            f"{path:8s} {name:11s} {len(deciding):14d}  {len(mixed):17d}  {least_c:9.3f}  "
            f"{bands[0]:11s}  {bands[1]:11s}  {', '.join(under) or '-'}"
        )


def _cosines(plant: Plant, vectors: np.ndarray) -> np.ndarray:
    """Each mode's c: Re Σ conj(θ) q / (|θ| |q|), its motors' motion against its links'."""
    positions = vectors[: plant.model.nq]
    motor, link = plant.motor_map @ positions, plant.link_map @ positions
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.real(np.sum(np.conj(motor) * link, axis=0)) / (
            np.linalg.norm(motor, axis=0) * np.linalg.norm(link, axis=0)
        )


@click.command()
@click.option(
    "--repeats", default=5, show_default=True, type=click.IntRange(min=1), help="timed runs of each"
)
@click.option("--split", "check_split", is_flag=True, help="check the tracking/elastic rule")
def main(repeats: int, check_split: bool) -> None:
    table()
    cost(repeats)
    if check_split:
        split()


if __name__ == "__main__":
    main()
