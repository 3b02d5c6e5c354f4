"""Well-formed but wrong input, as a buggy or hostile publisher sends it, into the running loop.

One realtime ``invent up --scenario square`` (realtime: the mode where forged stamps and torques
did the damage) while this test injects, from its own session, every input measured breaking
the loop before: far-future and absurd stamps on each time base, a forged torque from the future,
absurd gains and velocities, fixes stamped 0 or placed at 1e308 m, a wheel-angle jump of 10^6 rad,
10^6-element arrays, and floods. Afterwards the square must still come home within the e2e
bounds, every service must have counted what it refused, and none may have hung.
"""

from __future__ import annotations

import json
import math
import re
import threading
import time
from pathlib import Path

import pytest
import zenoh

from schemas.codec import encode
from schemas.keys import CONTROL, LOOP_SERVICES, Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition, TimedVelocity
from schemas.topics import Method, MethodFamily
from services.config import DriveConfig, LocalizationConfig
from tests.harness import call, free_port, peer_session, start_up, status_reply, wait_until

pytestmark = pytest.mark.slow

KEYS = Keys()
ROUNDS = 20
INJECT_AFTER_NS = 6_000_000_000
FAR_FUTURE_S = 100_000
ABSURD_SEC = 10**29
FLOOD_PAYLOAD_BYTES = 400_000
FLOOD_COUNT = 200
RSS_CEILING_MB = 300


class SimClock:
    """The newest ``sim/wheel_angles`` the loop published: the time base to forge against."""

    def __init__(self, session: zenoh.Session) -> None:
        self.latest: tuple[int, list[float]] | None = None
        self._subscriber = session.declare_subscriber(KEYS.sim_wheel_angles, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        if len(payload) > 1000:  # our own floods
            return
        message = json.loads(payload)
        if len(message["data"]) == 2 and message["tm"]["sec"] < FAR_FUTURE_S:  # not our own forgeries
            self.latest = (message["tm"]["sec"] * 1_000_000_000 + message["tm"]["nsec"], message["data"])

    def now(self) -> tuple[int, list[float]]:
        return wait_until(lambda: self.latest, 10, "the simulator's clock")


def _seq(stamp_ns: int, data: list[float]) -> bytes:
    return encode(TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), data))


def _raw_seq(sec: int, values: str) -> bytes:
    return f'{{"tm": {{"sec": {sec}, "nsec": 0}}, "data": [{values}]}}'.encode()


def _velocity(stamp_ns: int, vx: float, w: float = 0.0) -> bytes:
    return encode(TimedVelocity(Time.from_nanoseconds(stamp_ns), [], vx, 0.0, w, []))


def _position(stamp_ns: int, x: float) -> bytes:
    return encode(TimedPosition(Time.from_nanoseconds(stamp_ns), [], x, 0.0, 0.0, []))


def _rss_mb(pid: int) -> float:
    line = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("VmRSS"))
    return int(line.split()[1]) / 1024


