"""Hostile payloads for the goal, sensor and NavigateToPose surfaces (hypothesis strategies), each
bad by construction against a stack in goal mode whose robot rests at the origin with no goal: JSON
for the drive's goal queryables, ``sim/scan`` and ``sim/imu``; CDR with rmw_zenoh's attachment for
the action's services and ``goal_pose``. Used by tests/test_fuzz_goals.py."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

from hypothesis import strategies as st

from schemas.messages import MAX_GOAL_ID_LENGTH, MAX_SCAN_RAYS
from schemas.navigation import MAX_GOAL_SECONDS
from services.config import InputConfig
from tests import ros_client, ros_services
from tests.fuzz_payloads import malformed

LIMITS = InputConfig()
NOT_UTF8 = [b"\xff", b"\xc3(", b"\xed\xa0\x80", b"\xf8\x88\x80\x80\x80", b"\x80", b"\xe2\x82"]
"""Byte sequences no UTF-8 string holds: a stray byte, a broken pair, a surrogate, a 5-byte form, a
continuation byte alone, a sequence cut short."""
plain_ids = st.from_regex(r"[A-Za-z0-9_.\-]{1,20}", fullmatch=True)


def _json(value: object) -> bytes:
    return json.dumps(value).encode()


def _sign(draw: st.DrawFn) -> float:
    return draw(st.sampled_from([1.0, -1.0]))


@st.composite
def not_utf8_string(draw: st.DrawFn, fields: dict[str, object], field: str) -> bytes:
    """``fields`` as JSON with the string ``field`` holding bytes that are not UTF-8."""
    marker = "MARKER"
    text = _json({**fields, field: [marker] if isinstance(fields.get(field), list) else marker})
    return text.replace(marker.encode(), draw(st.sampled_from(NOT_UTF8)) + draw(plain_ids).encode())


# --- the drive's goal queryables ------------------------------------------------------------------

GOAL = {"x": 1.0, "y": 0.0, "frame": "map"}
"""Only fields none of tests/fuzz_payloads.py's mistyped values makes valid (an ``id`` of ``"x"`` would be)."""


@st.composite
def bad_ids(draw: st.DrawFn) -> str:
    kind = draw(st.sampled_from(["newline", "long", "character"]))
    if kind == "newline":
        return draw(st.sampled_from(["{}\n", "\n{}", "{}\n\n", "{}\r\n"])).format(draw(plain_ids))
    if kind == "long":
        return "g" * draw(st.integers(min_value=MAX_GOAL_ID_LENGTH + 1, max_value=500))
    return draw(plain_ids) + draw(st.sampled_from(["/", "*", " ", "$", "é", "\t", "\x00"]))


@st.composite
def goal_requests(draw: st.DrawFn) -> bytes:
    """Goals the drive must refuse, the robot at rest at the origin."""
    kind = draw(st.sampled_from(["malformed", "time_limit", "not_positive", "frame", "far", "id", "not_utf8"]))
    if kind == "malformed":
        return draw(malformed(_json(GOAL)))
    if kind == "time_limit":  # 1e308 s overflowed the drive's conversion to nanoseconds
        seconds = draw(st.floats(min_value=MAX_GOAL_SECONDS, max_value=1e308, exclude_min=True))
        return _json({"x": 1.0, "y": 0.0, "time_limit": seconds})
    if kind == "not_positive":
        field = draw(st.sampled_from(["position_tolerance", "heading_tolerance", "time_limit"]))
        return _json({"x": 1.0, "y": 0.0, field: draw(st.floats(max_value=0.0, allow_nan=False, allow_infinity=False))})
    if kind == "frame":
        return _json(
            {"x": 1.0, "y": 0.0, "frame": draw(st.text(max_size=20).filter(lambda f: f not in ("map", "odom")))}
        )
    if kind == "far":  # beyond goals.max_distance, the costmap or input.max_coordinate
        return _json({"x": draw(st.floats(min_value=20.0, max_value=1e308)) * _sign(draw), "y": 0.0})
    if kind == "id":
        return _json({"x": 1.0, "y": 0.0, "id": draw(bad_ids())})
    return draw(not_utf8_string(GOAL, draw(st.sampled_from(["id", "frame"]))))


@st.composite
def cancel_requests(draw: st.DrawFn) -> bytes:
    """Cancels the drive must refuse while no goal runs."""
    kind = draw(st.sampled_from(["malformed", "unknown", "all", "id", "not_utf8"]))
    if kind == "malformed":
        return draw(malformed(_json({"id": "g1"})))
    if kind == "unknown":
        return _json({"id": draw(plain_ids)})
    if kind == "all":
        return draw(st.sampled_from([b"", b" ", b"{}", b'{"id": ""}']))
    if kind == "id":
        return _json({"id": draw(bad_ids())})
    return draw(not_utf8_string({"id": "g1"}, "id"))


