"""Episode logs on disk: exact round trips, readable by an independent ROS 2 decoder, with the
arm's description and transforms for ROS 2 tools, which the writer is given."""

import dataclasses
import io
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest
import yaml
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.writer import Writer
from mcap_ros2.reader import read_ros2_messages
from scipy.spatial.transform import Rotation

from gainfarm.models import RIGID_MJCF, plant_preset, robot_of
from gainfarm.models.ur5e import JOINT_NAMES as UR5E_JOINT_NAMES
from gainfarm.models.urdf import description, urdf
from gainfarm.schemas import EpisodeSpec, TrajectorySpec
from gainfarm.schemas.episode_log import CHANNELS, TF_EVERY, EpisodeLog, Frame, RobotDescription
from gainfarm.schemas.mcap_episode import (
    NotAnEpisodeLog,
    decode_episode,
    episode_bytes,
    read_episode,
)
from gainfarm.schemas.robot import JOINT_NAMES
from gainfarm.worker.episode import run_episode

ARRAYS = ("t", "q", "qd", "tau", "u", "theta", "theta_d", "q_des", "qd_des", "ee", "ee_des")
LINKS = ["base", *(f"link{i}" for i in range(1, 8)), "flange"]


def write_episode(log: EpisodeLog, path: Path) -> int:
    """Write `log` as the worker does, the iiwa drawn; return its size."""
    content = episode_bytes(log, description())
    path.write_bytes(content)
    return len(content)


def tf_ticks(ticks: int) -> np.ndarray:
    """The ticks /tf has a message at: every TF_EVERY-th from the first, and the last."""
    return np.unique(np.append(np.arange(0, ticks, TF_EVERY), ticks - 1))


def test_round_trip_is_exact(tracking_log, tmp_path):
    path = tmp_path / "episode.mcap"
    size = write_episode(tracking_log, path)
    assert size == path.stat().st_size > 0
    back = read_episode(path)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(back, name), getattr(tracking_log, name), name)
    assert back.metadata == tracking_log.metadata


def test_an_independent_ros2_decoder_reads_every_channel(tracking_log, tmp_path):
    path = tmp_path / "episode.mcap"
    write_episode(tracking_log, path)
    decoded: dict[str, list] = {}
    for message in read_ros2_messages(str(path)):
        decoded.setdefault(message.channel.topic, []).append(message)
    assert {topic: len(m) for topic, m in decoded.items()} == {
        **{channel.topic: tracking_log.ticks for channel in CHANNELS},
        "/tf": len(tf_ticks(tracking_log.ticks)),
        "/robot_description": 1,
    }
    states = decoded["/joint_states"]
    assert states[0].schema.name == "sensor_msgs/msg/JointState"
    assert list(states[0].ros_msg.name) == [f"A{i}" for i in range(1, 8)]
    np.testing.assert_array_equal([m.ros_msg.position for m in states], tracking_log.q)
    np.testing.assert_array_equal([m.ros_msg.velocity for m in states], tracking_log.qd)
    np.testing.assert_array_equal([m.ros_msg.effort for m in states], tracking_log.tau)
    commands = decoded["/joint_commands"]
    np.testing.assert_array_equal([m.ros_msg.effort for m in commands], tracking_log.u)
    assert len(commands[0].ros_msg.position) == len(commands[0].ros_msg.velocity) == 0
    motors = decoded["/motor_states"]
    np.testing.assert_array_equal([m.ros_msg.position for m in motors], tracking_log.theta)
    np.testing.assert_array_equal([m.ros_msg.velocity for m in motors], tracking_log.theta_d)
    reference = decoded["/joint_reference"]
    np.testing.assert_array_equal([m.ros_msg.position for m in reference], tracking_log.q_des)
    np.testing.assert_array_equal([m.ros_msg.velocity for m in reference], tracking_log.qd_des)
    assert len(reference[0].ros_msg.effort) == 0
    for topic, expected in (("/ee/actual", tracking_log.ee), ("/ee/desired", tracking_log.ee_des)):
        points = [[m.ros_msg.point.x, m.ros_msg.point.y, m.ros_msg.point.z] for m in decoded[topic]]
        np.testing.assert_array_equal(points, expected)
        assert decoded[topic][0].ros_msg.header.frame_id == "world"
    # Log time and header stamp are both the simulated time since the episode started.
    stamps = [m.ros_msg.header.stamp.sec + m.ros_msg.header.stamp.nanosec * 1e-9 for m in states]
    np.testing.assert_allclose(stamps, tracking_log.t, atol=1e-9)
    np.testing.assert_allclose([m.log_time_ns * 1e-9 for m in states], tracking_log.t, atol=1e-9)