def _inject(session: zenoh.Session, clock: SimClock) -> bool:
    """Every forgery of the measured list, each a few times (a newest-only or sampled input takes
    the newest sample, so one forged sample can be overwritten before it is looked at); True if
    the absurd gains were refused."""
    put = session.put
    for round_index in range(ROUNDS):
        now_ns, angles = clock.now()
        far_ns = FAR_FUTURE_S * 1_000_000_000
        # One far-future stamp froze the loop; with a (valid) target between it and a second one,
        # the sim applied [20, 20] N·m for good.
        put(KEYS.sim_wheel_angles, _seq(far_ns, angles))
        if round_index == 0:
            put(KEYS.drive_target_velocity, _velocity(now_ns, 1.0))
        put(KEYS.sim_wheel_angles, _seq(far_ns + 1_000_000, angles))
        put(KEYS.sim_clock, _seq(far_ns, angles))  # the drive's clock
        put(KEYS.motor_wheel_angles, _seq(far_ns, angles))
        put(KEYS.motor_sim_pose_localization, _seq(far_ns, [0.0, 0.0, 0.0, 0.0]))
        # A forged torque from the future hijacked the realtime sim.
        put(KEYS.motor_torque, _seq(now_ns + 10 * 1_000_000_000, [20.0, -20.0]))
        # tm.sec = 10^29 hung the drive's and the localization's schedules.
        put(KEYS.sim_wheel_angles, _raw_seq(ABSURD_SEC, "0.0, 0.0"))
        put(KEYS.sim_clock, _raw_seq(ABSURD_SEC, "0.0, 0.0"))
        put(KEYS.motor_sim_pose_localization, _raw_seq(ABSURD_SEC, "0.0, 0.0, 0.0, 0.0"))
        # Absurd but finite values.
        put(KEYS.drive_target_velocity, _velocity(now_ns, 1e300))
        put(KEYS.localization_pose, _position(0, 5.0))
        put(KEYS.localization_pose, _position(now_ns, 1e308))
        put(KEYS.sim_wheel_angles, _seq(now_ns + 50_000_000, [angle + 1e6 for angle in angles]))
        put(KEYS.motor_wheel_angles, _seq(now_ns + 50_000_000, [angle + 1e6 for angle in angles]))
        time.sleep(0.005)  # pacing the forgeries, not waiting for a condition
    ok, reply = call(
        session,
        KEYS.method(MethodFamily.GUI, Method.SET_PD_GAIN),
        json.dumps({"p_gain_l": 1e308, "p_gain_r": 1e308, "d_gain_l": 1e308, "d_gain_r": 1e308}),
    )
    return not ok and "max_gain" in json.dumps(reply)


