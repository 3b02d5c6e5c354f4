"""The wire contract: round trips, strict rejection, and the key space."""

import json
import math
import re

import msgspec
import pytest
from hypothesis import given
from hypothesis import strategies as st

from schemas import (
    BadInput,
    BadMessage,
    BumpEvent,
    Keys,
    Method,
    MethodFamily,
    PDGains,
    Service,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
    Topic,
    decode,
    encode,
    schema_for_key,
)
from schemas.codec import MESSAGE_TYPES
from schemas.messages import ImuSample, LaserScan, MotorStateReport, PlannedPath, RunSummary, ScenarioOutcome, SimWorld
from schemas.navigation import (
    CancelReply,
    CancelRequest,
    GoalFeedback,
    GoalPlan,
    GoalReply,
    GoalRequest,
    GoalTarget,
    OccupancyGrid,
    ParticleCloud,
)
from schemas.tokens import parse_alive_key
from schemas.topics import TOPIC_TYPES
from services.clock.lockstep import decode_mark

finite = st.floats(allow_nan=False, allow_infinity=False)
times = st.builds(Time, st.integers(0, 2**40), st.integers(0, 999_999_999))
ids = st.lists(st.integers(-(2**31), 2**31 - 1), max_size=4)

EXAMPLES = [
    Time(3, 250),
    TimedDoubleSeq(Time(1, 2), [0.5, -1.25, 3.0]),
    TimedVelocity(Time(1, 2), [7], 0.3, 0.0, -0.1, [0.0]),
    TimedPosition(Time(1, 2), [], 1.0, -2.0, math.pi, []),
    BumpEvent(Time(4, 0), "box_1", 1.0, 0.2, 0.1),
    LaserScan(Time(0, 100), -math.pi, math.pi / 2, 0.12, 3.5, [0.5, None, 3.4, None], ["box"], [0, -1, 0, -1]),
    LaserScan(Time(0, 100), -1.0, 0.5, 0.0, 10.0, [2.0, 3.0, 4.0, 5.0, None]),
    ImuSample(Time(0, 10), (0.0, 0.0, 0.0, 1.0), "simulator", (0.0, 0.0, 0.5), (0.1, 0.0, 9.81)),
    ImuSample(Time(0, 10), (0.0, 0.0, 0.0, 0.0), "none", (0.0, 0.0, 0.5), (0.1, 0.0, 9.81)),
    PDGains(5.0, 5.0, 2.0, 2.0),
    MotorStateReport(Time(1, 871_000_000), "stopped", "bump"),
    ScenarioOutcome(Time(3, 880_000_000), "straight", "aborted", "bumped into 'box'", 0, 3.88),
    ScenarioOutcome(Time(9, 0), "goals", "canceled", "canceled by g2", 0, 4.5, goal_id="g1"),
    GoalRequest(x=1.5, y=0.5, theta=1.57, frame="odom", position_tolerance=0.05, id="a1b2"),
    GoalRequest(x=-2.0, y=0.0),
    GoalReply(True, "g1"),
    GoalReply(False, "", "the motor is latched stopped"),
    CancelRequest("g1"),
    CancelReply(["g1"]),
    CancelReply([], "no goal runs"),
    GoalTarget(Time(1, 0), "g1", 1.5, 0.5, None, "map", 0.05, 0.1, None),
    GoalFeedback(Time(2, 0), "g1", "executing", 0.3, 0.1, 0.2, 1.2, 1.0, 4.5),
    GoalFeedback(Time(2, 0), "g1", "executing", 0.3, 0.1, 0.2, 1.2, 1.0, 4.5, recoveries=2),
    OccupancyGrid(Time(0, 0), 0.05, 3, 2, -1.0, 2.5, bytes([0, 100, 255, 50, 0, 0])),
    GoalPlan(Time(1, 0), "g1", [(0.0, 0.0), (1.5, 0.25)]),
    GoalPlan(Time(1, 0), "g1", []),
]


@pytest.mark.parametrize(
    ("fields", "says"),
    [
        ({"data": "AAAA"}, "3 bytes of data for 2 x 2 cells"),
        ({"data": "AGUAAA=="}, "neither -1 (unknown) nor 0 to 100"),
        ({"width": 4096, "height": 4096, "data": ""}, "more than 4194304"),
        ({"resolution": 0.0}, "Expected `float` > 0.0"),
    ],
)
def test_an_occupancy_grid_that_does_not_hold_together_is_refused(fields, says):
    grid = {"tm": {"sec": 0, "nsec": 0}, "resolution": 0.1, "width": 2, "height": 2, "origin_x": 0.0}
    grid |= {"origin_y": 0.0, "data": "AAAAAA==", **fields}
    with pytest.raises(BadMessage, match=re.escape(says)):
        decode(OccupancyGrid, json.dumps(grid).encode())