# --- the simulator's sensors ------------------------------------------------------------------------

TM = {"sec": 1, "nsec": 0}
SCAN = {
    "tm": TM,
    "angle_min": -1.0,
    "angle_increment": 0.1,
    "range_min": 0.1,
    "range_max": 10.0,
    "ranges": [1.0, 2.0, None],
    "bodies": ["box"],
    "hits": [0, -1, -1],
}


@st.composite
def scans(draw: st.DrawFn) -> bytes:
    """Scans that cannot be one: every consumer refuses them as it decodes them."""
    kind = draw(st.sampled_from(["malformed", "limits", "range", "hits", "rays", "infinite", "not_utf8"]))
    if kind == "malformed":
        return draw(malformed(_json(SCAN)))
    if kind == "limits":
        low = draw(st.floats(min_value=0.0, max_value=100.0))
        limits = draw(st.sampled_from([(low, low), (low + 1.0, low), (-1.0 - low, 10.0)]))
        return _json({**SCAN, "range_min": limits[0], "range_max": limits[1]})
    if kind == "range":
        return _json({**SCAN, "ranges": [1.0, -draw(st.floats(min_value=1e-300, max_value=1e308)), None]})
    if kind == "hits":
        hits = draw(st.sampled_from([[0, -1], [1, -1, -1], [-2, -1, -1], []]))  # a length, a body, none
        return _json({**SCAN, "hits": hits})
    if kind == "rays":
        count = draw(st.integers(min_value=MAX_SCAN_RAYS + 1, max_value=2 * MAX_SCAN_RAYS))
        return _json({**SCAN, "ranges": [1.0] * count, "hits": [], "bodies": []})
    if kind == "infinite":
        field, value = draw(st.sampled_from([("angle_min", -1.0), ("angle_increment", 0.1), ("range_max", 10.0)]))
        literal = draw(st.sampled_from([b"1e999", b"-1e999"]))
        return _json(SCAN).replace(f'"{field}": {value}'.encode(), f'"{field}": '.encode() + literal, 1)
    return draw(not_utf8_string(SCAN, "bodies"))


IMU = {
    "tm": TM,
    "orientation": [0.0, 0.0, 0.0, 1.0],
    "orientation_source": "simulator",
    "angular_velocity": [0.0, 0.0, 0.0],
    "linear_acceleration": [0.0, 0.0, 9.81],
}


@st.composite
def imu_samples(draw: st.DrawFn) -> bytes:
    kind = draw(st.sampled_from(["malformed", "not_unit", "source", "lengths", "infinite", "not_utf8"]))
    if kind == "malformed":
        return draw(malformed(_json(IMU)))
    if kind == "not_unit":  # huge components too: their squares overflow
        scale = draw(st.one_of(st.floats(min_value=1.01, max_value=1e300), st.floats(min_value=0.0, max_value=0.99)))
        return _json({**IMU, "orientation": [0.0, 0.0, scale * math.sqrt(0.5), scale * math.sqrt(0.5)]})
    if kind == "source":
        source = draw(st.text(max_size=12).filter(lambda s: s not in ("none", "simulator", "estimate")))
        return _json({**IMU, "orientation_source": source})
    if kind == "lengths":
        field, length = draw(st.sampled_from([("orientation", 4), ("angular_velocity", 3), ("linear_acceleration", 3)]))
        count = draw(st.integers(min_value=0, max_value=8).filter(lambda n: n != length))
        return _json({**IMU, field: [0.0] * count})
    if kind == "infinite":
        return _json(IMU).replace(b"9.81", draw(st.sampled_from([b"1e999", b"-1e999", b"NaN"])))
    return draw(not_utf8_string(IMU, "orientation_source"))


# --- the NavigateToPose action and goal_pose (CDR and rmw_zenoh's attachment) -----------------------

Call = tuple[bytes, bytes | None]
"""A payload and its attachment (None: none)."""
uuids = st.binary(min_size=16, max_size=16)


def _attached(payload: bytes) -> Call:
    return payload, ros_client.attachment(1, bytes(16))


@st.composite
def bad_attachments(draw: st.DrawFn, payload: bytes) -> Call:
    kind = draw(st.sampled_from(["none", "length", "negative"]))
    if kind == "none":
        return payload, None
    if kind == "length":
        return payload, draw(st.binary(max_size=64).filter(lambda b: len(b) != 33))
    return payload, ros_client.attachment(-draw(st.integers(min_value=1, max_value=2**63)), bytes(16))


def _decodes(payload: bytes, store: Any, message_type: str) -> bool:
    try:
        store.deserialize_cdr(payload, message_type)
    except Exception:  # noqa: BLE001 (whatever rosbags raises: this payload is malformed, as wanted)
        return False
    return True


