"""The status replies' Structs (schemas/status.py, schemas/drive_status.py): each round-trips
through JSON; the real services' replies decode as their kind's; a reply that does not decode is a
bad reply, counted and taken as none by the readers, never a crash."""

from __future__ import annotations

import json
import math

import msgspec
import msgspec.inspect as mi
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas import Keys, Service
from schemas.drive_status import DriveStatus, Ros2Status
from schemas.keys import user_service_name
from schemas.status import (
    ControlStatus,
    LocalizationStatus,
    MotorStatus,
    OdometryStatus,
    ServiceStatus,
    SimStatus,
    UserServiceStatus,
    ViewStatus,
)
from schemas.status_kinds import STATUS_TYPES, status_type, status_type_of_key
from services.launch.composition import Composition
from services.recording.mcap_files import key_json_schema
from services.recording.report import loop_health
from services.runtime.discovery import StatusReader
from tests.harness import wait_until
from tests.test_composition import compose_the_loop

KEYS = Keys("rh0")
KINDS = (
    SimStatus,
    MotorStatus,
    OdometryStatus,
    LocalizationStatus,
    DriveStatus,
    Ros2Status,
    UserServiceStatus,
    ViewStatus,
    ControlStatus,
)
INT64 = 2**63 - 1

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-INT64, INT64)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=5),
    lambda children: st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=8), children, max_size=3),
    max_leaves=8,
)
"""What a free-form part (``dict[str, Any]``) holds: JSON, as it comes back."""


def _bounded(kind: mi.IntType | mi.FloatType) -> tuple[float | None, float | None]:
    low = kind.ge if kind.ge is not None else None if kind.gt is None else kind.gt + 1
    high = kind.le if kind.le is not None else None if kind.lt is None else kind.lt - 1
    return low, high


def strategy(kind: mi.Type) -> st.SearchStrategy:
    """Values of a status field's type as msgspec describes it: finite floats (JSON has no NaN) and
    64-bit integers (what msgspec encodes), a field left unset where it may be."""
    if isinstance(kind, mi.StructType):
        required = {field.name: strategy(field.type) for field in kind.fields if field.required}
        optional = {field.name: strategy(field.type) for field in kind.fields if not field.required}
        return st.fixed_dictionaries(required, optional=optional).map(lambda values: kind.cls(**values))
    if isinstance(kind, mi.UnionType):
        return st.one_of([strategy(member) for member in kind.types])
    if isinstance(kind, mi.IntType):
        low, high = _bounded(kind)
        return st.integers(-INT64 if low is None else int(low), INT64 if high is None else int(high))
    if isinstance(kind, mi.FloatType):
        return st.floats(allow_nan=False, allow_infinity=False)
    if isinstance(kind, mi.ListType):
        return st.lists(strategy(kind.item_type), max_size=3)
    if isinstance(kind, mi.TupleType):
        return st.tuples(*(strategy(item) for item in kind.item_types))
    if isinstance(kind, mi.DictType):
        return st.dictionaries(strategy(kind.key_type), strategy(kind.value_type), max_size=3)
    simple = {
        mi.StrType: st.text(max_size=8),
        mi.BoolType: st.booleans(),
        mi.NoneType: st.none(),
        mi.AnyType: json_values,
    }
    return simple[type(kind)]


@pytest.mark.parametrize("kind", KINDS, ids=lambda kind: kind.__name__)
@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_each_status_round_trips_through_its_json(kind, data):
    status = data.draw(strategy(mi.type_info(kind)))
    assert msgspec.json.decode(msgspec.json.encode(status), type=kind) == status


def test_every_built_in_service_has_its_kind_and_any_other_name_is_a_user_services():
    assert set(STATUS_TYPES) == set(Service)
    assert status_type("odometer") is UserServiceStatus


def test_a_status_key_names_its_kind_for_the_recordings_and_the_views_channel_schema():
    assert {service: status_type_of_key(KEYS.status(service)) for service in Service} == STATUS_TYPES
    assert status_type_of_key(KEYS.view_status) is ViewStatus
    assert status_type_of_key(KEYS.control_status) is ControlStatus
    assert status_type_of_key(Keys("rh1").status(user_service_name("odometer"))) is UserServiceStatus
    name, encoding, schema = key_json_schema(KEYS.status(Service.MOTOR)) or ("", "", b"")
    assert (name, encoding, json.loads(schema)) == ("MotorStatus", "jsonschema", msgspec.json.schema(MotorStatus))


