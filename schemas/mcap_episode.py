"""Episode logs as MCAP files with ROS 2 (CDR) messages, written and read in bulk.

Every message on a channel has the same byte layout (fixed joint names, fixed array lengths), so
the six MCAP Message records of one tick have a fixed size and layout too. Writing them one by
one through the mcap library costs a few µs per message, more than the simulation of the episode
can afford (15,006 messages per 5 s episode). Instead, one template tick is built once -- the CDR
messages by a ROS 2 serialiser (rosbags), the records around them by the mcap library -- and NumPy
copies it for every tick and writes the times and numbers into the copies through a structured
dtype: a chunk's whole record stream is one array. Reading does the reverse: a chunk's records
are viewed through the same dtype, checked byte for byte against the template, and the numbers
are sliced out as columns.

For ROS 2 tools to show the arm, the file's first chunk holds the arm's URDF on
/robot_description and its links' transforms on /tf (every TF_EVERY ticks), made from the logged
joint angles the same way (one template /tf message, its stamps and rotations filled in by
NumPy). The writer is given both as a RobotDescription (the iiwa's: models/urdf.py), so the
contract needs no robot model. They add nothing the columns lack, so the reader skips that chunk
unread: logs written before it existed read as before, the scores never depend on it, and
reading needs no description.

The records around the messages (Header, Metadata, Chunk, MessageIndex, DataEnd, the summary
section and the Footer) are written with the mcap library's record classes, with the contents its
Writer would give them, so that any MCAP reader and any ROS 2 decoder reads these files. One
deliberate difference: a chunk's uncompressed_crc is 0, which the MCAP spec defines as "not
computed" (readers skip it, validate_crcs or not); its zstd frame carries zstd's own checksum of
the same bytes instead, which every zstd decoder verifies (see CHUNK_CRC).
"""

import io
import json
import threading
import zlib
from collections.abc import Iterator, Sequence
from functools import cache, lru_cache
from pathlib import Path

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel as ChannelRecord
from mcap.records import (
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import StreamReader
from mcap.summary import Summary
from mcap.writer import MCAP0_MAGIC
from pydantic import ValidationError

from gainfarm.schemas.documents import BadDocument, read_bounded
from gainfarm.schemas.episode import EpisodeMetadata
from gainfarm.schemas.episode_log import (
    CHANNELS,
    DESCRIPTION_TOPIC,
    METADATA_NAME,
    STRING,
    TF_EVERY,
    TF_MESSAGE,
    TF_TOPIC,
    EpisodeLog,
    RobotDescription,
)
from gainfarm.schemas.mcap_layout import (
    CHUNK_CRC,
    CHUNK_SIZE,
    DERIVED_IDS,
    DESCRIPTION_ID,
    FOOTER_LENGTH,
    LIBRARY,
    MAX_DEFINITION_BYTES,
    MAX_METADATA_BYTES,
    MAX_SUMMARY_BYTES,
    MESSAGE_ENCODING,
    NANOSECONDS,
    PROFILE,
    RECORD_PREFIX,
    SCHEMA_ENCODING,
    TF_ID,
    UNREADABLE,
    ZSTD_LEVEL,
    NotAnEpisodeLog,
    TickLayout,
    schema_text,
    tf_layout,
    tick_layout,
    typestore,
)
from gainfarm.schemas.wire import MAX_EPISODE_BYTES

# --- writing ----------------------------------------------------------------------------------


def episode_bytes(log: EpisodeLog, robot: RobotDescription | None) -> bytes:
    """The whole file, in the order and with the records mcap.writer.Writer would emit for it;
    `robot` draws the arm on /robot_description and /tf (None: an arm with no description to
    draw it, whose log carries neither). Its JointState messages name the joints its metadata
    names (EpisodeMetadata.joint_names). (To a file: the caller writes these bytes, whole or not
    at all: gainfarm.edges.files.write_atomically.)

    One RecordBuilder holds the whole file from the magic on, so its count is the file offset
    that indexes point at. Two deliberate differences from what the old Writer-based code wrote:
    the two channels of each message type share one Schema record, and the Metadata record comes
    right after the Header (the Writer puts it wherever its chunk buffer stands), so that a
    reader streaming the file knows what it is before the data arrives.
    """
    layout = tick_layout(log.metadata.joint_names)
    log_times = np.round(log.t * NANOSECONDS).astype(np.uint64)
    schemas, channels = _definitions()
    out = RecordBuilder()
    out.write(MCAP0_MAGIC)
    Header(profile=PROFILE, library=LIBRARY).write(out)
    metadata_index = _write_metadata(out, log.metadata)
    compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_checksum=True)
    _check_columns(log, layout)  # first: no byte is written of a malformed log
    chunk_indexes = []
    counts = {}
    # The definitions of every channel open the first chunk.
    prefix = _definition_records() if log.ticks else b""
    if log.ticks:
        counts = {channel.id: log.ticks for channel in channels[: len(CHANNELS)]}
    if log.ticks and robot is not None:
        # First the description and the transforms, so that a tool reading the file from its
        # start draws the arm before the data plays.
        content, indexes = _derived_messages(log, log_times, len(prefix), robot)
        chunk_indexes.append(_write_chunk(out, compressor, prefix + content, indexes))
        counts |= {channel_id: len(times) for channel_id, times, _ in indexes}
        prefix = b""
    for part in _chunk_parts(log.ticks, layout.size):
        content = _records(log, log_times, part, layout).view(np.uint8)
        first = len(prefix)
        if prefix:  # no description: the definitions open the first chunk of ticks
            content, prefix = np.concatenate([np.frombuffer(prefix, np.uint8), content]), b""
        tick_offsets = first + layout.size * np.arange(part.stop - part.start, dtype=np.uint64)
        indexes = [
            (channel_id, log_times[part], tick_offsets + layout.record_offset(channel.topic))
            for channel_id, channel in enumerate(CHANNELS, start=1)
        ]
        chunk_indexes.append(_write_chunk(out, compressor, content, indexes))
    DataEnd(data_section_crc=0).write(out)  # the Writer's default: no data section CRC
    statistics = Statistics(
        attachment_count=0,
        channel_count=len(channels),
        channel_message_counts=counts,
        chunk_count=len(chunk_indexes),
        message_count=sum(counts.values()),
        message_end_time=int(log_times.max(initial=0)),
        message_start_time=int(log_times.min(initial=0)),
        metadata_count=1,
        schema_count=len(schemas),
    )
    _write_summary(out, schemas, channels, statistics, chunk_indexes, [metadata_index])
    out.write(MCAP0_MAGIC)
    return out.end()


