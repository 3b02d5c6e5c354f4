"""The localization stub on a plant with no ground truth of its own (docs/plant.md section 3):
a synthetic plant publishes only its wheel angles and clock, and a separate tracker process
(motion capture) publishes the body's pose on ``sim/body_pose``, unmarked, stamped on the plant's
clock, at its own rate. The real motor turns it into the axle centre's pose through its offsets
and the real localization stub hands that to odometry as its fixes (docs/protocol.md section 14).
"""

from __future__ import annotations

import math

import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from services.planar import wrap_angle
from tests.harness import Collector, InventProcess, open_peer, wait_alive, wait_until
from tests.sim_presence import SimPresence

KEYS = Keys()
CYCLE_NS = 5_000_000
"""The plant's control cycle: 200 Hz, as a serial driver might run."""
TRACKER_EVERY = 4
"""The tracker reports every fourth cycle (50 Hz), at its own moments."""
MARKER = (0.10, 0.02, 0.3)
"""Where the tracked body sits on the robot: ahead of and left of the axle centre, turned."""


def axle_pose(k: int) -> tuple[float, float, float]:
    """The robot's true axle pose at cycle k: driving a slow arc."""
    return 0.5 + 0.001 * k, -0.2 + 0.0005 * k, wrap_angle(0.4 + 0.002 * k)


def tracked_pose(k: int) -> list[float]:
    """What the tracker reports at cycle k: the marker's frame, 12 values (position, rotation)."""
    x, y, theta = axle_pose(k)
    dx, dy, dtheta = MARKER
    # The motor's offsets take the axle centre from the tracked frame: axle = marker + R(θm)·offset,
    # θ = θm + Δθ. The tracked frame here is the axle's moved and turned back by the same amounts.
    marker_theta = theta - dtheta
    offset_x = -(dx * math.cos(marker_theta) - dy * math.sin(marker_theta))
    offset_y = -(dx * math.sin(marker_theta) + dy * math.cos(marker_theta))
    c, s = math.cos(marker_theta), math.sin(marker_theta)
    return [x + offset_x, y + offset_y, 0.06, c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0]


def test_a_tracker_on_sim_body_pose_gives_the_localization_stub_its_fixes(
    endpoint: str, session: zenoh.Session
) -> None:
    dx, dy, dtheta = MARKER
    offsets = (
        f"motor.simulated_offset_x={dx}",
        f"motor.simulated_offset_y={dy}",
        f"motor.simulated_offset_angle={dtheta}",
    )
    flags = ("--connect", endpoint, "--log-level", "warning")
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    with (
        SimPresence(endpoint, KEYS),
        InventProcess("motor", *flags, *(f for offset in offsets for f in ("--set", offset))),
        InventProcess("localization", *flags, "--rate", "10"),
    ):
        wait_alive(session, KEYS.alive(Service.MOTOR))
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        tracker = open_peer(endpoint)
        try:
            wheels = session.declare_publisher(KEYS.sim_wheel_angles)
            clock = session.declare_publisher(KEYS.sim_clock)
            poses = tracker.declare_publisher(KEYS.sim_body_pose)
            torques = Collector(session, KEYS.motor_torque, TimedDoubleSeq)
            wait_until(lambda: wheels.matching_status.matching, what="the motor's wheel-angle subscriber")
            wait_until(lambda: poses.matching_status.matching, what="the motor's body-pose subscriber")
            received: list[TimedPosition] = []
            k = 0
            while len(received) < 4:
                assert k < 2_000, f"only {len(received)} fixes after {k} cycles"
                sample = encode(TimedDoubleSeq(Time.from_nanoseconds(k * CYCLE_NS), [0.01 * k, 0.01 * k]))
                wheels.put(sample)
                clock.put(sample)
                torques.get(timeout=5.0)  # the motor answered this cycle: its wheel-angle time is k
                if k % TRACKER_EVERY == 1:  # the tracker's moments are not the cycles' ticks
                    poses.put(encode(TimedDoubleSeq(Time.from_nanoseconds(k * CYCLE_NS - 1_000_000), tracked_pose(k))))
                received.extend(fixes.drain())
                k += 1
        finally:
            tracker.close()
    # The configured initial pose comes first only if the stub's first sample was within a fix period
    # of time 0 (its publisher may match the test's subscriber later): every other fix is the tracker's.
    if (received[0].x, received[0].y, received[0].theta) == (0.0, 0.0, 0.0):
        received.pop(0)
    assert len(received) >= 3
    for fix in received:
        cycle = round((fix.tm.to_nanoseconds() + 1_000_000) / CYCLE_NS)
        assert cycle % TRACKER_EVERY == 1, f"fix at {fix.tm} is not one of the tracker's samples"
        x, y, theta = axle_pose(cycle)
        assert math.isclose(fix.x, x, abs_tol=1e-9), (fix, x)
        assert math.isclose(fix.y, y, abs_tol=1e-9), (fix, y)
        assert math.isclose(fix.theta, theta, abs_tol=1e-9), (fix, theta)
