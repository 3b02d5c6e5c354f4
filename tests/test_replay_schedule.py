"""What ``invent replay`` publishes, and in which order (services/recording/mcap_files.py: no zenoh here)."""

import pytest

from schemas.keys import Keys, Service
from schemas.topics import Topic
from services.config import ConfigError
from services.recording.mcap_files import RecordedMessage, replay_schedule
from services.recording.replay import parse_topics
from tests.harness import refused

KEYS = Keys("rh0")


def _message(topic: str, stamp_ns: int, log_time_ns: int, data: bytes = b"{}") -> RecordedMessage:
    return RecordedMessage(topic, None, data, log_time_ns, stamp_ns)


def test_samples_come_in_stamp_order_and_in_recorded_order_between_equal_stamps():
    messages = [
        _message(KEYS.motor_wheel_angles, 2, 10, b"wheels 2"),
        _message(KEYS.localization_pose, 1, 11, b"fix 1"),
        _message(KEYS.motor_wheel_angles, 1, 12, b"wheels 1"),
        _message(KEYS.motor_wheel_angles, 3, 13, b"wheels 3"),
    ]
    robot, schedule = replay_schedule(messages)
    assert robot == "rh0"
    assert [item.data for item in schedule] == [b"fix 1", b"wheels 1", b"wheels 2", b"wheels 3"]


def test_only_the_requested_keys_and_never_the_run_summary_or_foreign_channels():
    messages = [
        _message(KEYS.motor_wheel_angles, 1, 1),
        _message(KEYS.odometry_pose, 1, 2),
        _message(KEYS.run_summary, 5, 3),
        _message(KEYS.status(Service.MOTOR), 0, 4),
        _message("/scene", 1, 5),
    ]
    assert {item.topic for item in replay_schedule(messages)[1]} == {Topic.MOTOR_WHEEL_ANGLES, Topic.ODOMETRY_POSE}
    assert {item.topic for item in replay_schedule(messages, [Topic.ODOMETRY_POSE])[1]} == {Topic.ODOMETRY_POSE}


def test_a_key_the_recording_lacks_or_several_robots_is_a_config_error():
    with pytest.raises(ConfigError, match="no samples of localization/pose"):
        replay_schedule([_message(KEYS.motor_wheel_angles, 1, 1)], [Topic.LOCALIZATION_POSE])
    with pytest.raises(ConfigError, match="robots recorded: a, b"):
        replay_schedule([_message(Keys("a").odometry_pose, 1, 1), _message(Keys("b").odometry_pose, 1, 2)])
    with pytest.raises(ConfigError, match="robots recorded: none"):
        replay_schedule([_message("/scene", 1, 1)])


def test_keys_name_data_keys_relative_to_the_robot():
    assert parse_topics(["motor/wheel_angles", "localization/pose"]) == [
        Topic.MOTOR_WHEEL_ANGLES,
        Topic.LOCALIZATION_POSE,
    ]
    with pytest.raises(ConfigError, match="motor/status is not a data key"):
        parse_topics(["motor/status"])


def test_bad_flags_exit_2_naming_them(tmp_path, capsys):
    code, _out, stderr = refused(capsys, "replay", str(tmp_path / "nothing.mcap"))
    assert code == 2 and "no such file" in stderr
    code, _out, stderr = refused(capsys, "replay", str(tmp_path / "nothing.mcap"), "--rate", "-1")
    assert code == 2 and "--rate" in stderr
    code, _out, stderr = refused(capsys, "replay", str(tmp_path / "nothing.mcap"), "--robot", "a/b")
    assert code == 2 and "--robot" in stderr