@cache
def _definitions() -> tuple[tuple[Schema, ...], tuple[ChannelRecord, ...]]:
    """One Schema per message type; one Channel per entry of CHANNELS, numbered from 1, then
    /tf and /robot_description. Each channel states the QoS a ROS 2 publisher of it would offer
    (the ros2 profile's offered_qos_profiles), so that `ros2 bag play` latches the description."""
    topics = [(channel.topic, channel.message_type, _VOLATILE) for channel in CHANNELS]
    topics += [(TF_TOPIC, TF_MESSAGE, _VOLATILE), (DESCRIPTION_TOPIC, STRING, _TRANSIENT_LOCAL)]
    schemas: dict[str, Schema] = {}
    channels = []
    for channel_id, (topic, message_type, durability) in enumerate(topics, start=1):
        if message_type not in schemas:
            schemas[message_type] = Schema(
                id=len(schemas) + 1,
                data=schema_text(message_type).encode(),
                encoding=SCHEMA_ENCODING,
                name=message_type,
            )
        channels.append(
            ChannelRecord(
                id=channel_id,
                topic=topic,
                message_encoding=MESSAGE_ENCODING,
                metadata={"offered_qos_profiles": _offered_qos(durability)},
                schema_id=schemas[message_type].id,
            )
        )
    return tuple(schemas.values()), tuple(channels)


# rmw's durability policies, as rosbag2 (Humble) writes them in offered_qos_profiles.
_TRANSIENT_LOCAL, _VOLATILE = 1, 2


def _offered_qos(durability: int) -> str:
    """One publisher's QoS profile in rosbag2's YAML: reliable, keep last 1 (history 1), and
    no deadline, lifespan or liveliness lease (0 s: the default, unbounded)."""
    never = "\n    sec: 0\n    nsec: 0"
    return (
        f"- history: 1\n  depth: 1\n  reliability: 1\n  durability: {durability}\n"
        f"  deadline:{never}\n  lifespan:{never}\n  liveliness: 1\n"
        f"  liveliness_lease_duration:{never}\n  avoid_ros_namespace_conventions: false"
    )


