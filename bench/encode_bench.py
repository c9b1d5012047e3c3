"""Cost of an episode's MCAP log against the episode's own, and where the log's cost goes.

    python bench/encode_bench.py [--quick] [--repeats 30] [--duration 5] [--batch 8]

The target (issue 45): writing the log (`episode_bytes`) costs at most a tenth of its episode.
Per repeat, interleaved so that every case meets the same load: a realistic episode alone
(`run_episode`), episodes stepped together in a batch (`simulate_all`, per episode: how a worker
runs them), the log of one of them, and the zstd compression of its ticks' chunk alone (the
floor under the log's cost: the rest is NumPy filling the template ticks, the /tf transforms and
the records around them). Process CPU time, the fastest repeat (the cost of the work itself;
the shared machine only ever adds), the median beside it.
"""

import io
import statistics
import time
from collections.abc import Callable

import click
import zstandard
from common import print_table
from episode_bench import candidates, prepared
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk

from gainfarm.models.urdf import description
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.gains import DEFAULT_GAINS
from gainfarm.schemas.mcap_episode import ZSTD_LEVEL, episode_bytes
from gainfarm.schemas.robot import REALISTIC_PLANT
from gainfarm.worker.episode import run_episode, simulate_all
from gainfarm.worker.reference import reference_for

TARGET = 0.10  # the log's cost, at most, as a share of its episode's


def ticks_chunk(content: bytes) -> Callable[[], bytes]:
    """Compressing the largest chunk's records (the ticks') as episode_bytes does, alone."""
    summary = make_reader(io.BytesIO(content)).get_summary()
    index = max(summary.chunk_indexes, key=lambda index: index.uncompressed_size)
    stream = io.BytesIO(content[index.chunk_start_offset + 1 + 8 :])  # opcode, record length
    records = zstandard.decompress(Chunk.read(ReadDataStream(stream)).data)
    compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_checksum=True)
    return lambda: compressor.compress(records)


@click.command(help=__doc__.split("\n\n")[0])
@click.option("--quick", is_flag=True, help="a CI-sized run: 1 s episodes, batch of 2, 3 repeats")
@click.option("--repeats", type=click.IntRange(min=1), default=30, show_default=True)
@click.option(
    "--duration",
    type=click.FloatRange(min=0, min_open=True),
    default=5.0,
    show_default=True,
    help="s per episode",
)
@click.option("--batch", type=click.IntRange(min=1), default=8, show_default=True)
def main(quick: bool, repeats: int, duration: float, batch: int) -> None:
    if quick:
        repeats, duration, batch = 3, 1.0, 2
    kind = "fourier" if duration < 3 else "spiral"  # a Cartesian path needs some 3 s
    trajectory = TrajectorySpec(kind=kind, duration=duration)
    spec = EpisodeSpec(gains=DEFAULT_GAINS, trajectory=trajectory, plant=REALISTIC_PLANT)
    reference_for(trajectory)  # the IK runs once per trajectory: not per-episode cost
    episodes = prepared(candidates(spec, batch))
    log = run_episode(spec)
    robot = description()
    logged = episode_bytes(log, robot)

    cases: dict[str, tuple[Callable[[], object], int]] = {  # what, episodes it runs
        "realistic episode": (lambda: run_episode(spec), 1),
        f"episodes, batch of {batch}": (lambda: simulate_all(episodes), batch),
        "its MCAP log (episode_bytes)": (lambda: episode_bytes(log, robot), 1),
        "  of which zstd of the ticks' chunk": (ticks_chunk(logged), 1),
    }
    times: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, (case, count) in cases.items():
            start = time.process_time()
            case()
            times[name].append((time.process_time() - start) / count)

    fastest = {name: min(values) for name, values in times.items()}
    median = {name: statistics.median(values) for name, values in times.items()}
    print(
        f"{duration:g} s {kind} episode, {trajectory.ticks} ticks, realistic plant; CPU time, "
        f"the fastest of {repeats} interleaved repeats (median beside)\n"
    )
    print_table(
        ("case", "ms", "median ms"),
        "lrr",
        ((name, f"{t * 1000:.2f}", f"{median[name] * 1000:.2f}") for name, t in fastest.items()),
    )
    encode = fastest["its MCAP log (episode_bytes)"]
    print()
    for name in ("realistic episode", f"episodes, batch of {batch}"):
        print(f"log/episode ({name}): {encode / fastest[name]:.3f} (target <= {TARGET:g})")
    print(f"bytes per log: {len(logged):,}")


if __name__ == "__main__":
    main()