@st.composite
def bad_cdr(
    draw: st.DrawFn, valid: bytes, message_type: str, most: int, store: Any = ros_services.ACTION_TYPESTORE
) -> Call:
    """``valid``'s message broken: random bytes, cut short, followed by more than CDR's padding of up
    to 3 bytes, beyond ``most`` bytes (never one that decodes), or with an attachment that is not one."""
    kind = draw(st.sampled_from(["bytes", "truncated", "trailing", "oversized", "attachment"]))
    if kind == "attachment":
        return draw(bad_attachments(valid))
    if kind == "oversized":
        return _attached(valid + bytes(draw(st.integers(min_value=most + 1 - len(valid), max_value=4 * most))))
    broken = {
        "bytes": st.binary(max_size=200),
        "truncated": st.integers(min_value=0, max_value=len(valid) - 1).map(lambda end: valid[:end]),
        "trailing": st.binary(min_size=4, max_size=16).map(lambda tail: valid + tail),
    }[kind]
    return _attached(draw(broken.filter(lambda payload: not _decodes(payload, store, message_type))))


def _pose(
    x: float = 1.0, y: float = 0.0, q: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0), frame: str = "map", store: Any = None
) -> Any:
    pose = ros_services.pose_stamped(x, y, 0.0, frame, store)
    orientation = pose.pose.orientation
    orientation.x, orientation.y, orientation.z, orientation.w = q
    return pose


@st.composite
def bad_poses(draw: st.DrawFn) -> dict[str, Any]:
    """Poses (``_pose``'s arguments) refused before any frame is looked up: not finite, beyond
    input.max_coordinate, no rotation."""
    kind = draw(st.sampled_from(["not_finite", "far", "no_rotation", "orientation_not_finite"]))
    if kind == "not_finite":
        return {"x": draw(st.sampled_from([math.nan, math.inf, -math.inf]))}
    if kind == "far":
        return {"y": draw(st.floats(min_value=LIMITS.max_coordinate * 1.001, max_value=1e308)) * _sign(draw)}
    if kind == "no_rotation":
        return {"q": (0.0, 0.0, 0.0, 0.0)}
    component = draw(st.sampled_from([math.nan, math.inf, -math.inf]))
    return {"q": tuple(draw(st.permutations([component, 0.0, 0.0, 1.0])))}


def _send_goal(pose: Any) -> bytes:
    return ros_services.send_goal_request(bytes(range(16)), pose)


def _goal_pose(pose: Any) -> bytes:
    return ros_client.cdr(pose)


def _frame_not_utf8(serialize: Callable[[Any], bytes], bad: bytes, store: Any = None) -> bytes:
    """A message whose pose's ``frame_id`` holds ``bad`` (bytes of the same length stand in for them
    while it is serialised: the CDR stays whole)."""
    stand_in = b"Z" * len(bad)
    return serialize(_pose(frame="map" + stand_in.decode(), store=store)).replace(stand_in, bad, 1)


@st.composite
def send_goal_calls(draw: st.DrawFn) -> Call:
    kind = draw(st.sampled_from(["cdr", "pose", "not_utf8"]))
    if kind == "cdr":
        return draw(bad_cdr(_send_goal(_pose()), f"{ros_services.NAVIGATE}_SendGoal_Request", 4096))
    if kind == "pose":
        return _attached(_send_goal(_pose(**draw(bad_poses()))))
    return _attached(_frame_not_utf8(_send_goal, draw(st.sampled_from(NOT_UTF8))))


@st.composite
def cancel_goal_calls(draw: st.DrawFn) -> Call:
    valid = ros_services.cancel_request(draw(uuids), draw(st.integers(min_value=0, max_value=(2**31 - 1) * 10**9)))
    return draw(bad_cdr(valid, "action_msgs/srv/CancelGoal_Request", 64))


@st.composite
def get_result_calls(draw: st.DrawFn) -> Call:
    return draw(bad_cdr(ros_services.result_request(draw(uuids)), f"{ros_services.NAVIGATE}_GetResult_Request", 64))


@st.composite
def goal_pose_samples(draw: st.DrawFn) -> Call:
    store = ros_client.TYPESTORE
    kind = draw(st.sampled_from(["cdr", "pose", "not_utf8"]))
    if kind == "cdr":
        return draw(bad_cdr(_goal_pose(_pose(store=store)), "geometry_msgs/msg/PoseStamped", 4096, store))
    if kind == "pose":
        return _attached(_goal_pose(_pose(**draw(bad_poses()), store=store)))
    return _attached(_frame_not_utf8(_goal_pose, draw(st.sampled_from(NOT_UTF8)), store))