@cache
def _definition_records() -> bytes:
    """The Schema and Channel records that open the first chunk, in registration order, as the
    Writer puts them there: each schema just before the first channel that uses it. The same in
    every log: written once per process."""
    schemas, channels = _definitions()
    builder = RecordBuilder()
    unwritten = {schema.id: schema for schema in schemas}
    for channel in channels:
        if channel.schema_id in unwritten:
            unwritten.pop(channel.schema_id).write(builder)
        channel.write(builder)
    return builder.end()


def _write_metadata(out: RecordBuilder, metadata: EpisodeMetadata) -> MetadataIndex:
    offset = out.count
    Metadata(name=METADATA_NAME, metadata=_metadata_record(metadata)).write(out)
    return MetadataIndex(offset=offset, length=out.count - offset, name=METADATA_NAME)


def _metadata_record(metadata: EpisodeMetadata) -> dict[str, str]:
    """One key per top-level field, each a JSON value, so that MCAP tools show them readably."""
    return {key: json.dumps(value) for key, value in metadata.model_dump(mode="json").items()}


def _check_columns(log: EpisodeLog, layout: TickLayout) -> None:
    """Each column must be one row per tick of the numbers its message field holds."""
    fields = layout.dtype
    for channel in CHANNELS:
        data = fields[channel.topic]["data"]
        for field, attribute in channel.fields:
            shape = (log.ticks, *data[field].shape)
            if np.shape(getattr(log, attribute)) != shape:
                raise ValueError(
                    f"{attribute} is {np.shape(getattr(log, attribute))}, not {shape}: one row "
                    f"of {channel.topic} {field} per tick"
                )


class _Ticks(threading.local):
    """Each thread's chunk of template ticks, filled in and compressed log after log (a worker
    encodes each log on the thread that stepped it). Every log writes all the variable bytes of
    the ticks it fills, so the template's bytes stay as they are; and a log of the same ticks
    as the last (each episode of a trajectory, unless one diverged) rewrites only its numbers:
    the sequence numbers, times and stamps are the last log's. Reused, not made anew: a fresh
    2.8 MB array of a 5 s episode's ticks, its page faults, the template's copy and the times
    cost ~0.5 ms more than the numbers alone, a sixth of writing the log."""

    ticks: np.ndarray | None = None  # template ticks, as many as the longest chunk yet
    times: tuple[int, bytes] | None = None  # (first sequence, log times) the ticks carry
    layout: TickLayout | None = None  # the arm's whose template the ticks are


_TICKS = _Ticks()


def _records(log: EpisodeLog, log_times: np.ndarray, part: slice, layout: TickLayout) -> np.ndarray:
    """The Message records of the ticks `part` as one structured array: template copies,
    filled in. (Valid until this thread's next call: they are to be compressed at once.)"""
    count = part.stop - part.start
    if (
        _TICKS.ticks is None or len(_TICKS.ticks) < count or _TICKS.layout is not layout
    ):  # at most a chunk's, per thread, of the last arm's layout
        _TICKS.ticks = np.tile(layout.template, count).view(layout.dtype)
        _TICKS.times = None
        _TICKS.layout = layout
    ticks = _TICKS.ticks[:count]
    times = (part.start, log_times[part].tobytes())
    if _TICKS.times != times:
        _TICKS.times = None  # until they are all written
        _write_times(ticks, log_times[part], part.start)
        _TICKS.times = times
    for channel in CHANNELS:
        data = ticks[channel.topic]["data"]
        for field, attribute in channel.fields:
            data[field] = getattr(log, attribute)[part]
    return ticks


def _write_times(ticks: np.ndarray, log_times: np.ndarray, first: int) -> None:
    """Every channel's sequence numbers (from `first`), log and publish times and stamps."""
    stamps = np.column_stack(divmod(log_times, NANOSECONDS)).astype("<u4")
    sequences = np.arange(first, first + len(ticks), dtype="<u4")
    for channel in CHANNELS:
        records = ticks[channel.topic]
        records["sequence"] = sequences
        records["log_time"] = log_times
        records["publish_time"] = log_times
        records["data"]["stamp"] = stamps