STACK_CHUNKS = ("invent", "rh0", "status", "motor", "view", "control", "up", "odometer", "Bad", "")
CHUNK = st.sampled_from(STACK_CHUNKS) | st.text(max_size=8)
"""A key's chunk: one the stack's keys have, or any text (a slash in it makes more chunks)."""


@given(
    key=st.lists(CHUNK, min_size=1, max_size=5).map("/".join) | st.builds("invent/{}/{}/status".format, CHUNK, CHUNK)
)
def test_no_key_but_a_status_key_of_a_name_a_service_may_have_has_a_status_kind(key):
    parts = key.split("/")
    named = len(parts) == 4 and parts[0] == "invent" and parts[1] != "" and parts[3] == "status"
    may_be = named and (parts[2] in (*Service, "view", "control") or _user_name(parts[2]))
    assert (status_type_of_key(key) is not None) == may_be, key


def _user_name(name: str) -> bool:
    try:
        user_service_name(name)
    except ValueError:
        return False
    return True


def _reply(session: zenoh.Session, service: Service) -> bytes:
    replies = [reply.ok for reply in session.get(KEYS.status(service), timeout=5.0) if reply.ok is not None]
    assert len(replies) == 1, f"{service}: {len(replies)} replies"
    return replies[0].payload.to_bytes()


def test_every_service_of_a_real_loop_answers_a_status_its_kind_decodes(session):
    composition = Composition(session)
    try:
        drive = compose_the_loop(composition)
        wait_until(lambda: drive.finished() == 0, 60, "the drive to finish its 0.3 s")
        loop = (Service.SIM, Service.MOTOR, Service.ODOMETRY, Service.LOCALIZATION, Service.DRIVE)
        statuses = {
            service: msgspec.json.decode(_reply(session, service), type=status_type(service)) for service in loop
        }
    finally:
        composition.stop()
    sim, drive_status = statuses[Service.SIM], statuses[Service.DRIVE]
    assert isinstance(sim, SimStatus) and sim.steps >= 300 and sim.robot == "rh0"
    assert isinstance(drive_status, DriveStatus) and drive_status.state == "done" and drive_status.done is True
    assert isinstance(statuses[Service.ODOMETRY], OdometryStatus)
    assert statuses[Service.ODOMETRY].counters.wheel_angle_samples >= 300
    localization = statuses[Service.LOCALIZATION]
    assert isinstance(localization, LocalizationStatus) and localization.mode == "stub"
    assert isinstance(localization.fixes_published, int) and localization.fixes_published >= 1
    assert all(status.service == str(service) for service, status in statuses.items())
    health = loop_health(sim, {str(service): status for service, status in statuses.items()})
    assert health["torques"]["applied"] == sim.counters.torques_applied and set(health["services"]) == set(
        map(str, loop)
    )


def _answer_with(session: zenoh.Session, key: str, payload: bytes) -> zenoh.Queryable:
    return session.declare_queryable(key, lambda query: query.reply(key, payload))


@pytest.mark.parametrize(
    "payload",
    [b"not json", b"[]", b'{"service": "sim", "steps": "many"}', json.dumps({"state": math.inf}).encode()],
    ids=["not JSON", "not an object", "a field of the wrong type", "not JSON's number"],
)
def test_a_malformed_status_reply_is_counted_and_taken_as_no_reply(session, payload):
    key = KEYS.status(Service.SIM)
    queryable = _answer_with(session, key, payload)
    try:
        reader = StatusReader(session)
        assert wait_until(lambda: reader.bad_replies.get(key, 0) or reader.get(key, SimStatus), 5, "a reply") == 1
        assert reader.get(key, SimStatus) is None and reader.bad_replies == {key: 2}
        assert reader.get_with_own(key, SimStatus) is None and reader.bad_replies == {key: 3}
    finally:
        queryable.undeclare()


def test_a_status_of_another_kind_is_a_bad_reply_but_every_status_reads_as_a_service_status(session):
    key = KEYS.status(Service.SIM)
    motor_status = msgspec.json.encode(ServiceStatus(service="motor", robot="rh0", internal_errors=2))
    queryable = _answer_with(session, key, motor_status)
    try:
        reader = StatusReader(session)
        common = wait_until(lambda: reader.get(key, ServiceStatus), 5, "a reply")
        assert common.internal_errors == 2
        assert reader.get(key, SimStatus) is None and reader.bad_replies == {key: 1}
    finally:
        queryable.undeclare()
