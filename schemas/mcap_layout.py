"""The episode log's fixed byte layout, shared by its writer and its reader
(schemas/mcap_episode.py): the MCAP and ROS 2 constants, the records' dtypes, the template tick and
the /tf message's layout, built once. Why the layout is fixed: mcap_episode.py's docstring."""

import struct
from dataclasses import dataclass
from functools import cache, lru_cache

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.exceptions import McapError
from mcap.records import (
    Message,
)
from rosbags.typesys import Stores, get_typestore

from gainfarm.schemas.episode_log import (
    CHANNELS,
    TF_MESSAGE,
    Channel,
    Frame,
)
from gainfarm.schemas.robot import JOINT_NAMES

# The layouts of the arms a process writes or reads (one per joint names: an arm's JointState
# messages name its joints), at most this many kept: a log names its own, so a stream of hostile
# logs may not grow the cache without bound.
LAYOUTS = 16

NANOSECONDS = 1_000_000_000
CHUNK_SIZE = 4 * 1024 * 1024  # uncompressed bytes of messages per chunk, at most (~7.5 s of ticks)

# Chunks are compressed with zstd at a negative ("fast") level: compression is most of the cost of
# writing, and the payloads are mostly float64 noise that no setting shrinks (zstd keeps the
# numbers as they are and removes the template's bytes around them). Measured on the 2.8 MB chunk
# of a 5 s episode's ticks (with the frame checksum): level 3 (the mcap Writer's default) 8.4 ms
# -> 1058 kB, level 1 4.5 ms -> 1081 kB, -1 3.6 ms -> 1119 kB, -4 2.7 ms -> 1173 kB, -10 2.3 ms
# -> 1244 kB, -12 2.2 ms -> 1454 kB (the ratio collapses below -10); zstd's other parameters
# (window, hash table, minimum match) trade size for time along the same line, and lz4 is not a
# declared dependency. -10 is the fastest setting that still compresses well; it costs 15% more
# disk than level 1. No worker threads: the cores step episodes. It is most of a log's cost (~3
# ms of CPU for a 5 s episode, against ~40 ms for the episode in a batch: bench/encode_bench.py).
ZSTD_LEVEL = -10

# A chunk's records are checked by the zstd frame's checksum (XXH64 of the uncompressed bytes,
# verified by every zstd decoder: this reader, the mcap library's, any other tool's), not by the
# Chunk record's CRC-32, which is written as 0 ("not computed", MCAP spec, Chunk; readers skip it,
# validating CRCs or not). Either catches a number corrupted on disk, which nothing else would
# (zstd stores the numbers as raw literals, and any number fits the template); the checksum costs
# 0.2 ms per 5 s episode where zlib.crc32 cost 0.65 ms, a fifth of writing the log. In transit the
# farm checks a log by its SHA-256 digest anyway (worker.job.Outcome.digest). Logs written with a
# CRC (before this) are still checked by it.
CHUNK_CRC = 0

# The Message record's header: opcode, record length, then these (MCAP spec, "Message").
MESSAGE_HEADER = [
    ("opcode", "u1"),
    ("length", "<u8"),
    ("channel_id", "<u2"),
    ("sequence", "<u4"),
    ("log_time", "<u8"),
    ("publish_time", "<u8"),
]
RECORD_PREFIX = 1 + 8  # opcode and record length, before every record's content
FOOTER_LENGTH = 8 + 8 + 4  # a Footer's content: summary start, summary offset start, CRC
# What a reader takes in besides the messages, bounded far above what episode_bytes writes (5.1
# kB of summary, 0.9 kB of metadata, 4.5 kB of Schema and Channel records in the first chunk), so
# that no length or count a file states makes the reader allocate in proportion to it.
MAX_SUMMARY_BYTES = 1024 * 1024  # the summary section and its summary offsets
MAX_METADATA_BYTES = 1024 * 1024  # the Metadata record
MAX_DEFINITION_BYTES = 1024 * 1024  # the records before the messages, in all chunks together
# The channels made for ROS 2 tools follow CHANNELS' ids 1..6; they share one chunk of their own,
# the file's first, which the reader skips.
TF_ID = len(CHANNELS) + 1
DESCRIPTION_ID = len(CHANNELS) + 2
DERIVED_IDS = frozenset({TF_ID, DESCRIPTION_ID})
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
PROFILE = "ros2"
# The writer and its log layout's version, in the Header's free-form library field (readers
# ignore it; a person or a tool telling logs apart reads it). 1 (written as plain "gainfarm"):
# chunks carried their CRC-32. 2: a chunk's CRC is 0 and its zstd frame carries zstd's checksum
# (CHUNK_CRC): the same messages, other bytes, so a log's digest differs from version 1's.
LIBRARY = "gainfarm episode log 2"
UNREADABLE = (
    OSError,
    McapError,
    EOFError,
    ValueError,
    struct.error,
    OverflowError,  # an offset or length past what io.BytesIO can seek or read
    zstandard.ZstdError,
    RuntimeError,  # lz4.frame's errors
    ImportError,  # lz4 is optional
)