def _derived_messages(
    log: EpisodeLog, log_times: np.ndarray, offset: int, robot: RobotDescription
) -> tuple[bytes, list[tuple[int, np.ndarray, np.ndarray]]]:
    """The /robot_description record (at the first tick) and the /tf records (every TF_EVERY
    ticks and at the last), and each channel's (id, log times, offsets from `offset` on)."""
    first = _description_record(robot.urdf, int(log_times[0]))
    ticks = np.unique(np.append(np.arange(0, log.ticks, TF_EVERY), log.ticks - 1))
    template, dtype = tf_layout(tuple(robot.frames))
    rotations = np.asarray(robot.rotations(log.q[ticks]))
    if rotations.shape != (len(ticks), len(robot.frames), 4):
        raise ValueError(
            f"the robot description's rotations are {rotations.shape}, not "
            f"{(len(ticks), len(robot.frames), 4)}: one x y z w per /tf tick and frame"
        )
    records = np.tile(template, len(ticks)).view(dtype)
    times = log_times[ticks]
    records["sequence"] = np.arange(len(ticks))
    records["log_time"] = times
    records["publish_time"] = times
    stamps = np.column_stack(divmod(times, NANOSECONDS)).astype("<u4")
    for i, quaternions in enumerate(np.moveaxis(rotations, 1, 0)):
        records["data"][f"stamp{i}"] = stamps
        records["data"][f"rotation{i}"] = quaternions
    tf_offsets = offset + len(first) + dtype.itemsize * np.arange(len(ticks), dtype=np.uint64)
    indexes = [
        (TF_ID, times, tf_offsets),
        (DESCRIPTION_ID, log_times[:1], np.array([offset], np.uint64)),
    ]
    return first + records.tobytes(), indexes


@lru_cache(maxsize=4)
def _description_record(urdf: str, log_time: int) -> bytes:
    """The /robot_description Message record: the same in every log of a robot (its first tick
    is at time 0), so serialised once per process, not once per log."""
    store = typestore()
    builder = RecordBuilder()
    Message(
        channel_id=DESCRIPTION_ID,
        log_time=log_time,
        data=bytes(store.serialize_cdr(store.types[STRING](data=urdf), STRING)),
        publish_time=log_time,
        sequence=0,
    ).write(builder)
    return builder.end()


