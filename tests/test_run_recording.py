"""``invent up``'s run.mcap, made of its processes' journals (services/recording/record.py,
``write_run_recording``): every published sample on its key's channel in publication order, the
Foxglove scene beside them, a journal cut short named, and the bounds of ``[record]``: a size cap
that stops the recording (saying so) but keeps how the run ended, and splits by size and duration
that the report reads back whole."""

from __future__ import annotations

import math

from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LaserScan_pb2 import LaserScan as FoxgloveLaserScan

from schemas.codec import decode, encode
from schemas.keys import Keys, Service
from schemas.messages import ImuSample, LaserScan, Time, TimedDoubleSeq, TimedPosition
from schemas.topics import TOPIC_TYPES, Topic
from services.config import RecordConfig, load_config
from services.recording.mcap_files import (
    RECORDING_STOPPED_TOPIC,
    read_messages,
    read_run,
    recording_parts,
    replay_schedule,
)
from services.recording.record import write_run_recording
from services.recording.scene import LIDAR_FRAME, ODOMETRY_TOPIC, SCAN_TOPIC, TRANSFORMS_TOPIC
from services.runtime.journal import Journal, journal_path

KEYS = Keys("rh0")
PUBLISHED_NS = 1_800_000_000 * 10**9
"""A Unix time in ns, when the first sample below was published."""
MS = 1_000_000


def _body_pose(stamp_ns: int, x: float) -> bytes:
    return encode(TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), [x, 0.0, 0.05, 1, 0, 0, 0, 1, 0, 0, 0, 1]))


def _odometry_pose(stamp_ns: int, x: float) -> bytes:
    return encode(TimedPosition(tm=Time.from_nanoseconds(stamp_ns), id=[], x=x, y=0.0, theta=0.0, error=[]))


def test_the_journals_make_one_recording_in_publication_order_with_the_scene(tmp_path):
    journals = tmp_path / "journals"
    journals.mkdir()
    sim = Journal(journal_path(journals, str(Service.SIM)))
    odometry = Journal(journal_path(journals, str(Service.ODOMETRY)))
    up = Journal(journal_path(journals, "up"))
    for step in range(3):
        sim.write(KEYS.sim_body_pose, _body_pose(step * MS, 0.1 * step), PUBLISHED_NS + 10 * step)
        odometry.write(KEYS.odometry_pose, _odometry_pose(step * MS, 0.1 * step), PUBLISHED_NS + 10 * step + 5)
    up.write(KEYS.status(Service.MOTOR), b'{"service":"motor","state":"idle"}', PUBLISHED_NS + 12)
    for journal in (sim, odometry, up):
        journal.close()
    output = tmp_path / "run.mcap"

    assert write_run_recording(journals, output, load_config(None, {})).cut_short == []

    read = read_messages(output)
    assert read.complete
    published = [(m.topic, m.log_time_ns - PUBLISHED_NS) for m in read.messages if m.topic.startswith(KEYS.prefix)]
    assert published == [
        (KEYS.sim_body_pose, 0),
        (KEYS.odometry_pose, 5),
        (KEYS.sim_body_pose, 10),
        (KEYS.status(Service.MOTOR), 12),
        (KEYS.odometry_pose, 15),
        (KEYS.sim_body_pose, 20),
        (KEYS.odometry_pose, 25),
    ]
    by_topic = {m.topic: m for m in read.messages}
    assert by_topic[KEYS.sim_body_pose].schema_name == "TimedDoubleSeq"
    assert by_topic[KEYS.odometry_pose].schema_name == "TimedPosition"
    assert by_topic[KEYS.odometry_pose].publish_time_ns == 2 * MS, "publish time: the message's stamp"
    assert by_topic[KEYS.status(Service.MOTOR)].schema_name == "MotorStatus", "a status: its service's kind"
    assert by_topic[TRANSFORMS_TOPIC].schema_name == "foxglove.FrameTransforms"
    assert by_topic[ODOMETRY_TOPIC].schema_name == "foxglove.PoseInFrame"


def test_a_journal_whose_service_was_killed_is_named_and_its_whole_batches_recorded(tmp_path):
    journals = tmp_path / "journals"
    journals.mkdir()
    whole = Journal(journal_path(journals, str(Service.SIM)))
    whole.write(KEYS.sim_body_pose, _body_pose(0, 0.0), PUBLISHED_NS)
    whole.close()
    killed = Journal(journal_path(journals, str(Service.MOTOR)))
    killed.write(KEYS.motor_torque, b"{}", PUBLISHED_NS + 1)
    output = tmp_path / "run.mcap"

    cut_short = write_run_recording(journals, output, load_config(None, {})).cut_short

    assert cut_short == [journal_path(journals, str(Service.MOTOR))]
    assert [m.topic for m in read_messages(output).messages if m.topic.startswith(KEYS.prefix)] == [KEYS.sim_body_pose]


def _square_journals(journals, steps: int = 1000) -> None:
    """A second of a run: a body pose every ms, and at its end the drive's outcome."""
    journals.mkdir()
    sim = Journal(journal_path(journals, str(Service.SIM)))
    for step in range(steps):
        sim.write(KEYS.sim_body_pose, _body_pose(step * MS, step * 1e-4), PUBLISHED_NS + step * MS)
    sim.close()
    drive = Journal(journal_path(journals, str(Service.DRIVE)))
    drive.write(KEYS.drive_outcome, b"{}", PUBLISHED_NS + steps * MS)
    drive.close()


