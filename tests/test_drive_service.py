"""``invent drive`` in its own process, in a synthetic loop played by the test.

The test is the simulator's clock (``sim/wheel_angles`` stamps, one per drive tick) and an
ideal unicycle plant that integrates each received command over the tick and publishes the
result as ``odometry/pose``. It waits for the command of every tick before the next one, so
the loop runs in lockstep.
"""

from __future__ import annotations

import itertools
import math

import pytest
import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition, TimedVelocity
from services.config import DriveConfig
from services.drive.path_following import Command
from services.drive.service import FINAL_ZERO_TICKS
from services.planar import Pose
from tests.harness import Collector, InventProcess, call, status_reply, wait_alive, wait_until
from tests.sim_presence import SimPresence
from tests.test_path_following import unicycle

KEYS = Keys()
DRIVE = DriveConfig()
TICK_NS = round(1e9 / DRIVE.rate)


class SyntheticLoop:
    def __init__(self, session: zenoh.Session, commands: Collector) -> None:
        self.commands = commands
        self.clock = session.declare_publisher(KEYS.sim_clock)
        self.odometry = session.declare_publisher(KEYS.odometry_pose)
        wait_until(lambda: self.clock.matching_status.matching, what="the drive's clock subscriber")
        wait_until(lambda: self.odometry.matching_status.matching, what="the drive's pose subscriber")
        self.now_ns = 0
        self.clock_attachment: bytes | None = None
        """The clock's attachment: a lockstep mark makes the drive wait for each tick's pose."""
        self.odometry_running = True
        self.pose = Pose(0.0, 0.0, 0.0)
        self.trajectory = [self.pose]

    def publish_tick(self, stamp_ns: int | None = None) -> None:
        """The pose at ``now``, then the clock: the drive computes its command with this pose."""
        tm = Time.from_nanoseconds(self.now_ns if stamp_ns is None else stamp_ns)
        if self.odometry_running:
            x, y, theta = self.pose
            self.odometry.put(encode(TimedPosition(tm=tm, id=[], x=x, y=y, theta=theta, error=[])))
        self.clock.put(encode(TimedDoubleSeq(tm=tm, data=[0.0, 0.0])), attachment=self.clock_attachment)

    def first_command(self) -> TimedVelocity:
        """Tick until the drive starts (it waits until its own publisher matches ours)."""
        for _ in range(100):
            self.publish_tick()
            try:
                return self.commands.get(timeout=0.25)
            except AssertionError:
                self.now_ns += TICK_NS
        raise AssertionError("the drive never published")

    def next_command(self, previous: TimedVelocity) -> TimedVelocity:
        """Move the plant one tick under ``previous``, tick, and return the drive's answer."""
        self.pose = unicycle(self.pose, Command(previous.vx, previous.w), TICK_NS / 1e9)
        self.trajectory.append(self.pose)
        self.now_ns += TICK_NS
        self.publish_tick()
        command = self.commands.get(timeout=5.0)
        assert command.tm.to_nanoseconds() == self.now_ns, "one command per tick, stamped with the tick's sim time"
        return command

    def until_final_zeros(self, first: TimedVelocity, max_ticks: int = 2000) -> list[TimedVelocity]:
        received = [first]
        while not _ends_with_zeros(received, FINAL_ZERO_TICKS):
            assert len(received) < max_ticks, "the drive never ended"
            received.append(self.next_command(received[-1]))
        return received


def _ends_with_zeros(commands: list[TimedVelocity], count: int) -> bool:
    tail = commands[-count:]
    return len(tail) == count and all((c.vx, c.vy, c.w) == (0.0, 0.0, 0.0) for c in tail)


def drive(endpoint: str, *flags: str) -> InventProcess:
    return InventProcess("drive", "--connect", endpoint, "--log-level", "warning", *flags)


