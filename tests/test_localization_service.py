"""``invent localization`` in its own process over real zenoh, fed synthetic simulated poses.

The service samples the newest pose (a ring of one), so the test waits for each fix right
after publishing the sample that falls on its tick; the samples between ticks may be skipped.
"""

from __future__ import annotations

import numpy as np
import pytest
import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from services.localization.core import Localizer, Noise
from services.planar import Pose, wrap_angle
from tests.harness import Collector, InventProcess, refused, status_reply, wait_alive, wait_until
from tests.sim_presence import SimPresence

KEYS = Keys()
STEP_NS = 10_000_000
"""The synthetic simulator publishes a pose every 10 ms of simulation time."""
SAMPLES_PER_SECOND = 100


def sim_pose(k: int) -> list[float]:
    return [0.002 * k, 0.001 * k, 0.05, wrap_angle(0.01 * k)]


def sample(k: int) -> TimedDoubleSeq:
    return TimedDoubleSeq(tm=Time.from_nanoseconds(k * STEP_NS), data=sim_pose(k))


def start_stream(session: zenoh.Session, fixes: Collector) -> tuple[zenoh.Publisher, int, TimedPosition]:
    """Publish samples one by one until the initial pose comes back; return (publisher, its k, the pose).

    The service starts its schedule only once its publisher matches ours, so the first
    samples may pass unanswered.
    """
    publisher = session.declare_publisher(KEYS.motor_sim_pose_localization)
    wait_until(lambda: publisher.matching_status.matching, what="the localization subscriber")
    for k in range(200):
        publisher.put(encode(sample(k)))
        try:
            initial = fixes.get(timeout=0.25)
        except AssertionError:
            continue
        return publisher, k, initial
    raise AssertionError("no initial pose after 200 samples")


def play(
    publisher: zenoh.Publisher, fixes: Collector, k0: int, count: int, samples_per_fix: int
) -> list[TimedPosition]:
    """Publish samples k0+1 .. k0+count; wait for the fix after each sample that falls on a tick."""
    received = []
    for k in range(k0 + 1, k0 + count + 1):
        publisher.put(encode(sample(k)))
        if (k - k0) % samples_per_fix == 0:
            received.append(fixes.get(timeout=5.0))
    return received


def localization_status(session: zenoh.Session) -> dict:
    return status_reply(session, KEYS, Service.LOCALIZATION)


def localization(endpoint: str, *flags: str) -> InventProcess:
    return InventProcess("localization", "--connect", endpoint, "--log-level", "warning", *flags)