def _chunk_parts(ticks: int, tick_size: int) -> Iterator[slice]:
    """Split the ticks into chunks of at most CHUNK_SIZE bytes of messages (at least one tick)."""
    per_chunk = max(1, CHUNK_SIZE // tick_size)
    for start in range(0, ticks, per_chunk):
        yield slice(start, min(start + per_chunk, ticks))


def _write_chunk(
    out: RecordBuilder,
    compressor: zstandard.ZstdCompressor,
    uncompressed: bytes | np.ndarray,
    indexes: list[tuple[int, np.ndarray, np.ndarray]],
) -> ChunkIndex:
    """Write one Chunk record holding the records `uncompressed`, and its MessageIndex records
    (per channel: its id, and its messages' log times and offsets in the chunk); return its
    ChunkIndex. (The records are compressed from where they lie: no copy of them is made.)"""
    start = min(int(times.min()) for _, times, _ in indexes)
    end = max(int(times.max()) for _, times, _ in indexes)
    chunk = Chunk(
        compression="zstd",
        data=compressor.compress(uncompressed),
        message_end_time=end,
        message_start_time=start,
        uncompressed_crc=CHUNK_CRC,  # zstd's frame checksum checks them instead
        uncompressed_size=memoryview(uncompressed).nbytes,
    )
    chunk_offset = out.count
    chunk.write(out)
    index = ChunkIndex(
        chunk_length=out.count - chunk_offset,
        chunk_start_offset=chunk_offset,
        compression=chunk.compression,
        compressed_size=len(chunk.data),
        message_end_time=end,
        message_index_length=0,
        message_index_offsets={},
        message_start_time=start,
        uncompressed_size=chunk.uncompressed_size,
    )
    indexes_offset = out.count
    for channel_id, log_times, offsets in indexes:
        index.message_index_offsets[channel_id] = out.count
        _write_message_index(out, channel_id, log_times, offsets)
    index.message_index_length = out.count - indexes_offset
    return index


def _write_message_index(
    out: RecordBuilder, channel_id: int, log_times: np.ndarray, offsets: np.ndarray
) -> None:
    """What mcap.records.MessageIndex.write writes, with its entries written in one piece:
    written one by one they would cost ~0.3 µs each, 3 ms per 5 s episode."""
    entries = np.empty(len(log_times), [("log_time", "<u8"), ("offset", "<u8")])
    entries["log_time"] = log_times
    entries["offset"] = offsets
    out.start_record(Opcode.MESSAGE_INDEX)
    out.write2(channel_id)
    out.write4(entries.nbytes)
    out.write(entries.tobytes())
    out.finish_record()


def _write_summary(
    out: RecordBuilder,
    schemas: Sequence[Schema],
    channels: Sequence[ChannelRecord],
    statistics: Statistics,
    chunk_indexes: list[ChunkIndex],
    metadata_indexes: list[MetadataIndex],
) -> None:
    """The summary section, summary offsets and footer, as Writer.finish writes them (including
    the empty attachment index group), with the footer's CRC over the summary section."""
    summary_start = out.count
    summary = RecordBuilder()  # offsets in it are relative to summary_start
    groups: list[tuple[Opcode, list]] = [
        (Opcode.SCHEMA, schemas),
        (Opcode.CHANNEL, channels),
        (Opcode.STATISTICS, [statistics]),
        (Opcode.CHUNK_INDEX, chunk_indexes),
        (Opcode.ATTACHMENT_INDEX, []),
        (Opcode.METADATA_INDEX, metadata_indexes),
    ]
    offsets = []
    for opcode, records in groups:
        group_start = summary.count
        for record in records:
            record.write(summary)
        offsets.append(
            SummaryOffset(opcode, summary_start + group_start, summary.count - group_start)
        )
    summary_offset_start = summary_start + summary.count
    for offset in offsets:
        offset.write(summary)
    section = summary.end()
    out.write(section)
    footer = Footer(summary_start, summary_offset_start, summary_crc=0)
    fields = RecordBuilder()
    footer.write(fields)
    # As in Writer.finish, the CRC covers the summary section and the footer up to the CRC itself.
    footer.summary_crc = zlib.crc32(fields.end()[:-4], zlib.crc32(section))
    footer.write(out)


# --- reading ----------------------------------------------------------------------------------


def read_episode(path: Path) -> EpisodeLog:
    """Read an episode log file (episode_bytes' bytes); NotAnEpisodeLog if it is not one, or
    holds more than MAX_EPISODE_BYTES (refused before it is read)."""
    try:
        content = read_bounded(Path(path), MAX_EPISODE_BYTES)
    except BadDocument as error:
        raise NotAnEpisodeLog(f"{path}: {error}") from None
    return decode_episode(content, str(path))


def check_chunks(path: Path, bound: int = MAX_EPISODE_BYTES) -> None:
    """Check, before another reader (rosbags) decompresses them, that the chunks of the MCAP
    file `path` decompress to `bound` bytes at most, all together: NotAnEpisodeLog, in one line,
    for a file larger than that, a chunk claiming more, or one whose data inflates past its
    claim (a 200 kB "bomb" that rosbags would inflate to gigabytes). Each chunk is decompressed
    here as decode_episode does, to its claim at most, and dropped."""
    where = str(path)
    try:
        with Path(path).open("rb") as stream:
            size = stream.seek(0, io.SEEK_END)
            if size > bound:
                raise NotAnEpisodeLog(f"{where}: {size} bytes, more than the {bound} read")
            stream.seek(max(0, size - len(MCAP0_MAGIC)))
            if stream.read() != MCAP0_MAGIC:
                return  # rosbags refuses a file without its end magic before reading a chunk
            stream.seek(0)
            reader = StreamReader(stream, emit_chunks=True, record_size_limit=bound)
            left = bound
            for record in reader.records:
                if isinstance(record, Chunk):
                    left -= len(_decompress(f"{where}: a chunk", record, left))
    except NotAnEpisodeLog:
        raise
    except UNREADABLE as error:
        reason = " ".join(str(error).split())[:300] or type(error).__name__
        raise NotAnEpisodeLog(f"{where}: unreadable MCAP ({reason})") from None


def decode_episode(content: bytes, source: str = "episode log") -> EpisodeLog:
    """Decode the bytes of an episode log; `source` names them in the NotAnEpisodeLog message.

    Whatever the bytes, NotAnEpisodeLog is the only error: the logs come from other machines, and
    the process reading them must outlive a hostile one. Every offset, length and size the file
    states is checked against the file and against this reader's own bounds before anything is
    read or allocated in proportion to it.
    """
    path = source
    try:
        if not content.startswith(MCAP0_MAGIC):
            raise NotAnEpisodeLog(f"{path}: not an MCAP file (no MCAP magic at its start)")
        if len(content) < 2 * len(MCAP0_MAGIC) or not content.endswith(MCAP0_MAGIC):
            raise NotAnEpisodeLog(f"{path}: truncated MCAP file (no MCAP magic at its end)")
        summary = _read_summary(path, content)
        metadata = _read_metadata(path, content, summary)
        _check_channels(path, summary)
        bound = _decompression_bound(path, metadata)
        return _assemble(path, metadata, _read_messages(path, content, summary, bound))
    except NotAnEpisodeLog:
        raise
    except UNREADABLE as error:
        reason = " ".join(str(error).split())[:300] or type(error).__name__
        raise NotAnEpisodeLog(f"{path}: not a readable MCAP file ({reason})") from None
    except Exception as error:  # anything else the bytes provoke is still not an episode log
        reason = " ".join(f"{type(error).__name__}: {error}".split())[:300]
        raise NotAnEpisodeLog(f"{path}: undecodable ({reason})") from None


def _record_span(path: str, content: bytes, offset: int, opcode: Opcode, limit: int) -> range:
    """Where the content of the `opcode` record at `offset` lies: within the file, and no longer
    than `limit`, whatever length the record states."""
    name = opcode.name.lower()
    data_end = len(content) - len(MCAP0_MAGIC)
    start = offset + RECORD_PREFIX
    if start > data_end or content[offset] != opcode:
        raise NotAnEpisodeLog(f"{path}: no {name} record at offset {offset}")
    length = int.from_bytes(content[offset + 1 : start], "little")
    if length > data_end - start:
        raise NotAnEpisodeLog(f"{path}: the {name} record at offset {offset} runs past the file")
    if length > limit:
        raise NotAnEpisodeLog(
            f"{path}: the {name} record at offset {offset} is {length} bytes, "
            f"over this reader's limit of {limit}"
        )
    return range(start, start + length)


def _record(path: str, content: bytes, offset: int, opcode: Opcode, limit: int) -> ReadDataStream:
    """The content of a small record as a stream of its own bytes, so that the lengths and map
    sizes inside it cannot make the mcap library read on into the rest of the file."""
    span = _record_span(path, content, offset, opcode, limit)
    return ReadDataStream(io.BytesIO(content[span.start : span.stop]))


def _read_summary(path: str, content: bytes) -> Summary:
    """The summary section that the footer points to. Read here, not with mcap.reader: its
    get_summary and iter_metadata decompress any Chunk record they meet (to the size the chunk
    claims) and read records from a stream over the whole file."""
    data_end = len(content) - len(MCAP0_MAGIC)
    footer_offset = data_end - RECORD_PREFIX - FOOTER_LENGTH
    if footer_offset < len(MCAP0_MAGIC):
        raise NotAnEpisodeLog(f"{path}: truncated MCAP file (too short for a footer)")
    footer = Footer.read(_record(path, content, footer_offset, Opcode.FOOTER, FOOTER_LENGTH))
    start = footer.summary_start
    if start == 0:
        raise NotAnEpisodeLog(f"{path}: MCAP file without a summary section")
    if not len(MCAP0_MAGIC) <= start <= footer_offset:
        raise NotAnEpisodeLog(f"{path}: its footer points outside the file for its summary")
    if footer_offset - start > MAX_SUMMARY_BYTES:
        raise NotAnEpisodeLog(
            f"{path}: a summary section of {footer_offset - start} bytes, over this reader's "
            f"limit of {MAX_SUMMARY_BYTES}"
        )
    # As in Writer.finish: the CRC covers the summary section and the footer up to the CRC.
    if footer.summary_crc not in (0, zlib.crc32(content[start : data_end - 4])):
        raise NotAnEpisodeLog(f"{path}: the summary section is corrupt (CRC mismatch)")
    summary = Summary()
    stream = io.BytesIO(content[start:])  # the summary, the footer and the closing magic
    reader = StreamReader(
        stream, skip_magic=True, emit_chunks=True, record_size_limit=MAX_SUMMARY_BYTES
    )
    for record in reader.records:  # up to and including the footer
        if isinstance(record, Schema):
            summary.schemas[record.id] = record
        elif isinstance(record, ChannelRecord):
            summary.channels[record.id] = record
        elif isinstance(record, ChunkIndex):
            summary.chunk_indexes.append(record)
        elif isinstance(record, MetadataIndex):
            summary.metadata_indexes.append(record)
        elif isinstance(record, Statistics):
            summary.statistics = record
    return summary


def _read_metadata(path: str, content: bytes, summary: Summary) -> EpisodeMetadata:
    for index in summary.metadata_indexes:
        if index.name != METADATA_NAME:
            continue
        stream = _record(path, content, index.offset, Opcode.METADATA, MAX_METADATA_BYTES)
        record = Metadata.read(stream)
        if record.name != METADATA_NAME:
            continue
        try:
            fields = {key: json.loads(value) for key, value in record.metadata.items()}
            return EpisodeMetadata.model_validate(fields)
        except (ValueError, ValidationError, RecursionError) as error:  # JSON too deep too
            reason = " ".join(str(error).split())[:300]
            raise NotAnEpisodeLog(f"{path}: invalid episode metadata: {reason}") from None
    raise NotAnEpisodeLog(f"{path}: no {METADATA_NAME!r} metadata record: not an episode log")


def _check_channels(path: str, summary: Summary) -> None:
    """The channels must be CHANNELS, with the ids episode_bytes gives them."""
    for channel_id, channel in enumerate(CHANNELS, start=1):
        record = summary.channels.get(channel_id)
        schema = summary.schemas.get(record.schema_id) if record else None
        if (
            record is None
            or schema is None
            or record.topic != channel.topic
            or record.message_encoding != MESSAGE_ENCODING
            or schema.name != channel.message_type
        ):
            raise NotAnEpisodeLog(
                f"{path}: channel {channel_id} is not {channel.topic} "
                f"({MESSAGE_ENCODING} {channel.message_type}): not an episode log"
            )


def _decompression_bound(path: str, metadata: EpisodeMetadata) -> int:
    """The most bytes the chunks of this log may decompress to, all together: the Message records
    of the ticks its metadata says ran, and room for the records before them. It is this reader's
    bound, not the sender's: the ticks are at most those of the episode's trajectory, whose
    duration the spec caps (MAX_DURATION), and the whole is capped by MAX_EPISODE_BYTES."""
    ticks, planned = metadata.ticks_run, metadata.spec.trajectory.ticks
    if ticks > planned:
        raise NotAnEpisodeLog(f"{path}: {ticks} ticks run, more than the {planned} of its path")
    size = tick_layout(metadata.joint_names).size
    return min(ticks * size + MAX_DEFINITION_BYTES, MAX_EPISODE_BYTES)


def _read_messages(path: str, content: bytes, summary: Summary, bound: int) -> bytes:
    """The Message records of all chunks in file order, joined; the chunks decompress to `bound`
    bytes at most, all together. (The decompressed chunks are freed on return, before the
    columns are sliced out.)"""
    parts = []
    for index in sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset):
        channels = index.message_index_offsets
        if channels and DERIVED_IDS.issuperset(channels):
            continue  # /tf and /robot_description: made from the columns for other tools
        records = _chunk_records(path, content, index.chunk_start_offset, bound)
        bound -= len(records)
        parts.append(_messages(records))
    return b"".join(parts)