def test_a_goal_id_is_one_plain_word_of_at_most_64_characters():
    assert decode(CancelRequest, b'{"id": "5f0e3a9c1d2b4e6f8a7b9c0d1e2f3a4b"}').id == "5f0e3a9c1d2b4e6f8a7b9c0d1e2f3a4b"
    for bad in (b'{"id": "a/b"}', b'{"id": "' + b"x" * 65 + b'"}', b'{"id": "**"}'):
        with pytest.raises(BadMessage):
            decode(CancelRequest, bad)


def test_a_goal_id_ending_in_a_newline_is_refused_it_is_matched_whole():
    """``$`` matches before a trailing newline: the id's pattern is anchored with ``\\A`` and ``\\Z``."""
    for payload in (b'{"id": "g1\\n"}', b'{"id": "\\ng1"}', b'{"id": "\\n"}'):
        with pytest.raises(BadMessage, match="matching regex"):
            decode(CancelRequest, payload)
        with pytest.raises(BadMessage, match="matching regex"):
            decode(GoalRequest, b'{"x": 1.0, "y": 0.0, "id": ' + payload[7:])


@pytest.mark.parametrize("message_type", MESSAGE_TYPES, ids=lambda t: t.__name__)
def test_a_string_that_is_not_utf_8_is_bad_input_for_every_message_type(message_type):
    """msgspec raises UnicodeDecodeError for it (0.22), or a DecodeError naming UTF-8 (0.23, for a key):
    the codec refuses it as any bad payload, saying so."""
    with pytest.raises(BadMessage, match="not UTF-8"):
        decode(message_type, b'{"\xff": 1}')


@pytest.mark.parametrize(
    ("message_type", "payload"),
    [
        (GoalRequest, b'{"x": 1.0, "y": 0.0, "id": "g\xff"}'),
        (GoalRequest, b'{"x": 1.0, "y": 0.0, "frame": "\xc3("}'),
        (CancelRequest, b'{"id": "\xed\xa0\x80"}'),
        (ScenarioOutcome, b'{"tm": {"sec": 0, "nsec": 0}, "scenario": "\xfe", "outcome": "completed"}'),
    ],
)
def test_invalid_utf_8_inside_a_string_value_is_bad_input(message_type, payload):
    with pytest.raises(BadMessage, match="not UTF-8"):
        decode(message_type, payload)


def test_a_lockstep_attachment_that_is_not_utf_8_is_bad_input():
    """The step's mark rides every wheel-angle sample: decoded apart from the codec, with the same hole once."""
    with pytest.raises(BadInput, match="step attachment"):
        decode_mark(b'{"owed": {"drive/target_velocity\xff": 1}}', 10)


@pytest.mark.parametrize("message", EXAMPLES, ids=lambda m: type(m).__name__)
def test_every_message_type_round_trips(message):
    assert decode(type(message), encode(message)) == message


@given(times, st.lists(finite, max_size=16))
def test_timed_double_seq_round_trips_any_finite_data(tm, data):
    message = TimedDoubleSeq(tm, data)
    assert decode(TimedDoubleSeq, encode(message)) == message


@given(times, ids, finite, finite, finite, st.lists(finite, max_size=3))
def test_timed_velocity_round_trips(tm, id_, vx, vy, w, error):
    message = TimedVelocity(tm, id_, vx, vy, w, error)
    assert decode(TimedVelocity, encode(message)) == message


@given(times, ids, finite, finite, finite, st.lists(finite, max_size=3))
def test_timed_position_round_trips(tm, id_, x, y, theta, error):
    message = TimedPosition(tm, id_, x, y, theta, error)
    assert decode(TimedPosition, encode(message)) == message


def test_payload_is_json_text_with_idl_field_order():
    payload = encode(TimedVelocity(Time(1, 0), [], 0.5, 0.0, 0.25, []))
    assert payload == b'{"tm":{"sec":1,"nsec":0},"id":[],"vx":0.5,"vy":0.0,"w":0.25,"error":[]}'


