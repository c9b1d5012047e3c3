"""Hostile bytes: decoding refuses them with a one-line reason, quickly and in little memory.

Every listener catches BadMessage (schemas.wire) or NotAnEpisodeLog (schemas.mcap_episode) and
goes on serving; anything else a sender can make a decoder raise (RecursionError, MemoryError, a
decompressor's own error) kills it. So whatever the bytes, those two are the only errors, and
what a file claims about itself (a chunk's uncompressed size, a zstd or lz4 frame's content
size, a record's length) never decides how much the reader allocates.
"""

import io
import json
import resource
import struct
import time
import tracemalloc
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import SimpleNamespace

import lz4.frame
import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.records import Chunk

from gainfarm.models.urdf import description
from gainfarm.schemas import mcap_episode
from gainfarm.schemas.episode_log import EpisodeLog
from gainfarm.schemas.mcap_episode import NotAnEpisodeLog, decode_episode, episode_bytes
from gainfarm.schemas.wire import (
    MAX_MESSAGE_BYTES,
    MESSAGES,
    PROTOCOL_VERSION,
    BadMessage,
    Job,
    LeaseRequest,
    Result,
    decode,
    decode_submission,
)

V = PROTOCOL_VERSION
MAGIC = b"\x89MCAP0\r\n"
BOMB_BYTES = 4 << 30  # what the zstd bombs inflate to
LZ4_BOMB_BYTES = 512 << 20  # the lz4 bomb: lz4 compresses at most ~255:1, so it is built
MIB = 1 << 20

# --- helpers -----------------------------------------------------------------------------------


def refused(error: type[Exception], decoder: Callable[[], object]) -> str:
    """The reason `decoder()` gives for refusing with `error`: there is one, on one line."""
    with pytest.raises(error) as caught:
        decoder()
    reason = str(caught.value)
    assert reason.strip() and "\n" not in reason
    return reason