def test_initial_pose_first_then_fixes_at_the_simulated_rate(endpoint: str, session: zenoh.Session) -> None:
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    with localization(endpoint, "--rate", "2", "--initial", "0.5", "-0.25", "0.1") as process:
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        publisher, k0, initial = start_stream(session, fixes)
        assert (initial.x, initial.y, initial.theta) == (0.5, -0.25, 0.1)
        assert initial.tm == Time.from_nanoseconds(k0 * STEP_NS)

        seconds, rate = 4, 2
        received = play(publisher, fixes, k0, seconds * SAMPLES_PER_SECOND, SAMPLES_PER_SECOND // rate)
        expected_k = [k0 + i * SAMPLES_PER_SECOND // rate for i in range(1, seconds * rate + 1)]
        assert len(received) == seconds * rate
        assert [fix.tm.to_nanoseconds() for fix in received] == [k * STEP_NS for k in expected_k]
        for fix, k in zip(received, expected_k):
            x, y, _z, theta = sim_pose(k)
            assert (fix.x, fix.y, fix.theta) == (x, y, theta)

        last = k0 + seconds * SAMPLES_PER_SECOND
        bad_inputs = [
            TimedDoubleSeq(tm=Time.from_nanoseconds((last + 1) * STEP_NS), data=[1.0, 2.0]),  # 2 values, not 4
            sample(last),  # a stamp not after the previous one
        ]
        for count, bad in enumerate(bad_inputs, start=1):
            publisher.put(encode(bad))
            wait_until(
                lambda count=count: localization_status(session)["bad_input"]["total"] == count,
                what=f"bad input {count} counted",
            )
        status = localization_status(session)
        assert status["fixes_published"] == 1 + seconds * rate
        assert status["rate_hz"] == 2.0
        assert status["state"] == "running"
        assert status["last_fix"]["t"] == pytest.approx(expected_k[-1] * STEP_NS / 1e9)
        assert fixes.drain() == [], "bad input must not produce a fix"
        code, _out, err = process.stop()
    assert code == 0, err


def test_seeded_noise_is_the_cores_noise_for_that_seed(endpoint: str, session: zenoh.Session) -> None:
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    with localization(endpoint, "--rate", "10", "--noise", "0.05", "0.04", "0.02", "--seed", "11") as process:
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        publisher, k0, _initial = start_stream(session, fixes)
        reference = Localizer(Pose(0.0, 0.0, 0.0), 10.0, Noise(0.05, 0.04, 0.02), np.random.default_rng(11))
        reference.on_sim_pose(k0 * STEP_NS, sim_pose(k0))
        expected = []
        for k in range(k0 + 1, k0 + 2 * SAMPLES_PER_SECOND + 1):
            if (fix := reference.on_sim_pose(k * STEP_NS, sim_pose(k))) is not None:
                expected.append((fix.stamp_ns, *fix.pose))
        received = play(publisher, fixes, k0, 2 * SAMPLES_PER_SECOND, SAMPLES_PER_SECOND // 10)
        assert [(f.tm.to_nanoseconds(), f.x, f.y, f.theta) for f in received] == expected
        assert any((x, y) != tuple(sim_pose(t // STEP_NS)[:2]) for t, x, y, _theta in expected), "noise was added"
        status = localization_status(session)
        assert status["seed"] == 11 and status["seed_from_config"]
        assert status["noise"] == {"x": 0.05, "y": 0.04, "theta": 0.02}
        code, _out, err = process.stop()
    assert code == 0, err


def test_a_restarted_simulator_takes_a_fix_at_once_and_restarts_the_schedule(
    endpoint: str, session: zenoh.Session
) -> None:
    fixes = Collector(session, KEYS.localization_pose, TimedPosition)
    with localization(endpoint, "--rate", "2", "--initial", "0.5", "-0.25", "0.1") as process:
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        publisher, k0, _initial = start_stream(session, fixes)
        play(publisher, fixes, k0, SAMPLES_PER_SECOND, SAMPLES_PER_SECOND // 2)
        with SimPresence(endpoint, KEYS):
            wait_until(lambda: localization_status(session)["sim_alive"], what="the localization to see the simulator")
            restart_k = 3  # the new clock starts again, long before the old one's last stamp
            publisher.put(encode(sample(restart_k)))
            first = fixes.get(timeout=5.0)
            assert first.tm == sample(restart_k).tm
            x, y, _z, theta = sim_pose(restart_k)
            assert (first.x, first.y, first.theta) == (x, y, theta), "a fix of the simulated pose, not the initial"
            # then the ticks of the grid anchored at 0, every 0.5 s: samples 50 and 100
            to_first_tick = 50 - restart_k
            received = play(publisher, fixes, restart_k, to_first_tick, to_first_tick)
            received += play(publisher, fixes, 50, 50, 50)
            assert [fix.tm for fix in received] == [sample(50).tm, sample(100).tm]
        status = localization_status(session)
        assert (status["fixes_published"], status["time_base_restarts"], status["bad_input"]["total"]) == (6, 1, 0)
        code, _out, err = process.stop()
    assert code == 0, err


def test_a_negative_noise_exits_2_naming_the_field(capsys) -> None:
    code, _out, err = refused(capsys, "localization", "--noise", "-0.1", "0", "0", "--connect", "tcp/127.0.0.1:1")
    assert code == 2
    assert "localization.noise_x" in err
