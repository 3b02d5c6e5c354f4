"""``invent odometry`` in its own process over real zenoh, checked against the core as a mirror.

One process serves the whole module (its start is the slow part). The :class:`OdometryLink`
keeps a local :class:`Odometry` in step with every input the service accepts, so each test
asserts its own behaviour whatever ran before it.
"""

from __future__ import annotations

import json
import math
import random
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from schemas.topics import Topic
from services.clock.lockstep import encode_mark
from services.config import load_config
from services.odometry.core import Branch, Odometry, Step
from tests.harness import (
    Collector,
    InventProcess,
    peer_session,
    refused,
    run_invent,
    running_router,
    status_reply,
    wait_alive,
    wait_until,
)
from tests.sim_presence import SimPresence

ROBOT = "odo1"
OVERRIDES = {
    "robot.left_wheel_id": 2,
    "robot.right_wheel_id": 0,
    "robot.radius_of_left_wheel": 0.12,
    "robot.radius_of_right_wheel": 0.12,
    "odometry.left_radius_scale": 0.95,
    "odometry.right_radius_scale": 0.95,
    "odometry.axle_scale": 1.1,
    "input.max_wheel_speed": 2000.0,
}
"""Non-default wheel ids, radii and calibration, to show the service reads them. Equal wheels and
dyadic angle increments (exact in binary) let equal increments take the exact straight branch.
The sequences turn the wheels up to 1 rad per ms: a wheel-speed bound that lets them through."""
DYADIC = 2.0**-24
WHEEL_COUNT = 3
STEP_NS = 10_000_000
FIRST_TM = Time(100, 0)


def wheel_data(q_left: float, q_right: float) -> list[float]:
    """A wheel-angle sequence with the left wheel at id 2 and the right at id 0."""
    return [q_right, -7.0, q_left]


class OdometryLink:
    """The test's side of the service: publishers, the pose collector and the mirror core."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.session = session
        self.keys = keys
        self.poses = Collector(session, keys.odometry_pose, TimedPosition)
        json_encoding = zenoh.Encoding.APPLICATION_JSON
        self.wheels = session.declare_publisher(keys.motor_wheel_angles, encoding=json_encoding)
        self.localization = session.declare_publisher(keys.localization_pose, encoding=json_encoding)
        config = load_config(overrides=OVERRIDES)
        self.mirror = Odometry(config.robot, config.odometry, limits=config.input)
        self.time_ns = FIRST_TM.to_nanoseconds()
        self.q_left = self.q_right = 0.0

    def wait_matched(self) -> None:
        for publisher in (self.wheels, self.localization):
            wait_until(lambda p=publisher: p.matching_status.matching, what=f"a subscriber on {publisher.key_expr}")

    def send_wheels(self, time_ns: int, q_left: float, q_right: float) -> tuple[Step, TimedPosition]:
        """Publish one valid sample; return the mirror's step and the pose the service published."""
        tm = Time.from_nanoseconds(time_ns)
        self.wheels.put(encode(TimedDoubleSeq(tm=tm, data=wheel_data(q_left, q_right))))
        expected = self.mirror.step(time_ns, wheel_data(q_left, q_right))
        self.time_ns, self.q_left, self.q_right = time_ns, q_left, q_right
        received = self.poses.get(timeout=5.0)
        assert received.tm == tm
        return expected, received

    def advance(self, dq_left: float, dq_right: float, dt_ns: int = STEP_NS) -> tuple[Step, TimedPosition]:
        return self.send_wheels(self.time_ns + dt_ns, self.q_left + dq_left, self.q_right + dq_right)

    def status(self) -> dict[str, Any]:
        return status_reply(self.session, self.keys, Service.ODOMETRY)

    def bad_input_count(self, key: str) -> int:
        entry = self.status()["bad_input"]["by_key"].get(key)
        return entry["count"] if entry else 0

    def put_bad(self, publisher: zenoh.Publisher, payload: bytes) -> str:
        """Publish a bad payload, wait until the service counts it, return its logged reason."""
        key = str(publisher.key_expr)
        before = self.bad_input_count(key)
        publisher.put(payload)
        wait_until(lambda: self.bad_input_count(key) == before + 1, what=f"bad input counted on {key}")
        return self.status()["bad_input"]["by_key"][key]["last_reason"]