def test_file_is_chunked_compressed_and_carries_its_metadata(tracking_log, tmp_path):
    path = tmp_path / "episode.mcap"
    write_episode(tracking_log, path)
    with open(path, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        tf = len(tf_ticks(tracking_log.ticks))
        assert summary.statistics.message_count == len(CHANNELS) * tracking_log.ticks + tf + 1
        assert summary.chunk_indexes
        assert all(chunk.compression in ("zstd", "lz4") for chunk in summary.chunk_indexes)
        (record,) = [m for m in reader.iter_metadata() if m.name == "gainfarm.episode"]
    for key in ("spec", "diverged", "versions", "ticks_planned", "torque_limits"):
        assert key in record.metadata
    assert '"mujoco"' in record.metadata["versions"]


def test_chunks_are_checked_by_zstds_checksum_and_read_with_crcs_validated(tracking_log):
    """A chunk states no CRC-32 (0: "not computed", which readers skip); its zstd frame carries
    a checksum of the same records instead. The mcap library's reader, validating CRCs, and the
    ROS 2 decoder read every message."""
    content = episode_bytes(tracking_log, description())
    reader = make_reader(io.BytesIO(content), validate_crcs=True)
    assert reader.get_header().library == "gainfarm episode log 2"  # the layout's version
    chunk_indexes = reader.get_summary().chunk_indexes
    for index in chunk_indexes:
        stream = io.BytesIO(content[index.chunk_start_offset + 1 + 8 :])
        chunk = Chunk.read(ReadDataStream(stream))
        assert chunk.uncompressed_crc == 0
        assert zstandard.get_frame_parameters(chunk.data).has_checksum
    messages = sum(1 for _ in reader.iter_messages())
    tf = len(tf_ticks(tracking_log.ticks))
    assert messages == len(CHANNELS) * tracking_log.ticks + tf + 1
    decoded = list(read_ros2_messages(io.BytesIO(content)))
    assert len(decoded) == messages


def test_logs_encoded_one_after_another_and_on_threads_are_each_their_own(
    tracking_log, diverged_log
):
    """The writer reuses its ticks from log to log, per thread: whatever was encoded before, and
    on whichever thread, a log's bytes are the same and read back as the log."""
    first = episode_bytes(tracking_log, description())
    diverged = episode_bytes(diverged_log, description())
    assert episode_bytes(tracking_log, description()) == first
    logs = [tracking_log, diverged_log] * 4
    with ThreadPoolExecutor(max_workers=4) as pool:
        made = list(pool.map(lambda log: episode_bytes(log, description()), logs))
    assert made == [first, diverged] * 4
    back = decode_episode(diverged)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(back, name), getattr(diverged_log, name), name)


def test_the_robot_description_is_the_arms_urdf_latched(tracking_log, tmp_path):
    path = tmp_path / "episode.mcap"
    write_episode(tracking_log, path)
    (message,) = read_ros2_messages(str(path), topics=["/robot_description"])
    assert message.schema.name == "std_msgs/msg/String" and message.log_time_ns == 0
    assert message.ros_msg.data == urdf()
    model = pin.buildModelFromXML(message.ros_msg.data)  # urdfdom, as ROS tools parse it
    assert list(model.names)[1:] == list(JOINT_NAMES)  # the joint states' names
    # Offered as robot_state_publisher offers it: reliable and transient local (latched), so
    # that `ros2 bag play` hands it to a subscriber that comes late; every other channel volatile.
    with open(path, "rb") as stream:
        channels = make_reader(stream).get_summary().channels.values()
    durability = {
        channel.topic: yaml.safe_load(channel.metadata["offered_qos_profiles"])[0]["durability"]
        for channel in channels
    }
    assert durability.pop("/robot_description") == 1
    assert set(durability.values()) == {2} and len(durability) == len(CHANNELS) + 1