VALID_SEQ = '{"tm":{"sec":1,"nsec":0},"data":[1.0,2.0]}'


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        ('{"tm":{"sec":1,"nsec":0},"data":["a"]}', "Expected `float`, got `str`"),
        ('{"tm":{"sec":"1","nsec":0},"data":[]}', "Expected `int`, got `str`"),
        ('{"tm":{"sec":1,"nsec":0},"data":1.0}', "Expected `array`"),
        ('{"tm":{"sec":1,"nsec":0}}', "missing required field `data`"),
        ('{"data":[1.0]}', "missing required field `tm`"),
        ('{"tm":{"sec":1,"nsec":0},"data":[1.0],"extra":0}', "unknown field `extra`"),
        ('{"tm":{"sec":1,"nsec":0,"usec":0},"data":[]}', "unknown field `usec`"),
        ('{"tm":{"sec":1,"nsec":0},"data":[NaN]}', "malformed"),
        ('{"tm":{"sec":1,"nsec":0},"data":[Infinity]}', "malformed"),
        ('{"tm":{"sec":1,"nsec":0},"data":[1e999]}', "out of range"),
        ('{"tm":{"sec":1,"nsec":0},"data":[null]}', "got `null`"),
        ('{"tm":{"sec":-1,"nsec":0},"data":[]}', ">= 0"),
        ('{"tm":{"sec":1,"nsec":1000000000},"data":[]}', "<= 999999999"),
        ("garbage", "not JSON"),
        ("", "not JSON"),
    ],
)
def test_timed_double_seq_rejects(payload, reason):
    with pytest.raises(BadMessage, match=reason):
        decode(TimedDoubleSeq, payload.encode())
    assert decode(TimedDoubleSeq, VALID_SEQ.encode()).data == [1.0, 2.0]


@pytest.mark.parametrize(
    "payload",
    [
        '{"tm":{"sec":1,"nsec":0},"id":[],"vx":1e999,"vy":0,"w":0,"error":[]}',
        '{"tm":{"sec":1,"nsec":0},"id":[],"vx":0,"vy":0,"w":0,"error":[-1e999]}',
        '{"tm":{"sec":1,"nsec":0},"id":[1.5],"vx":0,"vy":0,"w":0,"error":[]}',
        '{"tm":{"sec":1,"nsec":0},"id":[],"vx":0,"vy":0,"error":[]}',
        '{"tm":{"sec":1,"nsec":0},"id":[],"vx":0,"vy":0,"w":0,"error":[],"z":0}',
        "[1, 2, 3]",
    ],
)
def test_timed_velocity_rejects(payload):
    with pytest.raises(BadMessage):
        decode(TimedVelocity, payload.encode())


@pytest.mark.parametrize(
    "payload",
    [
        '{"tm":{"sec":1,"nsec":0},"id":[],"x":0,"y":0,"theta":1e400,"error":[]}',
        '{"tm":{"sec":1,"nsec":0},"id":[],"x":"0","y":0,"theta":0,"error":[]}',
        '{"tm":{"sec":1,"nsec":0},"id":[],"x":0,"y":0,"error":[]}',
        '{"tm":{"sec":1,"nsec":0},"id":[],"x":0,"y":0,"theta":0,"error":[],"vx":0}',
    ],
)
def test_timed_position_rejects(payload):
    with pytest.raises(BadMessage):
        decode(TimedPosition, payload.encode())


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_messages_cannot_be_built(value):
    with pytest.raises(ValueError, match="non-finite"):
        TimedDoubleSeq(Time(0, 0), [value])
    with pytest.raises(ValueError, match="non-finite"):
        TimedVelocity(Time(0, 0), [], value, 0.0, 0.0, [])


def test_pd_gains_reject_negative():
    with pytest.raises(BadMessage, match=">= 0"):
        decode(PDGains, b'{"p_gain_l":-1,"p_gain_r":1,"d_gain_l":1,"d_gain_r":1}')


@given(st.integers(0, 10**15))
def test_time_nanoseconds_round_trip(total_ns):
    assert Time.from_nanoseconds(total_ns).to_nanoseconds() == total_ns


def test_keys_are_a_function_of_the_robot_name():
    keys = Keys("rh1")
    assert keys.sim_wheel_angles == "invent/rh1/sim/wheel_angles"
    assert keys.motor_sim_pose_localization == "invent/rh1/motor/sim_pose/localization"
    assert keys.method(MethodFamily.BUMP, Method.STOP) == "invent/rh1/motor/bump/stop"
    assert keys.status(Service.ODOMETRY) == "invent/rh1/odometry/status"
    assert keys.alive(Service.SIM) == "invent/rh1/sim/alive"
    assert Keys().robot == "rh0"
    assert keys.drive_goal_send == "invent/rh1/drive/goal/send"
    assert keys.drive_goal_cancel == "invent/rh1/drive/goal/cancel"
    assert keys.drive_goal_feedback == "invent/rh1/drive/goal/feedback"