def assert_published(step: Step, pose: TimedPosition) -> None:
    assert (pose.x, pose.y, pose.theta) == (step.x, step.y, step.theta)


@pytest.fixture(scope="module")
def module_endpoint() -> Iterator[str]:
    """A router for this module's one service process."""
    with running_router() as endpoint:
        yield endpoint


@pytest.fixture(scope="module")
def module_session(module_endpoint: str) -> Iterator[zenoh.Session]:
    with peer_session(module_endpoint) as peer:
        yield peer


@pytest.fixture(scope="module")
def trace_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("odometry") / "trace.jsonl"


@pytest.fixture(scope="module")
def started(module_endpoint: str, module_session: zenoh.Session, trace_path: Path) -> Iterator[dict[str, Any]]:
    """The running service, and what it did at start: status before and the first sample's pose."""
    link = OdometryLink(module_session, Keys(ROBOT))
    flags = [item for key, value in OVERRIDES.items() for item in ("--set", f"{key}={value}")]
    with InventProcess(
        "odometry", "--connect", module_endpoint, "--robot", ROBOT, "--trace", str(trace_path), *flags
    ) as process:
        wait_alive(module_session, link.keys.alive(Service.ODOMETRY))
        link.wait_matched()
        status_before = link.status()
        first = link.send_wheels(link.time_ns, 0.0, 0.0)
        yield {"link": link, "status_before": status_before, "first": first, "status_after": link.status()}
        code, _out, err = process.stop()
        assert code == 0, err


@pytest.fixture
def link(started: dict[str, Any]) -> OdometryLink:
    return started["link"]


