"""``invent up``'s run.mcap, made of its processes' journals (services/recording/record.py,
``write_run_recording``): every published sample on its key's channel in publication order, the
Foxglove scene beside them, and a journal cut short named."""

from __future__ import annotations

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from services.config import load_config
from services.recording.mcap_files import read_messages
from services.recording.record import write_run_recording
from services.recording.scene import ODOMETRY_TOPIC, TRANSFORMS_TOPIC
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

    assert write_run_recording(journals, output, load_config(None, {})) == []

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
    assert by_topic[KEYS.status(Service.MOTOR)].schema_name is None
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

    cut_short = write_run_recording(journals, output, load_config(None, {}))

    assert cut_short == [journal_path(journals, str(Service.MOTOR))]
    assert [m.topic for m in read_messages(output).messages if m.topic.startswith(KEYS.prefix)] == [KEYS.sim_body_pose]