def test_constant_velocity_for_one_simulated_second_then_zero_and_exit_0(endpoint: str, session: zenoh.Session) -> None:
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)
    with drive(endpoint, "--vx", "0.3", "--w", "0.1", "--for", "1") as process:
        wait_alive(session, KEYS.alive(Service.DRIVE))
        loop = SyntheticLoop(session, commands)
        first = loop.first_command()
        start_ns = first.tm.to_nanoseconds()
        received = [first] + [loop.next_command(first) for _ in range(4)]

        loop.publish_tick(stamp_ns=loop.now_ns)  # a repeated clock stamp: bad input, no command
        ok, status = wait_until(
            lambda: (reply := call(session, KEYS.status(Service.DRIVE)))[1]["bad_input"]["total"] == 1 and reply,
            what="the repeated stamp counted",
        )
        assert ok and commands.drain() == []
        progress = (status["mode"], status["state"], status["segment_index"], status["done"])
        assert progress == ("constant", "running", 0, False)
        assert status["command"] == {"vx": 0.3, "w": 0.1}
        assert status["elapsed_s"] == pytest.approx(4 * TICK_NS / 1e9)

        received += loop.until_final_zeros(received[-1])[1:]
        assert process.process.wait(timeout=10) == 0, process.stop()[2]

    ticks_per_second = round(DRIVE.rate)
    expected = [(0.3, 0.0, 0.1)] * ticks_per_second + [(0.0, 0.0, 0.0)] * FINAL_ZERO_TICKS
    assert [(c.vx, c.vy, c.w) for c in received] == expected
    assert [c.tm.to_nanoseconds() - start_ns for c in received] == [k * TICK_NS for k in range(len(received))]
    assert received[ticks_per_second].tm.to_nanoseconds() - start_ns == 1_000_000_000, "zero 1 s of sim time later"


def test_a_twist_is_held_until_stopped_stamped_with_simulation_time(endpoint: str, session: zenoh.Session) -> None:
    """``--twist VX W`` is a target by hand the motor takes: stamped with the simulation's time
    (here 100 s in, far past the motor's command timeout), on every tick, until Ctrl-C."""
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)
    with drive(endpoint, "--twist", "0.2", "-0.5") as process:
        wait_alive(session, KEYS.alive(Service.DRIVE))
        loop = SyntheticLoop(session, commands)
        loop.now_ns = 100_000_000_000
        first = loop.first_command()
        start_ns = first.tm.to_nanoseconds()
        ticks = round(2.5 * DRIVE.rate)  # beyond the 1 s pass it plays over and over
        received = [first] + [loop.next_command(first) for _ in range(ticks)]
        status = call(session, KEYS.status(Service.DRIVE))[1]
        assert (status["mode"], status["state"], status["done"], status["loop"]) == ("twist", "running", False, True)
        assert process.process.poll() is None, "a twist runs until stopped"
        assert process.stop()[0] == 0

    assert start_ns >= 100_000_000_000
    assert {(c.vx, c.vy, c.w) for c in received} == {(0.2, 0.0, -0.5)}
    assert [c.tm.to_nanoseconds() - start_ns for c in received] == [k * TICK_NS for k in range(len(received))]


def test_waypoints_reach_a_1m_straight_goal_in_the_loop(endpoint: str, session: zenoh.Session) -> None:
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)
    with drive(endpoint, "--waypoints", "1,0") as process:
        wait_alive(session, KEYS.alive(Service.DRIVE))
        loop = SyntheticLoop(session, commands)
        received = loop.until_final_zeros(loop.first_command())
        assert process.process.wait(timeout=10) == 0, process.stop()[2]

    assert math.dist((loop.pose.x, loop.pose.y), (1.0, 0.0)) <= DRIVE.goal_tolerance
    assert max(abs(pose.y) for pose in loop.trajectory) < 0.01
    assert max(c.vx for c in received) == pytest.approx(DRIVE.cruise_speed)
    accelerations = [(b.vx - a.vx) * DRIVE.rate for a, b in itertools.pairwise(received)]
    assert max(abs(a) for a in accelerations) <= DRIVE.max_acceleration + 1e-9, "ramped, so the wheels do not slip"