def trace_lines(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_first_sample_publishes_the_starting_pose_with_its_tm(started: dict[str, Any]) -> None:
    assert started["status_before"]["state"] == "idle"
    step, pose = started["first"]
    assert step.branch is Branch.INITIAL
    assert pose.tm == FIRST_TM
    assert (pose.x, pose.y, pose.theta) == (0.0, 0.0, 0.0)
    assert started["status_after"]["state"] == "running"


def test_poses_equal_the_cores_for_a_sample_sequence(link: OdometryLink) -> None:
    rng = random.Random(4)
    increments = [(0.25, 0.25), (0.25, 0.25), (0.0, 0.0), (-0.5, 0.5), (0.5, 0.5 + DYADIC), (0.5, 0.5 + 2**-8)]
    increments += [(0.125, 0.375), (-0.25, -0.375), (-0.25, -0.25)]
    increments += [(rng.randint(-1024, 1024) / 1024, rng.randint(-1024, 1024) / 1024) for _ in range(40)]
    branches = set()
    for dq_left, dq_right in increments:
        step, pose = link.advance(dq_left, dq_right, dt_ns=rng.choice([1_000_000, STEP_NS, 3 * STEP_NS]))
        assert_published(step, pose)
        branches.add(step.branch)
    assert branches == {Branch.STRAIGHT, Branch.RHO_BORDER, Branch.SMALL_ANGLE, Branch.CHORD}


def test_every_sample_is_integrated_and_only_observed_steps_publish_a_pose(link: OdometryLink) -> None:
    """The motor passes the simulator's step mark on: a step that is not observed is integrated
    all the same but publishes nothing; the next observed step's pose includes it."""
    unobserved, observed_step = encode_mark(None, observed=False), encode_mark(None, observed=True)
    samples = link.status()["counters"]["wheel_angle_samples"]
    steps = []
    for k, mark in enumerate((unobserved, unobserved, observed_step), start=1):
        time_ns = link.time_ns + k * STEP_NS
        q_left, q_right = link.q_left + k * 0.01, link.q_right + k * 0.02
        link.wheels.put(
            encode(TimedDoubleSeq(Time.from_nanoseconds(time_ns), wheel_data(q_left, q_right))), attachment=mark
        )
        steps.append((time_ns, q_left, q_right))
    poses = [link.poses.get(timeout=5.0)]
    for time_ns, q_left, q_right in steps:
        expected = link.mirror.step(time_ns, wheel_data(q_left, q_right))
    link.time_ns, link.q_left, link.q_right = steps[-1]
    assert poses[0].tm == Time.from_nanoseconds(steps[-1][0]), "the observed step's pose"
    assert_published(expected, poses[0])
    assert link.poses.drain() == [], "no pose for the steps that are not observed"
    assert link.status()["counters"]["wheel_angle_samples"] == samples + 3, "every sample integrated"


def test_localization_pose_resets_the_pose(link: OdometryLink) -> None:
    before = link.status()["counters"]["localization_resets"]
    stamp = Time.from_nanoseconds(link.time_ns)  # the last sample's time: a plain overwrite
    link.localization.put(encode(TimedPosition(tm=stamp, id=[], x=3.0, y=-4.0, theta=4.0, error=[])))
    expected_pose = link.mirror.reset(3.0, -4.0, 4.0)
    assert expected_pose.theta == pytest.approx(4.0 - 2 * math.pi)
    wait_until(lambda: link.status()["counters"]["localization_resets"] == before + 1, what="the reset counted")
    assert link.status()["pose"] == expected_pose._asdict()
    step, pose = link.advance(0.25, 0.625)
    assert_published(step, pose)
    assert math.hypot(pose.x - 3.0, pose.y + 4.0) < 0.1


def raw_wheels(time_ns: int, values: str) -> bytes:
    """A wheel-angle payload written by hand, so it can carry what the encoder refuses to write."""
    tm = Time.from_nanoseconds(time_ns)
    return f'{{"tm": {{"sec": {tm.sec}, "nsec": {tm.nsec}}}, "data": [{values}]}}'.encode()


BAD_WHEEL_ANGLES = {
    # case: (payload given the last accepted sample's time, part of the reason the service logs)
    "dt_zero": (lambda last_ns: raw_wheels(last_ns, "1.0, 0.0, 1.0"), "<= 0"),
    "dt_negative": (lambda last_ns: raw_wheels(last_ns - STEP_NS, "1.0, 0.0, 1.0"), "<= 0"),
    "nan_literal": (lambda last_ns: raw_wheels(last_ns + STEP_NS, "NaN, 0.0, 1.0"), "not JSON"),
    "overflow_to_inf": (lambda last_ns: raw_wheels(last_ns + STEP_NS, "0.0, 0.0, 1e999"), "out of range"),
    "too_short_for_the_wheel_ids": (lambda last_ns: raw_wheels(last_ns + STEP_NS, "1.0, 1.0"), "need at least 3"),
    "garbage": (lambda _last_ns: b"\x00\xffnot json at all", "not JSON"),
    "wrong_schema": (lambda _last_ns: b'{"tm": {"sec": 1, "nsec": 0}, "angles": [1.0]}', "field"),
}


@pytest.mark.parametrize("case", BAD_WHEEL_ANGLES)
def test_bad_wheel_angles_are_rejected_counted_and_the_service_keeps_going(link: OdometryLink, case: str) -> None:
    make_payload, reason = BAD_WHEEL_ANGLES[case]
    samples_before = link.status()["counters"]["wheel_angle_samples"]
    assert reason in link.put_bad(link.wheels, make_payload(link.time_ns))
    assert link.status()["counters"]["wheel_angle_samples"] == samples_before
    step, pose = link.advance(0.0625, 0.125)
    assert_published(step, pose)


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b'{"tm": {"sec": 1, "nsec": 0}, "id": [], "x": NaN, "y": 0.0, "theta": 0.0, "error": []}', "not JSON"),
        (b'{"tm": {"sec": 1, "nsec": 0}, "id": [], "x": 0.0, "y": -1e999, "theta": 0.0, "error": []}', "out of range"),
        (b"garbage", "not JSON"),
    ],
)
def test_bad_localization_pose_is_rejected_counted_and_changes_nothing(
    link: OdometryLink, payload: bytes, reason: str
) -> None:
    resets_before = link.status()["counters"]["localization_resets"]
    assert reason in link.put_bad(link.localization, payload)
    status = link.status()
    assert status["counters"]["localization_resets"] == resets_before
    assert status["pose"] == link.mirror.pose._asdict()
    step, pose = link.advance(-0.125, 0.125)
    assert_published(step, pose)


