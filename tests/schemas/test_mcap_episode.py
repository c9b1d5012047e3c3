"""Episode logs on disk: exact round trips, readable by an independent ROS 2 decoder."""

import os

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_ros2.reader import read_ros2_messages

from schemas.episode_log import CHANNELS
from schemas.mcap_episode import NotAnEpisodeLog, read_episode, write_episode

ARRAYS = ("t", "q", "qd", "tau", "u", "theta", "theta_d", "q_des", "qd_des", "ee", "ee_des")


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
    decoded: dict[str, list] = {channel.topic: [] for channel in CHANNELS}
    for message in read_ros2_messages(str(path)):
        decoded[message.channel.topic].append(message)
    assert {topic: len(m) for topic, m in decoded.items()} == {
        channel.topic: tracking_log.ticks for channel in CHANNELS
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
        assert summary.statistics.message_count == len(CHANNELS) * tracking_log.ticks
        assert summary.chunk_indexes
        assert all(chunk.compression in ("zstd", "lz4") for chunk in summary.chunk_indexes)
        (record,) = [m for m in reader.iter_metadata() if m.name == "gainfarm.episode"]
    for key in ("spec", "diverged", "versions", "ticks_planned", "torque_limits"):
        assert key in record.metadata
    assert '"mujoco"' in record.metadata["versions"]


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


def test_a_failed_write_leaves_nothing_behind(tracking_log, tmp_path):
    broken = type(tracking_log)(**{**tracking_log.__dict__, "q": tracking_log.q[:, :3]})
    with pytest.raises(ValueError):
        write_episode(broken, tmp_path / "broken.mcap")
    assert os.listdir(tmp_path) == []
