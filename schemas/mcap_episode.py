"""Episode logs as MCAP files with ROS 2 (CDR) messages, written and read in bulk.

Every message on a channel has the same byte layout (fixed joint names, fixed array lengths), so
instead of encoding 10,000 messages one by one, one template message per channel is encoded by a
ROS 2 serialiser (rosbags) and the time stamps and numbers of all ticks are written into copies of
it with NumPy. Reading does the reverse: the payloads of a channel are gathered into one array and
viewed as numbers. Any ROS 2 MCAP decoder reads these files; the tests check that with one.
"""

import json
import os
import tempfile
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from pydantic import ValidationError
from rosbags.typesys import Stores, get_typestore

from schemas.episode import EpisodeMetadata
from schemas.episode_log import CHANNELS, METADATA_NAME, Channel, EpisodeLog
from schemas.robot import JOINT_NAMES, N_JOINTS

NANOSECONDS = 1_000_000_000
CHUNK_SIZE = 4 * 1024 * 1024


class NotAnEpisodeLog(ValueError):
    """The file is not a readable gainfarm episode log."""


@dataclass(frozen=True)
class _Layout:
    """Where the variable parts sit in a channel's fixed-size CDR message."""

    template: np.ndarray  # (size,) uint8: one encoded message
    stamp: int  # byte offset of header.stamp (int32 sec, uint32 nanosec)
    fields: dict[str, tuple[int, int]]  # message field -> (byte offset, number of float64s)

    @property
    def size(self) -> int:
        return len(self.template)


@cache
def _typestore():
    return get_typestore(Stores.ROS2_HUMBLE)


@cache
def schema_text(message_type: str) -> str:
    """The ros2msg schema text (with its dependencies) MCAP stores for `message_type`."""
    text, _ = _typestore().generate_msgdef(message_type, ros_version=2)
    return text


@cache
def _layout(channel: Channel) -> _Layout:
    """Encode one message with recognisable sentinel numbers and find where they landed."""
    store = _typestore()
    types = store.types
    stamp = types["builtin_interfaces/msg/Time"](sec=0x5EC0_5EC0, nanosec=0x0A0B_0C0D)
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id=channel.frame_id)
    sentinels = {
        field: 7.25e9 + 1000.0 * i + np.arange(N_JOINTS if field != "point" else 3)
        for i, (field, _) in enumerate(channel.fields)
    }
    if channel.message_type.endswith("JointState"):
        empty = np.zeros(0)
        arrays = {f: sentinels.get(f, empty) for f in ("position", "velocity", "effort")}
        message = types[channel.message_type](header=header, name=list(JOINT_NAMES), **arrays)
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
    return _Layout(np.frombuffer(encoded, np.uint8), stamp_offset, offsets)


def _encode(channel: Channel, log: EpisodeLog, stamps: np.ndarray) -> np.ndarray:
    layout = _layout(channel)
    payloads = np.tile(layout.template, (log.ticks, 1))
    payloads[:, layout.stamp : layout.stamp + 8].view("<u4")[:] = stamps
    for field, attribute in channel.fields:
        offset, count = layout.fields[field]
        payloads[:, offset : offset + 8 * count].view("<f8")[:] = getattr(log, attribute)
    return payloads


def write_episode(log: EpisodeLog, path: Path) -> int:
    """Write `log` to `path` atomically (a temporary file, then a rename); return its size."""
    path = Path(path)
    log_times = np.round(log.t * NANOSECONDS).astype(np.int64)
    stamps = np.column_stack(divmod(log_times, NANOSECONDS)).astype("<u4")
    payloads = [_encode(channel, log, stamps) for channel in CHANNELS]
    fd, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        os.fchmod(fd, 0o644)  # mkstemp's 0600 would hide the log from the rest of the farm
        with os.fdopen(fd, "wb") as stream:
            writer = Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
            writer.start(profile="ros2", library="gainfarm")
            channel_ids = []
            for channel in CHANNELS:
                schema_id = writer.register_schema(
                    channel.message_type, "ros2msg", schema_text(channel.message_type).encode()
                )
                channel_ids.append(writer.register_channel(channel.topic, "cdr", schema_id))
            for k, log_time in enumerate(log_times.tolist()):
                for channel_id, rows in zip(channel_ids, payloads, strict=True):
                    writer.add_message(channel_id, log_time, rows[k].tobytes(), log_time, k)
            writer.add_metadata(METADATA_NAME, _metadata_record(log.metadata))
            writer.finish()
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    return path.stat().st_size


def _metadata_record(metadata: EpisodeMetadata) -> dict[str, str]:
    """One key per top-level field, each a JSON value, so that MCAP tools show them readably."""
    return {key: json.dumps(value) for key, value in metadata.model_dump(mode="json").items()}


def read_episode(path: Path) -> EpisodeLog:
    """Read an episode log written by write_episode; NotAnEpisodeLog if it is not one."""
    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            metadata = _read_metadata(reader)
            by_topic: dict[str, list[bytes]] = {channel.topic: [] for channel in CHANNELS}
            stamps: dict[str, list[int]] = {channel.topic: [] for channel in CHANNELS}
            for _, channel, message in reader.iter_messages(topics=list(by_topic)):
                by_topic[channel.topic].append(message.data)
                stamps[channel.topic].append(message.log_time)
    except (OSError, McapError, EOFError, ValueError) as error:
        if isinstance(error, NotAnEpisodeLog):
            raise
        raise NotAnEpisodeLog(f"{path}: not a readable MCAP file ({error})") from None
    return _assemble(path, metadata, by_topic, stamps)


def _read_metadata(reader) -> EpisodeMetadata:
    for record in reader.iter_metadata():
        if record.name == METADATA_NAME:
            try:
                fields = {key: json.loads(value) for key, value in record.metadata.items()}
                return EpisodeMetadata.model_validate(fields)
            except (ValueError, ValidationError) as error:
                raise NotAnEpisodeLog(f"invalid episode metadata: {error}") from None
    raise NotAnEpisodeLog(f"no {METADATA_NAME!r} metadata record: not a gainfarm episode log")


def _assemble(path, metadata, by_topic, stamps) -> EpisodeLog:
    columns: dict[str, np.ndarray] = {}
    ticks = metadata.ticks_run
    for channel in CHANNELS:
        layout = _layout(channel)
        messages = by_topic[channel.topic]
        if len(messages) != ticks or any(len(m) != layout.size for m in messages):
            raise NotAnEpisodeLog(
                f"{path}: {channel.topic} has {len(messages)} messages of the wrong shape; "
                f"expected {ticks} {channel.message_type} messages of {layout.size} bytes"
            )
        payloads = np.frombuffer(b"".join(messages), np.uint8).reshape(ticks, layout.size)
        for field, attribute in channel.fields:
            offset, count = layout.fields[field]
            columns[attribute] = payloads[:, offset : offset + 8 * count].copy().view("<f8")
        columns["t"] = np.asarray(stamps[channel.topic], dtype=np.int64) / NANOSECONDS
    return EpisodeLog(metadata=metadata, **columns)
