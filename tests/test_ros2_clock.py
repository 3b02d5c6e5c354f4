"""``invent ros2`` in a composed lockstep run of the straight scenario: ``/clock`` runs ahead of the wall
clock and each /odom and /tf carries the simulation time of the pose it holds (tests/test_ros2_bridge.py:
the bridge of a realtime teleop run, against a client speaking rmw_zenoh's wire format).
"""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest

from schemas.codec import decode
from schemas.messages import TimedDoubleSeq
from services.config import Config
from tests import ros_client
from tests.harness import invent_command, peer_session, running_router
from tests.test_ros2_bridge import DOMAIN, KEYS, _key

pytestmark = pytest.mark.slow


def test_a_lockstep_run_publishes_clock_faster_than_wall_time_and_stamps_its_poses(tmp_path):
    """A composed lockstep run of the straight line: ``/clock`` runs ahead of the wall clock,
    and each /odom and /tf odom -> base_link carries the simulation time of the pose it holds:
    the ground truth of that very step is within millimetres of it."""
    with running_router() as endpoint, peer_session(endpoint) as session:
        recorder = ros_client.Recorder(session, f"{DOMAIN}/**")
        truth: dict[int, tuple[float, float]] = {}
        ground = session.declare_subscriber(
            KEYS.sim_body_pose,
            lambda sample: truth.__setitem__(
                (pose := decode(TimedDoubleSeq, sample.payload.to_bytes())).tm.to_nanoseconds(),
                (pose.data[0], pose.data[1]),
            ),
        )
        result = subprocess.run(
            invent_command(
                "up", "--ros2", "--composed", "--scenario", "straight", "--no-record", "--connect", endpoint
            ),
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        ground.undeclare()
        samples = recorder.take()
        recorder.close()
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    clock = [
        (ros_client.TYPESTORE.deserialize_cdr(s.payload, "rosgraph_msgs/msg/Clock").clock, s.received_ns)
        for s in samples
        if s.key == _key("clock")
    ]
    assert len(clock) > 100
    (first, first_wall), (last, last_wall) = clock[0], clock[-1]
    simulated_ns = (last.sec - first.sec) * 1_000_000_000 + (last.nanosec - first.nanosec)
    assert simulated_ns > 1.5 * (last_wall - first_wall), "/clock runs ahead of the wall clock"
    odoms = [
        ros_client.TYPESTORE.deserialize_cdr(s.payload, "nav_msgs/msg/Odometry")
        for s in samples
        if s.key == _key("odom")
    ]
    tfs = [
        ros_client.TYPESTORE.deserialize_cdr(s.payload, "tf2_msgs/msg/TFMessage")
        for s in samples
        if s.key == _key("tf")
    ]
    assert len(odoms) == len(tfs) > 50
    config = Config()
    step_ns = round(config.sim.step * 1e9)
    compared = 0
    for odom, tf in zip(odoms, tfs, strict=True):
        stamp_ns = odom.header.stamp.sec * 1_000_000_000 + odom.header.stamp.nanosec
        (transform,) = [t for t in tf.transforms if (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")]
        assert transform.header.stamp == odom.header.stamp and stamp_ns % step_ns == 0, "a step's own time"
        assert transform.transform.translation.x == odom.pose.pose.position.x
        if stamp_ns in truth:
            x, y = truth[stamp_ns]
            position = odom.pose.pose.position
            assert math.hypot(position.x - x, position.y - y) < 0.005, f"t = {stamp_ns} ns"
            compared += 1
    assert compared > 50
    wheels = [
        ros_client.TYPESTORE.deserialize_cdr(s.payload, "sensor_msgs/msg/JointState")
        for s in samples
        if s.key == _key("joint_states")
    ]
    assert np.all(np.diff([state.position[0] for state in wheels]) >= -1e-9), (
        "the straight line turns the wheels forward"
    )