def test_status_reports_pose_velocity_parameters_and_counters(link: OdometryLink) -> None:
    before = link.status()
    step, _ = link.advance(0.375, 0.875)
    status = link.status()
    assert status["state"] == "running"
    assert status["pose"] == {"x": step.x, "y": step.y, "theta": step.theta}
    assert status["velocity"] == {"v": step.v, "omega": step.omega}
    assert status["last_wheel_angles_tm"] == {"sec": link.time_ns // 10**9, "nsec": link.time_ns % 10**9}
    counters, counted_before = status["counters"], before["counters"]
    assert counters["wheel_angle_samples"] == counted_before["wheel_angle_samples"] + 1
    assert counters["branches"][step.branch] == counted_before["branches"][step.branch] + 1
    parameters = status["parameters"]
    assert (parameters["left_wheel_id"], parameters["right_wheel_id"]) == (2, 0)
    assert parameters["left_radius"] == parameters["right_radius"] == pytest.approx(0.12 * 0.95)
    assert parameters["half_axle"] == pytest.approx(0.441 * 1.1 / 2)
    assert parameters["rotation_angle_border"] == pytest.approx(math.pi / 180)
    assert parameters["rho_border"] == 10000.0


def test_a_reconnected_simulator_costs_nothing_and_a_restarted_one_starts_from_the_kept_pose(
    link: OdometryLink, module_endpoint: str, module_session: zenoh.Session
) -> None:
    """The simulator's token comes back while its clock goes on (a reconnection): every sample is
    integrated as if nothing happened, and a lockstep sample held for its fix when the token comes
    back is integrated once the fix comes. Then two new simulators in turn, each clock starting at 0
    (the first after samples at 100 s and later), each run's first fix arriving before its first
    sample: the sample initialises again from the pose reached, and the fix is applied, not refused."""
    before = link.status()
    counters = before["counters"]
    inputs_taken = before["inputs"][link.keys.localization_pose]["samples"]

    def sim_alive(alive: bool) -> None:
        wait_until(lambda: link.status()["sim_alive"] is alive, what=f"the odometry to see sim_alive {alive}")

    with SimPresence(module_endpoint, link.keys) as sim:
        sim_alive(True)
        for k in range(1, 4):
            step, pose = link.advance(0.25, 0.25 + k * 2**-6)
            assert step.branch is not Branch.INITIAL, "a reconnection starts no new time base"
            assert_published(step, pose)
        sim.leave(module_session)
        sim_alive(False)
    # Lockstep: a sample held for its fix, then the token appears (the clock now decides) before the
    # fix comes. The fix is of the old time base: taken at once, not kept for a next sample.
    held_ns, fix_ns = link.time_ns + STEP_NS, link.time_ns + STEP_NS // 2
    q_left, q_right = link.q_left + 0.25, link.q_right + 0.25 + 2**-6
    held = TimedDoubleSeq(Time.from_nanoseconds(held_ns), wheel_data(q_left, q_right))
    holds = link.status()["counters"]["lockstep_holds"]["held"]
    link.wheels.put(encode(held), attachment=encode_mark({Topic.LOCALIZATION_POSE: fix_ns}, observed=True))
    wait_until(lambda: link.status()["counters"]["lockstep_holds"]["held"] == holds + 1, what="the sample to be held")
    with SimPresence(module_endpoint, link.keys) as sim:
        sim_alive(True)
        fix = (0.5, 0.25, 0.125)
        link.localization.put(encode(TimedPosition(Time.from_nanoseconds(fix_ns), [], *fix, [])))
        inputs_taken += 1
        link.mirror.reset_at(fix_ns, *fix)
        step = link.mirror.step(held_ns, held.data)
        pose = link.poses.get(timeout=5.0)
        assert pose.tm == held.tm
        assert_published(step, pose)
        link.time_ns, link.q_left, link.q_right = held_ns, q_left, q_right
        sim.leave(module_session)
        sim_alive(False)
    for run in (1, 2):
        with SimPresence(module_endpoint, link.keys) as sim:
            sim_alive(True)
            fix = (1.0 * run, -2.0, 0.5)
            link.localization.put(encode(TimedPosition(Time(0, 0), [], *fix, [])))
            inputs_taken += 1
            wait_until(
                lambda taken=inputs_taken: link.status()["inputs"][link.keys.localization_pose]["samples"] == taken,
                what="the new run's first fix to reach the odometry",
            )
            kept = link.mirror.pose
            link.mirror = Odometry(
                link.mirror.robot, link.mirror.config, start=kept, limits=load_config(overrides=OVERRIDES).input
            )
            link.mirror.reset_at(0, *fix)
            step, pose = link.send_wheels(0, 4.0, -3.0)
            assert step.branch is Branch.INITIAL and (pose.x, pose.y, pose.theta) == kept
            for k in range(1, 6):
                step, pose = link.advance(0.25, 0.25 + k * 2**-6, dt_ns=1_000_000)
                assert_published(step, pose)
            assert math.hypot(pose.x - fix[0], pose.y - fix[1]) < 0.2 < math.dist(kept[:2], fix[:2]), "from the fix"
            sim.leave(module_session)
            sim_alive(False)
    after = link.status()
    assert after["bad_input"]["total"] == before["bad_input"]["total"], after["bad_input"]
    assert after["counters"]["time_base_restarts"] == counters["time_base_restarts"] + 2
    assert after["counters"]["localization_resets"] == counters["localization_resets"] + 3


def test_trace_writes_one_line_per_accepted_step(link: OdometryLink, trace_path: Path) -> None:
    first = trace_lines(trace_path)[0]
    assert first["branch"] == "initial" and first["tm"] == {"sec": FIRST_TM.sec, "nsec": FIRST_TM.nsec}
    lines_before = len(trace_lines(trace_path))
    steps = [link.advance(dq, 2 * dq)[0] for dq in (0.125, 0.25, 0.0, -0.375)]
    link.put_bad(link.wheels, b"garbage")
    lines = trace_lines(trace_path)
    assert len(lines) == lines_before + len(steps)
    for line, step in zip(lines[lines_before:], steps, strict=True):
        assert line["branch"] == step.branch
        assert (line["q_left"], line["q_right"], line["dt"], line["dphi"], line["dl"]) == (
            step.q_left,
            step.q_right,
            step.dt,
            step.dphi,
            step.dl,
        )
        assert (line["x"], line["y"], line["theta"]) == (step.x, step.y, step.theta)
        assert line["localization_resets"] == link.status()["counters"]["localization_resets"]


def test_bad_config_exits_2_naming_the_field(capsys) -> None:
    code, _out, err = refused(capsys, "odometry", "--set", "odometry.rho_border=-1")
    assert code == 2
    assert "rho_border" in err


def test_unwritable_trace_file_exits_2_naming_the_flag(module_endpoint: str, tmp_path: Path) -> None:
    result = run_invent("odometry", "--connect", module_endpoint, "--trace", str(tmp_path / "missing" / "trace.jsonl"))
    assert result.returncode == 2
    assert "--trace" in result.stderr