def test_a_path_pauses_while_the_pose_is_stale_and_resumes_from_rest(endpoint: str, session: zenoh.Session) -> None:
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)
    with drive(endpoint, "--waypoints", "5,0") as process:
        wait_alive(session, KEYS.alive(Service.DRIVE))
        loop = SyntheticLoop(session, commands)
        command = loop.first_command()
        for _ in range(round(DRIVE.rate)):
            command = loop.next_command(command)
        assert command.vx > 0.2

        loop.odometry_running = False
        last_pose_ns = loop.now_ns
        stale = []
        while loop.now_ns - last_pose_ns <= DRIVE.pose_timeout * 1e9 + 2 * TICK_NS:
            command = loop.next_command(command)
            stale.append((loop.now_ns - last_pose_ns, command.vx))
        assert all(vx > 0.0 for age, vx in stale if age <= DRIVE.pose_timeout * 1e9), "a late pose is still used"
        assert all(vx == 0.0 for age, vx in stale if age > DRIVE.pose_timeout * 1e9), "a stale one stops the robot"
        ok, status = call(session, KEYS.status(Service.DRIVE))
        assert ok and status["state"] == "waiting_for_pose" and status["pose_age_s"] > DRIVE.pose_timeout

        loop.odometry_running = True
        resumed = [loop.next_command(command)]
        resumed += [loop.next_command(resumed[-1]) for _ in range(5)]
        assert resumed[-1].vx > 0.0
        steps = [b.vx - a.vx for a, b in zip([command, *resumed], resumed)]
        assert max(steps) <= DRIVE.max_acceleration / DRIVE.rate + 1e-9, "resumes with a ramp from rest"
        code, _out, err = process.stop()
    assert code == 0, err


def test_a_restarted_simulator_starts_the_scenario_over(endpoint: str, session: zenoh.Session) -> None:
    commands = Collector(session, KEYS.drive_target_velocity, TimedVelocity)

    def drive_status() -> dict:
        return status_reply(session, KEYS, Service.DRIVE)

    with drive(endpoint, "--vx", "0.3", "--w", "0.1", "--for", "1") as process:
        wait_alive(session, KEYS.alive(Service.DRIVE))
        loop = SyntheticLoop(session, commands)
        with SimPresence(endpoint, KEYS) as first_sim:
            wait_until(lambda: drive_status()["sim_alive"], what="the drive to see the first simulator")
            loop.now_ns = 5_000_000_000
            command = loop.first_command()
            for _ in range(10):
                command = loop.next_command(command)
            assert drive_status()["elapsed_s"] == pytest.approx(10 * TICK_NS / 1e9)
            first_sim.leave(session)
        wait_until(lambda: not drive_status()["sim_alive"], what="the drive to see the simulator go")
        with SimPresence(endpoint, KEYS):
            wait_until(lambda: drive_status()["sim_alive"], what="the drive to see the second simulator")
            loop.now_ns = 0
            first = loop.first_command()
            status = drive_status()
            assert (status["time_base_restarts"], status["elapsed_s"], status["bad_input"]["total"]) == (1, 0.0, 0)
            received = loop.until_final_zeros(first)
            assert process.process.wait(timeout=10) == 0, process.stop()[2]

    ticks_per_second = round(DRIVE.rate)
    expected = [(0.3, 0.0, 0.1)] * ticks_per_second + [(0.0, 0.0, 0.0)] * FINAL_ZERO_TICKS
    assert [(c.vx, c.vy, c.w) for c in received] == expected, "the whole second, from the new clock's start"
    assert [c.tm.to_nanoseconds() for c in received] == [k * TICK_NS for k in range(len(received))]