def peak_rss() -> int:
    """The process's peak resident memory so far, in bytes (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


@contextmanager
def frugal(seconds: float = 2.0, allocated: int = 64 * MIB) -> Iterator[dict[str, float]]:
    """The block must finish within `seconds`, with at most `allocated` bytes of Python objects
    alive at its peak (tracemalloc sees every bytes object and array, whoever allocates it) and
    without raising the process's peak RSS by more than that plus 256 MiB (native allocations,
    such as a decompressor's own buffers). Yields the measurements."""
    measured: dict[str, float] = {}
    rss_before = peak_rss()
    tracemalloc.start()
    start = time.perf_counter()
    try:
        yield measured
    finally:
        measured["seconds"] = time.perf_counter() - start
        measured["allocated"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        measured["rss_growth"] = peak_rss() - rss_before
    assert measured["seconds"] < seconds, measured
    assert measured["allocated"] < allocated, measured
    assert measured["rss_growth"] < allocated + 256 * MIB, measured


def decodes_or_refuses(kind: type, raw: bytes | None) -> None:
    """decode gives a `kind` message or a one-line BadMessage, and nothing else."""
    try:
        message = decode(kind, raw)
    except BadMessage as error:
        assert str(error).strip() and "\n" not in str(error)
    else:
        assert isinstance(message, kind)


def episode_or_refusal(content: bytes) -> None:
    """decode_episode gives an EpisodeLog or a one-line NotAnEpisodeLog, and nothing else."""
    try:
        log = decode_episode(content)
    except NotAnEpisodeLog as error:
        assert str(error).strip() and "\n" not in str(error)
    else:
        assert isinstance(log, EpisodeLog)


def zstd_bomb(size: int, states_size: bool) -> bytes:
    """A zstd frame of RLE blocks of zero bytes inflating to `size` (a multiple of 128 KiB): 4
    bytes per 128 KiB block, so 4 GiB take 131 kB. With `states_size` its header states the
    size (ZstdDecompressor.decompress then allocates it all); without, it is unknown."""
    block = 128 * 1024  # the largest block a frame may have
    descriptor = 0xC0 if states_size else 0x00  # an 8-byte content size field, or none
    window = 7 << 3  # 2^(10 + 7) bytes: one block
    header = struct.pack("<IBB", 0xFD2FB528, descriptor, window)
    if states_size:
        header += struct.pack("<Q", size)
    rle = ((block << 3) | 0b010).to_bytes(3, "little") + b"\0"  # block type 1 (RLE), not last
    last = ((block << 3) | 0b011).to_bytes(3, "little") + b"\0"
    return header + rle * (size // block - 1) + last


def lz4_bomb(size: int) -> bytes:
    """An lz4 frame of `size` zero bytes, its header stating the size; compressed a MiB at a
    time, so that building it takes no more memory than that."""
    compressor = lz4.frame.LZ4FrameCompressor()
    zeros = bytes(MIB)
    parts = [compressor.begin(source_size=size)]
    parts += [compressor.compress(zeros) for _ in range(size // MIB)]
    return b"".join([*parts, compressor.flush()])


def written(log: EpisodeLog, compress: Callable[[bytes], bytes], **claims: object) -> bytes:
    """What episode_bytes makes of `log`, with each chunk's records compressed by `compress`
    and the chunk's stated fields replaced by `claims` (compression, uncompressed_size): a valid
    MCAP file, its offsets, indexes and summary CRC as the writer makes them."""

    class Compressor:
        def compress(self, data: bytes) -> bytes:
            return compress(data)

    def chunk(**fields: object) -> Chunk:
        return Chunk(**{**fields, **claims})

    with pytest.MonkeyPatch.context() as patch:
        fake = SimpleNamespace(ZstdCompressor=lambda level, **options: Compressor())
        patch.setattr(mcap_episode, "zstandard", fake)
        patch.setattr(mcap_episode, "Chunk", chunk)
        return episode_bytes(log, description())


def with_metadata(log: EpisodeLog, **values: str) -> bytes:
    """What episode_bytes makes of `log`, with these metadata values (JSON text) instead."""
    original = mcap_episode._metadata_record
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(mcap_episode, "_metadata_record", lambda m: {**original(m), **values})
        return episode_bytes(log, description())


def chunk_offsets(content: bytes) -> list[int]:
    """Where the chunks of an honest file's ticks start (the mcap reader is safe on these): not
    the first chunk, /tf's and /robot_description's, which the episode reader skips."""
    summary = make_reader(io.BytesIO(content)).get_summary()
    return sorted(
        index.chunk_start_offset
        for index in summary.chunk_indexes
        if 1 in index.message_index_offsets  # /joint_states
    )


def summary_start(content: bytes) -> int:
    footer = len(content) - len(MAGIC) - (1 + 8 + 20)
    return struct.unpack_from("<Q", content, footer + 1 + 8)[0]


def with_summary_crc(content: bytearray) -> bytes:
    """`content` with its footer's CRC made right again, so that a reader gets past it."""
    end = len(content) - len(MAGIC)
    struct.pack_into("<I", content, end - 4, zlib.crc32(content[summary_start(content) : end - 4]))
    return bytes(content)


@pytest.fixture(scope="module")
def honest(tracking_log: EpisodeLog) -> bytes:
    """A real episode log (3 s: its ticks in one chunk, after the chunk of /tf and
    /robot_description), which decodes: the baseline every attack alters."""
    content = episode_bytes(tracking_log, description())
    assert decode_episode(content).ticks == tracking_log.ticks
    return content


# --- messages ----------------------------------------------------------------------------------


def test_the_deep_array_attachment_is_a_bad_result() -> None:
    reason = refused(BadMessage, lambda: decode(Result, b"[" * 100_000))
    assert reason.startswith("Result: not JSON")


@pytest.mark.parametrize("depth", [1, 100, 250, 1_000, 5_000, 100_000])
@pytest.mark.parametrize(
    "nest",
    [
        lambda n: b"[" * n,
        lambda n: b"[" * n + b"]" * n,
        lambda n: b'{"a":' * n,
        lambda n: b'{"a":' * n + b"1" + b"}" * n,
        lambda n: b'{"protocol": %d, "worker": ' % V + b"[" * n + b"]" * n + b"}",
        lambda n: b'{"protocol": %d, "x": ' % V + b'{"a":' * n + b"0" + b"}" * n + b"}",
        lambda n: b'{"protocol": ' + b"[" * n + b"]" * n + b', "worker": "w"}',
    ],
    ids=["open", "closed", "objects", "closed-objects", "in-a-field", "in-extra", "protocol"],
)
def test_nesting_of_any_depth_is_a_bad_message(nest: Callable[[int], bytes], depth: int) -> None:
    raw = nest(depth)
    for kind in MESSAGES:
        refused(BadMessage, lambda kind=kind: decode(kind, raw))
    refused(BadMessage, lambda: decode_submission(raw))


def test_nesting_inside_a_job_rejects_the_job_or_the_submission() -> None:
    deep = b"[" * 150 + b"]" * 150  # within the parser's depth limit: a bad job, not a bad message
    raw = b'{"protocol": %d, "study": "s", "jobs": [%s, {"job_id": "j"}]}' % (V, deep)
    study, jobs, rejected = decode_submission(raw)
    assert (study, jobs, [r.job_id for r in rejected]) == ("s", [], ["jobs[0]", "j"])
    deeper = b"[" * 100_000
    raw = b'{"protocol": %d, "study": "s", "jobs": [%s]}' % (V, deeper)
    assert "not JSON" in refused(BadMessage, lambda: decode_submission(raw))


@pytest.mark.parametrize(
    ("raw", "reason"),
    [
        (b"\xff", "not UTF-8"),
        (b'{"protocol": %d, "worker": "\xff"}' % V, "not UTF-8"),
        (b'{"protocol": %d, "worker": "\xed\xa0\x80"}' % V, "not UTF-8"),  # a UTF-8 surrogate
        (LeaseRequest(worker="w").to_bytes().decode().encode("utf-16"), "not UTF-8"),
        (LeaseRequest(worker="w").to_bytes().decode().encode("utf-32"), "not UTF-8"),
        (b"\xef\xbb\xbf" + LeaseRequest(worker="w").to_bytes(), "not JSON"),  # a BOM
        (b'{"protocol": %d, "worker": "\\ud800"}' % V, "not JSON"),  # a lone surrogate escape
    ],
    ids=["byte", "in-a-string", "surrogate", "utf-16", "utf-32", "bom", "escaped-surrogate"],
)
def test_anything_but_utf8_json_is_a_bad_message(raw: bytes, reason: str) -> None:
    for kind in MESSAGES:
        assert reason in refused(BadMessage, lambda kind=kind: decode(kind, raw))
    refused(BadMessage, lambda: decode_submission(raw))


@pytest.mark.parametrize(
    "number",
    [
        b"1" * 4_300,  # as many digits as Python converts
        b"1" * 4_301,
        b"9" * 100_000,
        b"-" + b"9" * 100_000,
        b"1e999999",
        b"-1e999999",
        b"0." + b"0" * 100_000 + b"1",
        b"NaN",
        b"Infinity",
    ],
    ids=lambda number: f"{number[:12].decode()}..({len(number)})",
)
def test_huge_numbers_are_bad_messages(number: bytes) -> None:
    for raw in (
        b'{"protocol": %s, "worker": "w"}' % number,
        b'{"protocol": %d, "worker": %s}' % (V, number),
        b'{"protocol": %d, "worker": "w", "x": %s}' % (V, number),
        number,
    ):
        for kind in MESSAGES:
            reason = refused(BadMessage, lambda raw=raw, kind=kind: decode(kind, raw))
            assert len(reason) < 500  # the reason quotes no 100,000-digit number
        refused(BadMessage, lambda raw=raw: decode_submission(raw))


@pytest.mark.parametrize("size", [0, 1, 2, 7, 64, 1_000, 65_536, MIB, MAX_MESSAGE_BYTES])
def test_random_bytes_of_any_size_are_bad_messages(size: int) -> None:
    raw = np.random.default_rng(size).bytes(size)
    for kind in MESSAGES:
        refused(BadMessage, lambda kind=kind: decode(kind, raw))
    refused(BadMessage, lambda: decode_submission(raw))
    too_big = raw + b" " * (MAX_MESSAGE_BYTES + 1 - size)
    assert "over the limit" in refused(BadMessage, lambda: decode(LeaseRequest, too_big))


@settings(max_examples=300, deadline=None)
@given(kind=st.sampled_from(MESSAGES), raw=st.binary(max_size=4_096))
def test_any_bytes_decode_to_a_message_or_a_bad_message(kind: type, raw: bytes) -> None:
    decodes_or_refuses(kind, raw)


JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner),
    max_leaves=30,
)


@settings(max_examples=300, deadline=None)
@given(
    kind=st.sampled_from(MESSAGES),
    fields=st.dictionaries(st.text(max_size=12), JSON, max_size=6),
    version=st.sampled_from([V, V - 1, None]),
    cut=st.integers(min_value=0),
)
@pytest.mark.slow
def test_any_json_decodes_to_a_message_or_a_bad_message(
    kind: type, fields: dict, version: int | None, cut: int
) -> None:
    raw = json.dumps({**fields, "protocol": version} if version else fields).encode()
    decodes_or_refuses(kind, raw)
    decodes_or_refuses(kind, raw[: cut % (len(raw) + 1)])  # and any prefix of it


@settings(max_examples=300, deadline=None)
@given(
    raw=st.binary(max_size=4_096)
    | st.builds(
        lambda jobs: json.dumps({"protocol": V, "study": "s", "jobs": jobs}).encode(),
        st.lists(JSON, max_size=5),
    )
)
@pytest.mark.slow
def test_any_submission_is_judged_or_refused(raw: bytes) -> None:
    try:
        study, jobs, rejected = decode_submission(raw)
    except BadMessage as error:
        assert "\n" not in str(error)
    else:
        assert study == "s"  # random bytes are never a submission; the JSON ones name "s"
        assert all(isinstance(job, Job) for job in jobs)
        assert all("\n" not in rejection.reason for rejection in rejected)


# --- episode logs ------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(raw=st.binary(max_size=8_192))
def test_random_bytes_are_not_an_episode_log(raw: bytes) -> None:
    refused(NotAnEpisodeLog, lambda: decode_episode(raw))
    refused(NotAnEpisodeLog, lambda: decode_episode(MAGIC + raw + MAGIC))


def test_every_truncation_is_not_an_episode_log(honest: bytes) -> None:
    for cut in [*range(0, len(honest), 499), *range(len(honest) - 200, len(honest))]:
        refused(NotAnEpisodeLog, lambda cut=cut: decode_episode(honest[:cut]))
        if cut < len(honest) - len(MAGIC):  # the same, its closing magic put back
            refused(NotAnEpisodeLog, lambda cut=cut: decode_episode(honest[:cut] + MAGIC))
            # and a piece cut out of its middle
            rest = honest[cut + 1_000 :] or MAGIC
            refused(NotAnEpisodeLog, lambda cut=cut, rest=rest: decode_episode(honest[:cut] + rest))


@settings(max_examples=300, deadline=None)
@given(data=st.data())
@pytest.mark.slow
def test_altered_records_are_refused_or_harmless(honest: bytes, data: st.DataObject) -> None:
    """Overwrite a few bytes where the records are read (the header and metadata at the start,
    the ticks' chunk header; the summary and footer at the end) with anything, including huge
    offsets and lengths, then fix the summary CRC so that the altered summary is read too."""
    content = bytearray(honest)
    head, tail = range(0, 1_200), range(summary_start(honest) - 4_000, len(honest) - len(MAGIC))
    chunk = range(chunk_offsets(honest)[0], chunk_offsets(honest)[0] + 200)
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.sampled_from(head) | st.sampled_from(chunk) | st.sampled_from(tail))
        value = data.draw(
            st.binary(min_size=1, max_size=8)
            | st.integers(0, 2**64 - 1).map(lambda n: n.to_bytes(8, "little"))
            | st.sampled_from([b"\xff" * 4, b"\xff" * 8, (1 << 40).to_bytes(8, "little")])
        )
        content[at : at + len(value)] = value
    content = content[: len(honest)]
    episode_or_refusal(with_summary_crc(content))
    episode_or_refusal(bytes(content))


def test_bad_crcs_magics_and_lengths_are_refused_with_their_reason(honest: bytes) -> None:
    def altered(at: int, value: bytes, fix_crc: bool = True) -> bytes:
        content = bytearray(honest)
        content[at : at + len(value)] = value
        return with_summary_crc(content) if fix_crc else bytes(content)

    chunk = chunk_offsets(honest)[0]
    summary = summary_start(honest)
    footer = len(honest) - len(MAGIC) - (1 + 8 + 20)
    huge = (2**63).to_bytes(8, "little")
    cases = {
        "CRC mismatch": altered(chunk + 9 + 24, b"\x01\x02\x03\x04"),  # the chunk's CRC
        "summary section is corrupt": altered(summary + 20, b"\xff", fix_crc=False),
        "no MCAP magic at its start": altered(0, b"\x89MCAP1"),
        "no MCAP magic at its end": altered(len(honest) - 3, b"!"),
        "the chunk record at offset": altered(chunk + 1, huge),  # its record length
        "the footer record at offset": altered(footer + 1, huge),
        "points outside the file": altered(footer + 9, huge),  # summary_start
        "no footer record": altered(footer, b"\x01"),
    }
    for reason, content in cases.items():
        assert reason in refused(NotAnEpisodeLog, lambda content=content: decode_episode(content))


def test_a_corrupted_number_is_refused_by_zstds_checksum(
    honest: bytes, tracking_log: EpisodeLog
) -> None:
    """The chunks state no CRC (0: not computed); a number altered in a chunk's compressed
    data, where nothing else would notice (the numbers are zstd's raw literals, and any value
    fits the template), is refused by the zstd frame's checksum, here and by the mcap library's
    reader."""
    number = tracking_log.q[len(tracking_log.q) // 2, 3].tobytes()
    at = honest.index(number)  # stored as it is: a literal
    assert honest.count(number) == 1 and at > chunk_offsets(honest)[0]
    content = bytearray(honest)
    content[at] ^= 0x01
    reason = refused(NotAnEpisodeLog, lambda: decode_episode(bytes(content)))
    assert "checksum" in reason
    with pytest.raises(zstandard.ZstdError, match="checksum"):
        for _ in make_reader(io.BytesIO(bytes(content)), validate_crcs=True).iter_messages():
            pass


def test_a_chunk_claiming_2_40_bytes_is_refused_before_decompressing(
    honest: bytes, tracking_log: EpisodeLog
) -> None:
    # The real log, its chunk's uncompressed_size (after the two times) rewritten: it has no
    # CRC of its own, and the CRC of the data is only checked after decompressing.
    rewritten = bytearray(honest)
    struct.pack_into("<Q", rewritten, chunk_offsets(honest)[0] + 9 + 16, 2**40)
    # And a file made so: the claim in the chunk index too, and a frame that does not state its
    # size, which ZstdDecompressor.decompress would answer by allocating all 2^40 bytes.
    unsized = zstandard.ZstdCompressor(write_content_size=False).compress
    made = written(tracking_log, unsized, uncompressed_size=2**40)
    for content in (bytes(rewritten), made):
        with frugal(seconds=0.5, allocated=16 * MIB):
            reason = refused(NotAnEpisodeLog, lambda content=content: decode_episode(content))
        assert "claims 1099511627776 bytes uncompressed" in reason


def test_the_zstd_bombs_are_real() -> None:
    """131 kB of zstd that really inflate to 4 GiB (streamed, a MiB at a time)."""
    for states_size in (True, False):
        bomb = zstd_bomb(BOMB_BYTES, states_size)
        assert len(bomb) < 132_000
        chunks = zstandard.ZstdDecompressor().read_to_iter(bomb, write_size=MIB)
        assert sum(len(chunk) for chunk in chunks) == BOMB_BYTES
    assert zstandard.frame_content_size(zstd_bomb(BOMB_BYTES, True)) == BOMB_BYTES


@pytest.mark.parametrize("states_size", [True, False], ids=["size-in-header", "size-unknown"])
def test_a_zstd_bomb_is_refused_in_little_memory(tracking_log: EpisodeLog, states_size: bool):
    bomb = zstd_bomb(BOMB_BYTES, states_size)
    # The chunk claims the honest size and CRC of its records; its data inflates to 4 GiB.
    content = written(tracking_log, lambda records: bomb)
    with frugal(allocated=16 * MIB):  # the honest chunk is 0.7 MB; the bomb 4 GiB
        reason = refused(NotAnEpisodeLog, lambda: decode_episode(content))
    assert "decompresses to more bytes" in reason
    # Claiming the bomb's true size is no better: over this reader's bound, so never inflated.
    content = written(tracking_log, lambda records: bomb, uncompressed_size=BOMB_BYTES)
    with frugal(seconds=0.5, allocated=16 * MIB):
        reason = refused(NotAnEpisodeLog, lambda: decode_episode(content))
    assert f"claims {BOMB_BYTES} bytes uncompressed" in reason


def test_an_lz4_bomb_is_refused_in_little_memory(tracking_log: EpisodeLog) -> None:
    bomb = lz4_bomb(LZ4_BOMB_BYTES)
    assert len(bomb) < 3 * MIB
    assert lz4.frame.get_frame_info(bomb)["content_size"] == LZ4_BOMB_BYTES
    content = written(tracking_log, lambda records: bomb, compression="lz4")
    with frugal(allocated=16 * MIB):
        reason = refused(NotAnEpisodeLog, lambda: decode_episode(content))
    assert "decompresses to more bytes" in reason


@pytest.mark.parametrize(
    ("compression", "compress"),
    [
        ("zstd", zstandard.ZstdCompressor(write_content_size=False).compress),
        ("zstd", zstandard.ZstdCompressor(level=19).compress),
        ("lz4", lz4.frame.compress),
        ("", bytes),
    ],
    ids=["zstd-size-unknown", "zstd-19", "lz4", "uncompressed"],
)
def test_honest_chunks_of_every_compression_still_decode(
    tracking_log: EpisodeLog, compression: str, compress: Callable[[bytes], bytes]
) -> None:
    """The bounds refuse bombs, not honest logs that other MCAP writers might make."""
    back = decode_episode(written(tracking_log, compress, compression=compression))
    np.testing.assert_array_equal(back.q, tracking_log.q)
    assert back.metadata == tracking_log.metadata


def test_a_chunk_indexed_a_thousand_times_is_decompressed_within_the_bound(
    tracking_log: EpisodeLog,
) -> None:
    # Each decompression is within the bound; together they would take 0.7 GB.
    write_summary = mcap_episode._write_summary
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(
            mcap_episode,
            "_write_summary",
            lambda out, schemas, channels, statistics, chunks, metadata: write_summary(
                out, schemas, channels, statistics, chunks * 1_000, metadata
            ),
        )
        content = episode_bytes(tracking_log, description())
    with frugal(allocated=16 * MIB):
        reason = refused(NotAnEpisodeLog, lambda: decode_episode(content))
    assert "bytes uncompressed, more than the" in reason


@pytest.mark.parametrize(
    ("values", "reason"),
    [
        ({"spec": "[" * 100_000}, "invalid episode metadata"),
        ({"spec": '{"a":' * 100_000}, "invalid episode metadata"),
        ({"ticks_run": "1" * 5_000}, "invalid episode metadata"),
        ({"ticks_run": "1000000000"}, "1000000000 ticks run, more than the"),
    ],
    ids=["deep-array", "deep-object", "digits", "ticks"],
)
def test_hostile_metadata_is_refused(tracking_log: EpisodeLog, values: dict, reason: str) -> None:
    content = with_metadata(tracking_log, **values)
    with frugal(allocated=16 * MIB):
        assert reason in refused(NotAnEpisodeLog, lambda: decode_episode(content))