def test_tf_puts_every_link_where_mujoco_puts_it(tracking_log, tmp_path):
    """/tf, decoded by an independent decoder and composed from the world out, at each of its
    ticks: MuJoCo's body poses for the logged joint angles, under the URDF's link names."""
    path = tmp_path / "episode.mcap"
    write_episode(tracking_log, path)
    messages = list(read_ros2_messages(str(path), topics=["/tf"]))
    ticks = tf_ticks(tracking_log.ticks)
    assert len(messages) == len(ticks) and ticks[-1] == tracking_log.ticks - 1
    assert messages[0].schema.name == "tf2_msgs/msg/TFMessage"
    urdf_links = {frame.name for frame in pin.buildModelFromXML(urdf()).frames}
    model = mujoco.MjModel.from_xml_string(RIGID_MJCF.read_text())
    data = mujoco.MjData(model)
    hinges = [model.joint(name).qposadr[0] for name in JOINT_NAMES]
    for message, tick in zip(messages, ticks, strict=True):
        transforms = message.ros_msg.transforms
        assert [(t.header.frame_id, t.child_frame_id) for t in transforms] == list(
            zip(["world", *LINKS[:-1]], LINKS, strict=True)
        )
        assert set(LINKS) <= urdf_links
        assert message.log_time_ns == round(tracking_log.t[tick] * 1e9)
        for transform in transforms:
            stamp = transform.header.stamp
            assert stamp.sec * 1_000_000_000 + stamp.nanosec == message.log_time_ns
        world = {"world": (np.zeros(3), Rotation.identity())}
        for transform in transforms:
            v, r = transform.transform.translation, transform.transform.rotation
            position, rotation = world[transform.header.frame_id]
            world[transform.child_frame_id] = (
                position + rotation.apply([v.x, v.y, v.z]),
                rotation * Rotation.from_quat([r.x, r.y, r.z, r.w]),
            )
        data.qpos[hinges] = tracking_log.q[tick]
        mujoco.mj_kinematics(model, data)
        for link in LINKS:
            where = data.site(link) if link == "flange" else data.body(link)
            np.testing.assert_allclose(world[link][0], where.xpos, atol=1e-12, err_msg=link)
            matrix = world[link][1].as_matrix()
            np.testing.assert_allclose(matrix, where.xmat.reshape(3, 3), atol=1e-12)
        # The logged angles are the encoders': the flange drawn is within a millimetre of where
        # the simulation had it.
        assert np.linalg.norm(world["flange"][0] - tracking_log.ee[tick]) < 1e-3


def test_a_log_written_before_tf_and_by_the_mcap_writer_reads_the_same(tracking_log, tmp_path):
    """The reader needs only the six channels of ticks (logs written before /tf still read),
    and not this writer's layout: the mcap library's Writer, chunking as it likes, will do."""
    ours = tmp_path / "episode.mcap"
    write_episode(tracking_log, ours)
    older = tmp_path / "older.mcap"
    with open(ours, "rb") as source, open(older, "wb") as stream:
        reader = make_reader(source)
        summary = reader.get_summary()
        writer = Writer(stream, chunk_size=300_000)
        writer.start(profile="ros2", library="an older gainfarm")
        for schema in summary.schemas.values():
            writer.register_schema(schema.name, schema.encoding, schema.data)
        topics = {channel.topic for channel in CHANNELS}
        kept = sorted(c.id for c in summary.channels.values() if c.topic in topics)
        for channel_id in kept:
            channel = summary.channels[channel_id]
            writer.register_channel(channel.topic, "cdr", channel.schema_id)
        (metadata,) = reader.iter_metadata()
        writer.add_metadata(metadata.name, metadata.metadata)
        for _, channel, message in reader.iter_messages(topics=topics, log_time_order=False):
            writer.add_message(
                channel.id, message.log_time, message.data, message.publish_time, message.sequence
            )
        writer.finish()
    with open(older, "rb") as stream:
        assert {c.topic for c in make_reader(stream).get_summary().channels.values()} == topics
    back = read_episode(older)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(back, name), getattr(tracking_log, name), name)
    assert back.metadata == tracking_log.metadata


