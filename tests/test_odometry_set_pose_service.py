"""``odometry/set_pose`` over real zenoh: ``invent odometry`` in its own process sets (and resets)
its pose on a query on exactly the key, refuses and counts bad requests, acts on no wildcard, and
in a secure deployment answers the operator only (a real router with the generated access control).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import msgspec
import pytest
import zenoh

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import SetOdometry, SetOdometryReply, Time
from services.security import Role, write_profile
from tests.harness import InventProcess, call, free_port, peer_session, running_router, wait_alive, wait_until
from tests.test_odometry_service import OVERRIDES, ROBOT, OdometryLink, assert_published


@pytest.fixture(scope="module")
def link() -> Iterator[OdometryLink]:
    with running_router() as endpoint, peer_session(endpoint) as session:
        link = OdometryLink(session, Keys(ROBOT))
        flags = [item for key, value in OVERRIDES.items() for item in ("--set", f"{key}={value}")]
        with InventProcess("odometry", "--connect", endpoint, "--robot", ROBOT, *flags) as process:
            wait_alive(session, link.keys.alive(Service.ODOMETRY))
            link.wait_matched()
            link.send_wheels(link.time_ns, 0.0, 0.0)
            yield link
            code, _out, err = process.stop()
            assert code == 0, err


def set_pose(link: OdometryLink, payload: bytes) -> SetOdometryReply:
    ok, reply = call(link.session, link.keys.odometry_set_pose, payload)
    assert ok, reply
    return msgspec.convert(reply, SetOdometryReply)


def test_set_pose_then_driving_on_from_it(link: OdometryLink) -> None:
    """diff_drive_controller's odometry_set_service, over the wire: move, set, then move on."""
    link.advance(0.25, 0.25)
    reply = set_pose(link, encode(SetOdometry(x=5.0, y=-2.0, theta=math.pi / 2)))
    assert reply == SetOdometryReply(True, tm=Time.from_nanoseconds(link.time_ns)), "at the last sample"
    link.mirror.set_pose(5.0, -2.0, math.pi / 2)
    status = link.status()
    assert status["pose"] == link.mirror.pose._asdict()
    assert status["counters"]["pose_sets"] >= 1
    step, pose = link.advance(0.25, 0.25)
    assert_published(step, pose)
    assert pose.y > -2.0 and pose.x == pytest.approx(5.0), "forward is +y now"


def test_reset_zeroes_the_pose(link: OdometryLink) -> None:
    link.advance(0.5, 0.25)
    assert set_pose(link, encode(SetOdometry(x=0.0, y=0.0, theta=0.0))).accepted
    link.mirror.set_pose(0.0, 0.0, 0.0)
    assert link.status()["pose"] == {"x": 0.0, "y": 0.0, "theta": 0.0}
    step, pose = link.advance(0.0, 0.0)
    assert (pose.x, pose.y, pose.theta) == (0.0, 0.0, 0.0)
    assert_published(step, pose)


def test_a_stamped_pose_ahead_lands_on_the_first_sample_after_its_stamp(link: OdometryLink) -> None:
    stamp_ns = link.time_ns + 5_000_000
    reply = set_pose(link, encode(SetOdometry(x=1.0, y=1.0, theta=0.0, tm=Time.from_nanoseconds(stamp_ns))))
    assert reply.accepted and reply.tm == Time.from_nanoseconds(stamp_ns)
    link.mirror.set_pose(1.0, 1.0, 0.0, stamp_ns)
    step, pose = link.advance(0.125, 0.125)  # 10 ms on: the first sample after the stamp
    assert_published(step, pose)
    assert pose.x == pytest.approx(1.0 + step.dl) and pose.y == pytest.approx(1.0)


BAD_REQUESTS = {
    "garbage": (b"\x00not json", "not a SetOdometry"),
    "nan": (b'{"x": NaN, "y": 0, "theta": 0}', "not a SetOdometry"),
    "missing_theta": (b'{"x": 0, "y": 0}', "not a SetOdometry"),
    "unknown_field": (b'{"x": 0, "y": 0, "theta": 0, "z": 1}', "not a SetOdometry"),
    "beyond_max_coordinate": (b'{"x": 1e9, "y": 0, "theta": 0}', "refused"),
    "older_than_the_history": (b'{"x": 0, "y": 0, "theta": 0, "tm": {"sec": 0, "nsec": 0}}', "refused"),
    "beyond_the_horizon": (b'{"x": 0, "y": 0, "theta": 0, "tm": {"sec": 100000, "nsec": 0}}', "refused"),
}


@pytest.mark.parametrize("case", BAD_REQUESTS)
def test_a_bad_request_is_refused_counted_and_changes_nothing(link: OdometryLink, case: str) -> None:
    payload, reason = BAD_REQUESTS[case]
    key = link.keys.odometry_set_pose
    before, counted = link.status(), link.bad_input_count(key)
    reply = set_pose(link, payload)
    assert not reply.accepted and reply.reason.startswith(reason) and reply.tm is None
    after = link.status()
    assert after["pose"] == before["pose"] == link.mirror.pose._asdict()
    assert after["counters"]["pose_sets"] == before["counters"]["pose_sets"]
    assert link.bad_input_count(key) == counted + 1
    step, pose = link.advance(0.125, -0.125)
    assert_published(step, pose)


def test_a_wildcard_query_never_sets_the_pose(link: OdometryLink) -> None:
    before = link.status()
    replies = list(link.session.get(f"{link.keys.prefix}/odometry/*", payload=b'{"x": 7, "y": 7, "theta": 0}'))
    assert [str(reply.ok.key_expr) for reply in replies if reply.ok is not None] == [link.keys.status(Service.ODOMETRY)]
    assert link.status()["pose"] == before["pose"]
    assert link.status()["counters"]["pose_sets"] == before["counters"]["pose_sets"]


def test_in_a_secure_deployment_only_the_operator_reaches_set_pose(tmp_path: Path) -> None:
    """A real router with the generated access control: an odometry-role session serves the key;
    the operator's query reaches it, every other role's does not."""
    keys = Keys()
    profile = write_profile(tmp_path / "secrets", keys, endpoint=f"tcp/127.0.0.1:{free_port()}")
    callers: list[str] = []
    with ExitStack() as stack:
        stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.router_config))))

        def open_as(role: Role) -> zenoh.Session:
            return stack.enter_context(zenoh.open(zenoh.Config.from_file(str(profile.client_config(role)))))

        odometry = open_as(Role.ODOMETRY)

        def serve(query: zenoh.Query) -> None:
            callers.append(query.payload.to_bytes().decode() if query.payload is not None else "")
            query.reply(keys.odometry_set_pose, encode(SetOdometryReply(True)))

        odometry.declare_queryable(keys.odometry_set_pose, serve)
        status = keys.status(Service.ODOMETRY)
        odometry.declare_queryable(status, lambda query: query.reply(status, b"{}"))
        sessions = {role: open_as(role) for role in Role if role is not Role.ODOMETRY}
        wait_until(lambda: call(sessions[Role.OBSERVER], status)[0], 10, "the odometry's status")
        answered = {
            role: any(
                reply.ok is not None for reply in session.get(keys.odometry_set_pose, payload=role.value, timeout=1.0)
            )
            for role, session in sessions.items()
        }
    assert answered == {role: role is Role.OPERATOR for role in sessions}
    assert callers == [Role.OPERATOR.value]