def test_a_recording_at_its_max_size_stops_says_why_and_keeps_how_the_run_ended(tmp_path):
    _square_journals(tmp_path / "journals")
    output = tmp_path / "run.mcap"
    payload = len(_body_pose(0, 0.0))

    written = write_run_recording(tmp_path / "journals", output, load_config(None, {}), (), RecordConfig(max_size=0.01))

    assert written.stopped is not None and written.stopped["reason"].startswith("record.max_size"), written.stopped
    messages = read_messages(output).messages
    kept = sum(len(m.data) for m in messages if m.topic not in (KEYS.drive_outcome, RECORDING_STOPPED_TOPIC))
    assert 10_000 <= kept < 10_000 + 20 * payload, "up to 10 kB of messages (uncompressed), and a sample's scene"
    assert len([m for m in messages if m.topic == KEYS.sim_body_pose]) < 1000
    assert [m.topic for m in messages if m.topic == KEYS.drive_outcome] == [KEYS.drive_outcome], "kept past the cap"
    stop = [m for m in messages if m.topic == RECORDING_STOPPED_TOPIC]
    assert len(stop) == 1 and b"record.max_size" in stop[0].data


def test_a_recording_split_by_duration_and_by_size_reads_back_whole_in_order(tmp_path):
    for name, record in (("duration", RecordConfig(split_duration=0.25)), ("size", RecordConfig(split_size=0.05))):
        _square_journals(tmp_path / name)
        output = tmp_path / f"{name}.mcap"
        written = write_run_recording(tmp_path / name, output, load_config(None, {}), (), record)
        assert written.parts == recording_parts(output) and len(written.parts) > 1, (name, written.parts)
        assert written.parts[1].name == f"{name}_1.mcap" and written.stopped is None
        read = read_run(output)
        stamps = [m.publish_time_ns for m in read.messages if m.topic == KEYS.sim_body_pose]
        assert read.complete and stamps == [step * MS for step in range(1000)], name
        for part in written.parts[:-1]:
            poses = [m.publish_time_ns for m in read_messages(part).messages if m.topic == KEYS.sim_body_pose]
            if name == "duration":
                assert poses[-1] - poses[0] == 249 * MS, (part, "a quarter of a second each")
            else:
                assert sum(len(m.data) for m in read_messages(part).messages) >= 50_000, part


def _scan(stamp_ns: int) -> bytes:
    ranges = [None if ray % 2 else 1.0 + ray / 1000 for ray in range(360)]
    return encode(LaserScan(Time.from_nanoseconds(stamp_ns), -math.pi, 2 * math.pi / 360, 0.12, 3.5, ranges))


def _imu(stamp_ns: int) -> bytes:
    return encode(ImuSample(Time.from_nanoseconds(stamp_ns), (0, 0, 0, 1), "simulator", (0, 0, 0.5), (0, 0, 9.81)))


def test_the_lidar_and_imu_are_recorded_at_their_rates_the_scan_drawn_and_both_replayable(tmp_path):
    """A second of the sim's journal as it publishes its sensors (scans at 10 Hz, the IMU at 100 Hz,
    beside the observed steps' poses): run.mcap holds both keys with their schemas, every scan
    again as a foxglove.LaserScan in the lidar's frame, and a replay sends both as recorded."""
    journals = tmp_path / "journals"
    journals.mkdir()
    sim = Journal(journal_path(journals, str(Service.SIM)))
    for step in range(0, 1000, 10):
        published = PUBLISHED_NS + step * MS
        if step % 100 == 0:
            sim.write(KEYS.sim_scan, _scan(step * MS), published)
        sim.write(KEYS.sim_imu, _imu(step * MS), published)
        if step % 20 == 0:
            sim.write(KEYS.sim_body_pose, _body_pose(step * MS, 0.0), published + 1)
    sim.close()
    output = tmp_path / "run.mcap"

    write_run_recording(journals, output, load_config(None, {}))

    messages = read_run(output).messages
    by_topic: dict[str, list] = {}
    for message in messages:
        by_topic.setdefault(message.topic, []).append(message)
    assert len(by_topic[KEYS.sim_scan]) == 10 and len(by_topic[KEYS.sim_imu]) == 100, "at their own rates"
    assert {by_topic[key][0].schema_name for key in (KEYS.sim_scan, KEYS.sim_imu)} == {"LaserScan", "ImuSample"}
    shown = by_topic[SCAN_TOPIC]
    assert len(shown) == 10 and shown[0].schema_name == "foxglove.LaserScan"
    assert [m.publish_time_ns for m in shown] == [m.publish_time_ns for m in by_topic[KEYS.sim_scan]]
    scan = FoxgloveLaserScan.FromString(shown[-1].data)
    assert scan.frame_id == LIDAR_FRAME and list(scan.ranges) == decode(LaserScan, _scan(0)).ranges_or_inf()
    frames = {
        (t.parent_frame_id, t.child_frame_id)
        for m in by_topic[TRANSFORMS_TOPIC]
        for t in FrameTransforms.FromString(m.data).transforms
    }
    assert frames == {("world", "base_link"), ("base_link", LIDAR_FRAME)}
    robot, schedule = replay_schedule(messages)
    replayed = [item for item in schedule if item.topic in (Topic.SIM_SCAN, Topic.SIM_IMU)]
    assert robot == KEYS.robot and len(replayed) == 110
    assert [decode(TOPIC_TYPES[item.topic], item.data).tm.to_nanoseconds() for item in replayed] == [
        item.stamp_ns for item in replayed
    ], "every sample decodes, in stamp order"
