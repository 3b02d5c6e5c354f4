"""``invent record``: a real recorder process, stopped by SIGTERM or killed, and its file read back."""

import signal

import pytest
import zenoh
from mcap.reader import make_reader

from schemas.codec import encode
from schemas.keys import Keys
from schemas.messages import Time, TimedDoubleSeq
from services.recording.mcap_files import CHUNK_SIZE, read_messages
from tests.harness import InventProcess, peer_session, running_router, wait_until

pytestmark = pytest.mark.slow

KEYS = Keys("recorded")


def _sample(index: int) -> bytes:
    return encode(TimedDoubleSeq(Time.from_nanoseconds(index * 1_000_000), [float(index), -float(index)]))


def _record_and_publish(tmp_path, count: int, stop_signal: signal.Signals):
    output = tmp_path / "recorded.mcap"
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = InventProcess("record", "--connect", endpoint, "--robot", KEYS.robot, "--output", str(output))
        try:
            # BLOCK, not zenoh's default DROP: a flood of samples on a loaded machine must not lose
            # some in transport, or what the recorder wrote would not be a prefix of what was sent.
            publisher = session.declare_publisher(
                KEYS.sim_wheel_angles, congestion_control=zenoh.CongestionControl.BLOCK
            )
            wait_until(lambda: publisher.matching_status.matching, 30, "the recorder to subscribe")
            for index in range(count):
                publisher.put(_sample(index))
            if stop_signal is signal.SIGKILL:
                wait_until(lambda: output.stat().st_size > CHUNK_SIZE // 4, 30, "whole chunks in the file")
            recorder.process.send_signal(stop_signal)
            recorder.process.wait(30)
        finally:
            recorder.__exit__()
    return output, recorder.process.returncode


def test_sigterm_during_a_recording_leaves_a_whole_indexed_file(tmp_path):
    output, code = _record_and_publish(tmp_path, 500, signal.SIGTERM)
    assert code == 0
    with open(output, "rb") as file:
        reader = make_reader(file)
        assert reader.get_summary().statistics is not None
        data = [
            message.data
            for _schema, channel, message in reader.iter_messages()
            if channel.topic == KEYS.sim_wheel_angles
        ]
    assert data == [_sample(index) for index in range(len(data))], "what it took, in order"
    assert read_messages(output).complete


def test_a_killed_recorder_loses_at_most_its_last_chunk_and_the_reader_says_so(tmp_path):
    count = 3 * CHUNK_SIZE // len(_sample(99_999))
    output, code = _record_and_publish(tmp_path, count, signal.SIGKILL)
    assert code == -signal.SIGKILL
    read = read_messages(output)
    assert not read.complete
    data = [message.data for message in read.messages if message.topic == KEYS.sim_wheel_angles]
    assert data == [_sample(index) for index in range(len(data))], "a prefix, in order"
    assert data, "the whole chunks written before the kill"


def test_a_far_future_stamp_is_recorded_with_its_receive_time_and_kills_nothing(tmp_path):
    """A buggy or hostile publisher's stamp past what MCAP and Foxglove can hold (10^29 s)."""
    output = tmp_path / "forged.mcap"
    forged = encode(TimedDoubleSeq(Time(10**29, 0), [1.0, 2.0]))
    with running_router() as endpoint, peer_session(endpoint) as session:
        # --duration ends it, not a signal right after the puts: samples still on their way would be lost.
        recorder = InventProcess(
            "record", "--connect", endpoint, "--robot", KEYS.robot, "--output", str(output), "--duration", "5"
        )
        with recorder:
            publisher = session.declare_publisher(KEYS.sim_body_pose)
            wait_until(lambda: publisher.matching_status.matching, 30, "the recorder to subscribe")
            publisher.put(_sample(1))
            publisher.put(forged)
            publisher.put(_sample(2))
            recorder.process.wait(30)
            code, _out, err = recorder.stop()
    assert code == 0, err
    recorded = [message for message in read_messages(output).messages if message.topic == KEYS.sim_body_pose]
    assert [message.data for message in recorded] == [_sample(1), forged, _sample(2)]
    assert recorded[1].publish_time_ns == recorded[1].log_time_ns
    assert [recorded[0].publish_time_ns, recorded[2].publish_time_ns] == [1_000_000, 2_000_000]