def test_every_spec_data_key_has_its_schema():
    keys = Keys("rh0")
    spec = {
        "sim/wheel_angles": TimedDoubleSeq,
        "sim/clock": TimedDoubleSeq,
        "sim/body_pose": TimedDoubleSeq,
        "motor/torque": TimedDoubleSeq,
        "motor/wheel_velocity": TimedDoubleSeq,
        "motor/wheel_angles": TimedDoubleSeq,
        "motor/sim_pose/gui": TimedDoubleSeq,
        "motor/sim_pose/localization": TimedDoubleSeq,
        "drive/target_velocity": TimedVelocity,
        "odometry/pose": TimedPosition,
        "localization/pose": TimedPosition,
        "localization/particles": ParticleCloud,
        "sim/bump": BumpEvent,
        "sim/scan": LaserScan,
        "sim/imu": ImuSample,
        "sim/world": SimWorld,
        "drive/path": PlannedPath,
        "motor/state": MotorStateReport,
        "drive/outcome": ScenarioOutcome,
        "drive/goal": GoalTarget,
        "drive/goal/feedback": GoalFeedback,
        "drive/map": OccupancyGrid,
        "drive/costmap": OccupancyGrid,
        "drive/plan": GoalPlan,
        "up/run": RunSummary,
    }
    assert {str(topic): schema for topic, schema in TOPIC_TYPES.items()} == spec
    for suffix, schema in spec.items():
        assert schema_for_key(f"{keys.prefix}/{suffix}") is schema
    assert schema_for_key(keys.topic(Topic.ODOMETRY_POSE)) is TimedPosition


@pytest.mark.parametrize("key", ["invent/rh0/motor/status", "other/rh0/sim/body_pose", "invent/rh0", "invent"])
def test_unknown_keys_have_no_schema(key):
    assert schema_for_key(key) is None


@pytest.mark.parametrize("name", ["", "a/b", "r*", "r h", "$x"])
def test_robot_names_must_be_one_key_chunk(name):
    with pytest.raises(ValueError, match="robot name"):
        Keys(name)


def test_alive_keys_parse_back():
    assert parse_alive_key(Keys("rh2").alive(Service.DRIVE)) == ("rh2", Service.DRIVE)
    assert parse_alive_key("invent/rh2/odometer/alive") == ("rh2", "odometer"), "a user service's (docs/extending.md)"
    assert parse_alive_key("invent/rh2/No-thing/alive") is None
    assert parse_alive_key(Keys("rh2").status(Service.DRIVE)) is None


def test_msgspec_structs_are_strict_and_frozen():
    message = TimedDoubleSeq(Time(0, 0), [1.0])
    with pytest.raises(AttributeError):
        message.tm = Time(1, 0)
    assert msgspec.structs.asdict(message)["data"] == [1.0]


SCAN = b'{"tm":{"sec":0,"nsec":0},"angle_min":-1.0,"angle_increment":0.5,"range_min":0.1,"range_max":3.5,'


@pytest.mark.parametrize(
    ("tail", "reason"),
    [
        (b'"ranges":[1.0,-0.5]}', "range -0.5"),
        (b'"ranges":[1.0,NaN]}', "not JSON"),
        (b'"ranges":[1.0],"bodies":["box"],"hits":[0,0]}', "2 hits for 1 ranges"),
        (b'"ranges":[1.0],"bodies":["box"],"hits":[1]}', "hit 1 names no body"),
        (b'"ranges":[1.0],"bodies":["box"]}', "bodies without hits"),
        (b'"ranges":[' + b",".join([b"1.0"] * 5000) + b"]}", "length <= 4096"),
    ],
)
def test_a_scan_that_cannot_be_a_scan_is_refused(tail: bytes, reason: str) -> None:
    with pytest.raises(BadMessage, match=reason):
        decode(LaserScan, SCAN + tail)


def test_a_scan_range_limits_must_be_ordered() -> None:
    payload = SCAN.replace(b'"range_min":0.1', b'"range_min":5.0') + b'"ranges":[1.0]}'
    with pytest.raises(BadMessage, match="0 <= min < max"):
        decode(LaserScan, payload)


def test_an_imu_orientation_from_somewhere_is_a_unit_quaternion() -> None:
    with pytest.raises(ValueError, match="not a unit quaternion"):
        ImuSample(Time(0, 0), (0.0, 0.0, 0.0, 2.0), "simulator", (0.0, 0.0, 0.0), (0.0, 0.0, 9.81))