def test_a_diverged_episode_round_trips(diverged_log, tmp_path):
    path = tmp_path / "diverged.mcap"
    write_episode(diverged_log, path)
    back = read_episode(path)
    assert back.metadata.diverged and back.ticks == diverged_log.ticks
    np.testing.assert_array_equal(back.q, diverged_log.q)


def test_files_that_are_not_episode_logs_are_rejected_with_a_reason(tracking_log, tmp_path):
    random_bytes = tmp_path / "random.mcap"
    random_bytes.write_bytes(np.random.default_rng(0).bytes(4096))
    good = tmp_path / "good.mcap"
    write_episode(tracking_log, good)
    truncated = tmp_path / "truncated.mcap"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        writer.finish()
    for path in (random_bytes, truncated, foreign, tmp_path / "empty.mcap"):
        path.touch()
        with pytest.raises(NotAnEpisodeLog) as caught:
            read_episode(path)
        assert "\n" not in str(caught.value)


def test_a_malformed_log_is_refused_before_any_byte_is_made(tracking_log):
    broken = type(tracking_log)(**{**tracking_log.__dict__, "q": tracking_log.q[:, :3]})
    with pytest.raises(ValueError):
        episode_bytes(broken, description())


def test_the_contract_draws_whatever_robot_it_is_given(tracking_log):
    """The writer takes the description and the transforms as inputs: a stand-in two-link
    robot's text and frames land on /robot_description and /tf, its rotations at each /tf
    tick, and the columns read back the same, whatever robot drew them."""
    turns = []

    def rotations(q: np.ndarray) -> np.ndarray:
        turns.append(q.copy())
        half = q[:, :2] / 2  # each frame turns about z by its joint's angle
        return np.stack(
            [np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)], axis=-1
        )

    frames = (Frame("world", "base", (0.0, 0.0, 0.5)), Frame("base", "tip", (1.0, 0.0, 0.0)))
    robot = RobotDescription('<robot name="stand-in"/>', frames, rotations)
    content = episode_bytes(tracking_log, robot)
    ticks = tf_ticks(tracking_log.ticks)
    (seen,) = turns
    np.testing.assert_array_equal(seen, tracking_log.q[ticks])
    messages = list(read_ros2_messages(io.BytesIO(content), topics=["/robot_description", "/tf"]))
    assert messages[0].ros_msg.data == '<robot name="stand-in"/>'
    tf = [m.ros_msg.transforms for m in messages[1:]]
    assert len(tf) == len(ticks)
    assert [(t.header.frame_id, t.child_frame_id) for t in tf[-1]] == [
        ("world", "base"),
        ("base", "tip"),
    ]
    assert tf[0][1].transform.translation.x == 1.0
    z = [[t.transform.rotation.z for t in message] for message in tf]
    np.testing.assert_array_equal(z, np.sin(tracking_log.q[ticks, :2] / 2))
    back = decode_episode(content)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(back, name), getattr(tracking_log, name), name)
    # Rotations that do not match the frames are refused, not written.
    wrong = RobotDescription(robot.urdf, frames[:1], rotations)
    with pytest.raises(ValueError, match="one x y z w per /tf tick and frame"):
        episode_bytes(tracking_log, wrong)


# --- any arm: the log names its joints, and reads back for 6 as for 7 ---------------------------