def _chunk_records(path: str, content: bytes, offset: int, bound: int) -> bytes:
    """The records of the chunk at `offset`, decompressed (to `bound` bytes at most) and
    CRC-checked."""
    span = _record_span(path, content, offset, Opcode.CHUNK, len(content))
    # Not _record: a stream over the whole content shares its buffer, and the chunk's data is
    # copied once, as it is read; the only sizes inside it are the compression's and the data's.
    stream = io.BytesIO(content)
    stream.seek(span.start)
    chunk = Chunk.read(ReadDataStream(stream))
    if stream.tell() > span.stop:
        raise NotAnEpisodeLog(f"{path}: the chunk at offset {offset} runs past its record")
    data = _decompress(f"{path}: the chunk at offset {offset}", chunk, bound)
    if chunk.uncompressed_crc not in (0, zlib.crc32(data)):
        raise NotAnEpisodeLog(f"{path}: chunk at offset {offset} is corrupt (CRC mismatch)")
    return data


def _decompress(where: str, chunk: Chunk, bound: int) -> bytes:
    """A chunk's records, decompressed to `bound` bytes at most. The chunk's uncompressed_size is
    the sender's claim: it is checked against the bound before anything is allocated, and the
    output is never allowed to grow past it, whatever the compressed data says."""
    size = chunk.uncompressed_size
    if size > bound:
        raise NotAnEpisodeLog(
            f"{where} claims {size} bytes uncompressed, more than the {bound} this log's "
            "messages may take"
        )
    if chunk.compression == "zstd":
        # One byte more than claimed tells a longer output from an exact one. Not
        # ZstdDecompressor.decompress: it allocates the content size the frame header states,
        # whatever its max_output_size; a stream reader allocates what it is asked to read, and
        # is as fast.
        with zstandard.ZstdDecompressor().stream_reader(chunk.data) as reader:
            data = reader.read(size + 1)
    elif chunk.compression == "lz4":
        import lz4.frame  # optional extra: lz4, as in the mcap library (we write zstd)

        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=size + 1)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise NotAnEpisodeLog(f"{where} has an unsupported compression {chunk.compression!r}")
    if len(data) != size:
        got = "more" if len(data) > size else str(len(data))
        raise NotAnEpisodeLog(f"{where} decompresses to {got} bytes, not the {size} it claims")
    return data