def _flood(session: zenoh.Session, clock: SimClock, motor_pid: int) -> tuple[float, float]:
    """Unbounded work: huge arrays, then floods. Returns the motor's RSS before and after, in MB."""
    put = session.put
    million = ", ".join(["0.5"] * 1_000_000)
    now_ns, _angles = clock.now()
    tm = Time.from_nanoseconds(now_ns)
    put(KEYS.sim_wheel_angles, _raw_seq(tm.sec, million))
    put(
        KEYS.drive_target_velocity,
        f'{{"tm": {{"sec": {tm.sec}, "nsec": {tm.nsec}}}, "id": [{", ".join(["1"] * 1_000_000)}], '
        f'"vx": 0.1, "vy": 0.0, "w": 0.0, "error": []}}'.encode(),
    )
    rss_before = _rss_mb(motor_pid)
    big = _raw_seq(tm.sec, ", ".join(["0.25"] * (FLOOD_PAYLOAD_BYTES // 6)))
    for _ in range(FLOOD_COUNT):
        put(KEYS.sim_wheel_angles, big)
    for _ in range(10_000):
        put(KEYS.drive_target_velocity, _velocity(now_ns, 0.0))
    return rss_before, _rss_mb(motor_pid)


def _status(session: zenoh.Session, service: Service) -> dict:
    return status_reply(session, KEYS, service)


def refused(status: dict) -> dict[str, int]:
    """The bad-input count of each key a service's ``status`` names, by key relative to the robot."""
    return {key.removeprefix(KEYS.prefix + "/"): entry["count"] for key, entry in status["bad_input"]["by_key"].items()}


EXACTLY_REFUSED = {
    (Service.ODOMETRY, "motor/wheel_angles"): ROUNDS * 2,
    (Service.ODOMETRY, "localization/pose"): ROUNDS * 2,
    (Service.SIM, "motor/torque"): ROUNDS,
}
"""Forgeries every sample of which reaches a service's handler: each is refused exactly once."""


def _statuses_once_forgeries_are_handled(session: zenoh.Session) -> dict[Service, dict]:
    """Every service's status, once each has handled the forgeries it is counted for exactly.

    A status query overtakes the samples still queued in a loaded service's input (queries are
    handled first), so a status read right after the last put may miss the last few rounds."""

    def statuses_if_handled() -> dict[Service, dict] | None:
        statuses = {service: _status(session, service) for service in LOOP_SERVICES}
        handled = all(
            refused(statuses[service]).get(key, 0) >= count for (service, key), count in EXACTLY_REFUSED.items()
        )
        return statuses if handled else None

    return wait_until(statuses_if_handled, 30, "every service to handle the forgeries it was sent")


def test_forged_and_absurd_input_is_counted_and_the_square_still_comes_home(tmp_path):
    report_dir = tmp_path / "report"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    process = start_up("--scenario", "square", "--mode", "realtime", "--report", str(report_dir), "--listen", endpoint)
    output: list[str] = []
    reader = threading.Thread(target=lambda: output.extend(process.stdout), daemon=True)
    reader.start()
    try:
        wait_until(lambda: "started drive" in "".join(output) or process.poll() is not None, 120, "the drive")
        pids = {name: int(pid) for name, pid in re.findall(r"started (\w+) \(pid (\d+)\)", "".join(output))}
        with peer_session(endpoint) as session:
            clock = SimClock(session)
            # Well into the run, as measured: a fix stamped 0 is then older than odometry's history
            # (early on it is a genuine fix of where the robot was at time 0).
            wait_until(lambda: clock.now()[0] > INJECT_AFTER_NS, 60, "the run to be under way")
            absurd_gains_refused = _inject(session, clock)
            # Read while the run certainly goes on: the floods can take seconds on a loaded machine,
            # and once the drive has ended, ``up`` stops every service.
            statuses = _statuses_once_forgeries_are_handled(session)
            # realtime: the motor runs in invent control, composed with the sim (docs/realtime.md)
            rss_before, rss_after = _flood(session, clock, pids[CONTROL])
        process.wait(timeout=180)
    finally:
        if process.poll() is None:
            process.kill()
    reader.join(5)
    log = "".join(output)
    assert process.returncode == 0, log[-4000:]

    report = json.loads((report_dir / "report.json").read_text())
    start, end = report["start"], report["final"]["ground_truth"]
    assert math.hypot(end["x"] - start["x"], end["y"] - start["y"]) < 0.05, log[-3000:]
    assert report["path_error"]["max_m"] < 0.10, log[-6000:]
    assert report["odometry_error"]["max_m"] < 0.05
    final_fix = report["final"]["localization"]
    # The last genuine fix is at most one fix period before the end, in which the robot drives at
    # most its cruise speed (it brakes into the goal, so usually far less); the forged fixes were
    # placed 5 m and 1e308 m away.
    fix_period_travel_m = DriveConfig().cruise_speed / LocalizationConfig().rate
    assert math.hypot(final_fix["x"] - end["x"], final_fix["y"] - end["y"]) <= fix_period_travel_m, (
        "the report leaves out the fixes every service refused"
    )

    motor, localization = refused(statuses[Service.MOTOR]), refused(statuses[Service.LOCALIZATION])
    assert motor["sim/wheel_angles"] >= ROUNDS * 4, motor  # two far-future, one absurd, one jump a round
    assert motor["drive/target_velocity"] >= 1, motor
    assert absurd_gains_refused and motor["motor/gui/set_pd_gain"] == 1
    for (service, key), count in EXACTLY_REFUSED.items():
        assert refused(statuses[service])[key] == count, (service, key, statuses[service]["bad_input"])
    assert localization["motor/sim_pose/localization"] >= 1, localization
    assert refused(statuses[Service.DRIVE])["sim/clock"] >= 1
    for service, status in statuses.items():
        assert status["internal_errors"] == 0, (service, status)
    assert statuses[Service.MOTOR]["gains"]["p_gain_l"] == 5.0
    assert rss_after < RSS_CEILING_MB, f"the motor's memory grew from {rss_before:.0f} to {rss_after:.0f} MB"