@pytest.fixture(scope="module")
def ur5e_log() -> EpisodeLog:
    """A real 1 s episode of the UR5e (6 joints) on its realistic plant, default gains."""
    robot = robot_of("ur5e")
    trajectory = TrajectorySpec(kind="fourier", duration=1.0)
    spec = EpisodeSpec(
        gains=robot.default_gains, trajectory=trajectory, plant=plant_preset("realistic", "ur5e")
    )
    return run_episode(spec)


UR5E_JOINTS = list(UR5E_JOINT_NAMES)


def test_a_six_joint_log_names_its_joints_and_round_trips(ur5e_log, tmp_path):
    assert ur5e_log.q.shape == (ur5e_log.ticks, 6)
    assert list(ur5e_log.metadata.joint_names) == UR5E_JOINTS
    path = tmp_path / "ur5e.mcap"
    path.write_bytes(episode_bytes(ur5e_log, None))  # no drawing of the UR5e: columns only
    back = read_episode(path)
    for name in ARRAYS:
        np.testing.assert_array_equal(getattr(back, name), getattr(ur5e_log, name), name)
    assert back.metadata == ur5e_log.metadata
    assert back.metadata.spec.plant.robot == "ur5e"
    # An independent ROS 2 decoder reads the same: the JointState messages name the UR5e's joints.
    decoded: dict[str, list] = {}
    for message in read_ros2_messages(str(path)):
        decoded.setdefault(message.channel.topic, []).append(message)
    assert {topic: len(m) for topic, m in decoded.items()} == {
        channel.topic: ur5e_log.ticks for channel in CHANNELS
    }
    for topic in ("/joint_states", "/joint_commands", "/motor_states", "/joint_reference"):
        assert list(decoded[topic][0].ros_msg.name) == UR5E_JOINTS, topic
    states = decoded["/joint_states"]
    np.testing.assert_array_equal([m.ros_msg.position for m in states], ur5e_log.q)
    commands = decoded["/joint_commands"]
    np.testing.assert_array_equal([m.ros_msg.effort for m in commands], ur5e_log.u)


def test_logs_of_two_arms_encoded_on_one_thread_are_each_their_own(ur5e_log, tracking_log):
    # The writer's per-thread ticks are of the last arm's layout: they are made again for another.
    first = episode_bytes(tracking_log, description())
    other = episode_bytes(ur5e_log, None)
    assert episode_bytes(tracking_log, description()) == first
    assert episode_bytes(ur5e_log, None) == other
    assert decode_episode(other).metadata.joint_names == tuple(UR5E_JOINTS)


def test_an_iiwa_log_leaves_out_its_joint_names_and_speeds_as_logs_before_did(tracking_log):
    # Its metadata's bytes are those of a log written before arms were many, which read as the
    # iiwa 14's: joint names A1..A7 and its data sheet's speed limits.
    record = tracking_log.metadata.model_dump_json()
    assert "joint_names" not in record and "speed_limits" not in record
    back = decode_episode(episode_bytes(tracking_log, description())).metadata
    assert back.joint_names == JOINT_NAMES


def test_a_log_whose_names_or_limits_miscount_its_joints_is_refused(ur5e_log):
    too_few = ur5e_log.metadata.model_dump() | {"speed_limits": (1.0,) * 5}
    with pytest.raises(ValueError, match="speed_limits: one per joint"):
        type(ur5e_log.metadata).model_validate(too_few)
    iiwa_names = ur5e_log.metadata.model_dump() | {"joint_names": JOINT_NAMES}
    with pytest.raises(ValueError, match="torque_limits: one per joint"):
        type(ur5e_log.metadata).model_validate(iiwa_names)


def test_columns_that_are_not_one_per_named_joint_are_refused_before_any_byte(
    tracking_log, ur5e_log
):
    # The iiwa's seven columns under the UR5e's six names: the writer refuses, as the reader
    # refuses messages of another layout than the names its metadata gives.
    misnamed = dataclasses.replace(tracking_log, metadata=ur5e_log.metadata)
    with pytest.raises(ValueError, match=r"not \(\d+, 6\): one row of /joint_states"):
        episode_bytes(misnamed, None)