def _messages(records: bytes) -> memoryview:
    """A chunk's Message records, without the Schema and Channel records that may precede them
    (a view, not a copy: the chunks are joined next)."""
    position = 0
    while position < len(records) and records[position] != Opcode.MESSAGE:
        length = int.from_bytes(records[position + 1 : position + RECORD_PREFIX], "little")
        position += RECORD_PREFIX + length
    return memoryview(records)[position:]


def _assemble(path: str, metadata: EpisodeMetadata, messages: bytes) -> EpisodeLog:
    """View the Message records as ticks, check them against the template of the arm its
    metadata names, slice out columns."""
    layout = tick_layout(metadata.joint_names)
    ticks = metadata.ticks_run
    if len(messages) != ticks * layout.size:
        raise NotAnEpisodeLog(
            f"{path}: {len(messages)} bytes of messages, not the {ticks} ticks of "
            f"{layout.size} bytes its metadata promises: not a complete episode log"
        )
    word = layout.word
    words = np.frombuffer(messages, word).reshape(ticks, layout.size // word.itemsize)
    expected = (layout.template & layout.constant).view(word)
    if ((words & layout.constant.view(word)) != expected).any():
        raise NotAnEpisodeLog(
            f"{path}: the messages do not have the episode log layout (record headers, channel "
            "ids, frame ids or joint names differ): not an episode log"
        )
    records = np.frombuffer(messages, layout.dtype)
    log_times = records[CHANNELS[0].topic]["log_time"]
    for channel in CHANNELS:
        channel_records = records[channel.topic]
        if not (
            np.array_equal(channel_records["log_time"], log_times)
            and np.array_equal(channel_records["publish_time"], log_times)
            and np.array_equal(channel_records["sequence"], np.arange(ticks))
        ):
            raise NotAnEpisodeLog(f"{path}: {channel.topic} messages are not one per tick")
    columns = {
        attribute: records[channel.topic]["data"][field].copy()
        for channel in CHANNELS
        for field, attribute in channel.fields
    }
    return EpisodeLog(metadata=metadata, t=log_times.astype(np.int64) / NANOSECONDS, **columns)