class NotAnEpisodeLog(ValueError):
    """The file is not a readable gainfarm episode log."""


@dataclass(frozen=True)
class ChannelLayout:
    """Where the variable parts sit in a channel's fixed-size CDR message."""

    template: np.ndarray  # (size,) uint8: one encoded message
    stamp: int  # byte offset of header.stamp (int32 sec, uint32 nanosec)
    fields: dict[str, tuple[int, int]]  # message field -> (byte offset, number of float64s)

    @property
    def size(self) -> int:
        return len(self.template)

    def dtype(self) -> np.dtype:
        """The message as a structured dtype: the stamp and the numbers are named fields, the
        bytes in between (CDR header, frame_id, joint names, sequence lengths) are gaps."""
        names = ["stamp", *self.fields]
        formats = [("<u4", (2,)), *(("<f8", (count,)) for _, count in self.fields.values())]
        offsets = [self.stamp, *(offset for offset, _ in self.fields.values())]
        return np.dtype(
            {"names": names, "formats": formats, "offsets": offsets, "itemsize": self.size}
        )


@dataclass(frozen=True)
class TickLayout:
    """The Message records of one tick, one per channel in CHANNELS order."""

    dtype: np.dtype  # one field per topic, each a Message record with its CDR data as a subfield
    template: np.ndarray  # (size,) uint8: the records of tick 0 at time 0
    constant: np.ndarray  # (size,) uint8: 0xFF where every tick has the template's byte, else 0

    @property
    def size(self) -> int:
        return self.dtype.itemsize

    @property
    def word(self) -> np.dtype:
        """The widest unsigned integer that tiles a tick, to compare ticks a word at a time."""
        return np.dtype(f"<u{next(w for w in (8, 4, 2, 1) if self.size % w == 0)}")

    def record_offset(self, topic: str) -> int:
        return self.dtype.fields[topic][1]


@cache
def typestore():
    return get_typestore(Stores.ROS2_HUMBLE)


@cache
def schema_text(message_type: str) -> str:
    """The ros2msg schema text (with its dependencies) MCAP stores for `message_type`."""
    text, _ = typestore().generate_msgdef(message_type, ros_version=2)
    return text


@lru_cache(maxsize=LAYOUTS * 8)
def channel_layout(channel: Channel, joint_names: tuple[str, ...] = JOINT_NAMES) -> ChannelLayout:
    """Encode one message, of an arm with joints `joint_names`, with recognisable sentinel
    numbers and find where they landed."""
    store = typestore()
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=0x5EC0_5EC0, nanosec=0x0A0B_0C0D)
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id=channel.frame_id)
    sentinels = {
        field: 7.25e9 + 1000.0 * i + np.arange(len(joint_names) if field != "point" else 3)
        for i, (field, _) in enumerate(channel.fields)
    }
    if channel.message_type.endswith("JointState"):
        empty = np.zeros(0)
        arrays = {f: sentinels.get(f, empty) for f in ("position", "velocity", "effort")}
        message = types[channel.message_type](header=header, name=list(joint_names), **arrays)
    else:
        x, y, z = sentinels["point"]
        point = types["geometry_msgs/msg/Point"](x=x, y=y, z=z)
        message = types[channel.message_type](header=header, point=point)
    encoded = bytes(store.serialize_cdr(message, channel.message_type))
    offsets = {
        field: (encoded.index(values.astype("<f8").tobytes()), len(values))
        for field, values in sentinels.items()
    }
    stamp_offset = encoded.index(np.array([0x5EC0_5EC0, 0x0A0B_0C0D], "<u4").tobytes())
    # The sentinels were only there to be found: the template carries zeros in their place.
    template = bytearray(encoded)
    for offset, count in [(stamp_offset, 1), *offsets.values()]:
        template[offset : offset + 8 * count] = bytes(8 * count)
    return ChannelLayout(np.frombuffer(bytes(template), np.uint8), stamp_offset, offsets)


@lru_cache(maxsize=LAYOUTS)
def tick_layout(joint_names: tuple[str, ...] = JOINT_NAMES) -> TickLayout:
    """Lay out one tick's Message records of an arm with joints `joint_names` (the iiwa 14's by
    default); the mcap library writes the template's records."""
    dtype = np.dtype(
        [
            (
                channel.topic,
                [*MESSAGE_HEADER, ("data", channel_layout(channel, joint_names).dtype())],
            )
            for channel in CHANNELS
        ]
    )
    builder = RecordBuilder()
    for channel_id, channel in enumerate(CHANNELS, start=1):
        data = channel_layout(channel, joint_names).template.tobytes()
        Message(channel_id=channel_id, log_time=0, data=data, publish_time=0, sequence=0).write(
            builder
        )
    template = np.frombuffer(builder.end(), np.uint8)
    if len(template) != dtype.itemsize:
        raise AssertionError("the tick dtype does not match the records the mcap library writes")
    return TickLayout(dtype, template, constant_bytes(dtype))


def constant_bytes(dtype: np.dtype) -> np.ndarray:
    """Mark the bytes of a tick that episode_bytes copies from the template unchanged: all but
    the sequence numbers, times, stamps and numbers (so opcodes, record lengths, channel ids, CDR
    headers, frame ids, joint names, array lengths and padding)."""
    variable = np.zeros(dtype.itemsize, bool)
    for record, record_offset in dtype.fields.values():
        for name in ("sequence", "log_time", "publish_time"):
            field, offset = record.fields[name]
            start = record_offset + offset
            variable[start : start + field.itemsize] = True
        data, data_offset = record.fields["data"]
        for field, offset in data.fields.values():
            start = record_offset + data_offset + offset
            variable[start : start + field.itemsize] = True
    return np.where(variable, 0, 0xFF).astype(np.uint8)


@cache
def tf_layout(frames: tuple[Frame, ...]) -> tuple[np.ndarray, np.dtype]:
    """One /tf Message record at time 0 (the frames' names and translations in place, stamps and
    rotations zero) and its dtype, whose data names each transform's stamp and rotation."""
    store = typestore()
    types = store.types
    sentinels = 7.25e9 + 1000.0 * np.arange(len(frames))[:, None] + np.arange(4)
    transforms = []
    for i, transform in enumerate(frames):
        stamp = types["builtin_interfaces/msg/Time"](sec=0x5EC0_0000 + i, nanosec=0x0A0B_0C0D)
        x, y, z = transform.translation
        qx, qy, qz, qw = sentinels[i]
        transforms.append(
            types["geometry_msgs/msg/TransformStamped"](
                header=types["std_msgs/msg/Header"](stamp=stamp, frame_id=transform.parent),
                child_frame_id=transform.child,
                transform=types["geometry_msgs/msg/Transform"](
                    translation=types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                    rotation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
                ),
            )
        )
    encoded = bytearray(store.serialize_cdr(types[TF_MESSAGE](transforms=transforms), TF_MESSAGE))
    names, formats, offsets = [], [], []
    for i in range(len(frames)):
        stamp = np.array([0x5EC0_0000 + i, 0x0A0B_0C0D], "<u4").tobytes()
        rotation = sentinels[i].astype("<f8").tobytes()
        for name, value, form in (
            ("stamp", stamp, ("<u4", (2,))),
            ("rotation", rotation, ("<f8", (4,))),
        ):
            offset = encoded.index(value)
            encoded[offset : offset + len(value)] = bytes(len(value))  # found: now zero
            names.append(f"{name}{i}")
            formats.append(form)
            offsets.append(offset)
    data = np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": len(encoded)}
    )
    builder = RecordBuilder()
    Message(channel_id=TF_ID, log_time=0, data=bytes(encoded), publish_time=0, sequence=0).write(
        builder
    )
    template = np.frombuffer(builder.end(), np.uint8)
    dtype = np.dtype([*MESSAGE_HEADER, ("data", data)])
    if len(template) != dtype.itemsize:
        raise AssertionError("the /tf dtype does not match the record the mcap library writes")
    return template, dtype
