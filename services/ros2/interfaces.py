"""The ROS 2 interfaces the bridge speaks, their CDR and their RIHS01 type hashes, all from
``rosbags`` (pure Python) and the interfaces' own definitions: nothing here is typed in from a
ROS install.

Messages come from rosbags' Jazzy typestore (Kilted's and Rolling's definitions of these types
are the same, and so are their hashes). Services are not in it: ``std_srvs/srv/Trigger`` is built
from its ``.srv`` text, with the ``Request``, ``Response`` and ``Event`` messages ROS generates for
every service, and its hash is REP 2011's hash of the service's type description (the three as
fields ``request_message``, ``response_message``, ``event_message``). One correction to rosbags:
``service_msgs/msg/ServiceEventInfo`` declares ``char[16] client_gid``, and ROS's type description
maps a ``.msg`` ``char`` to ``uint8`` (rosidl_adapter), so the event is hashed with ``uint8[16]``;
with rosbags' ``char`` the Trigger hash differs from the one ROS computes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from schemas.codec import BadInput

ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
JOINT_STATE = "sensor_msgs/msg/JointState"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
IMU = "sensor_msgs/msg/Imu"
CLOCK = "rosgraph_msgs/msg/Clock"
STRING = "std_msgs/msg/String"
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
TRIGGER = "std_srvs/srv/Trigger"
TRIGGER_REQUEST = f"{TRIGGER}_Request"
TRIGGER_RESPONSE = f"{TRIGGER}_Response"

_TRIGGER_SRV = ("", "bool success   # indicate successful run of triggered service\nstring message # informational")
"""std_srvs/srv/Trigger.srv: an empty request, then ``bool success`` and ``string message``."""
_SERVICE_EVENT_INFO = "service_msgs/msg/ServiceEventInfo"
_TIME = "builtin_interfaces/msg/Time"


@dataclass(frozen=True)
class Interface:
    """A message or service type as the wire names it."""

    name: str
    """``nav_msgs/msg/Odometry``"""
    type_hash: str
    """``RIHS01_<64 hex>``"""


@functools.cache
def messages() -> Typestore:
    """rosbags' typestore of ROS 2 Jazzy: every message type the bridge publishes or takes."""
    return get_typestore(Stores.ROS2_JAZZY)


@functools.cache
def services() -> Typestore:
    """A typestore holding ``std_srvs/srv/Trigger``: its request, response and event messages and
    the service itself as REP 2011 describes a service for hashing."""
    store = get_typestore(Stores.EMPTY)
    jazzy = messages()
    consts, fields = jazzy.fielddefs[_SERVICE_EVENT_INFO]
    store.register(
        {
            _TIME: jazzy.fielddefs[_TIME],
            _SERVICE_EVENT_INFO: (consts, [(name, _uint8_for_char(field)) for name, field in fields]),
        }
    )
    request, response = _TRIGGER_SRV
    store.register(
        _service_types(
            TRIGGER,
            {
                "Request": request,
                "Response": response,
                "Event": f"{_SERVICE_EVENT_INFO} info\n{TRIGGER_REQUEST}[<=1] request\n{TRIGGER_RESPONSE}[<=1] response",
            },
        )
    )
    store.register(
        _service_types(
            TRIGGER,
            {
                "": f"{TRIGGER_REQUEST} request_message\n{TRIGGER_RESPONSE} response_message\n{TRIGGER}_Event event_message"
            },
        )
    )
    return store


def _uint8_for_char(field: Any) -> Any:
    """``char[N]`` as ROS's type description has it: ``uint8[N]``."""
    kind, detail = field
    if kind is Nodetype.ARRAY and detail[0] == (Nodetype.BASE, ("char", 0)):
        return (Nodetype.ARRAY, ((Nodetype.BASE, ("uint8", 0)), detail[1]))
    return field


def _service_types(service: str, parts: dict[str, str]) -> dict[str, Any]:
    """rosbags' field definitions of ``<service>_<part>`` from ``.msg`` text. rosbags files any type
    under ``msg``; a service's parts keep ROS's name (``std_srvs/srv/Trigger_Request``)."""
    types: dict[str, Any] = {}
    for part, text in parts.items():
        name = f"{service}_{part}" if part else service
        types.update(_srv_names(get_types_from_msg(text, name)))
    return types


def _srv_names(value: Any) -> Any:
    if isinstance(value, str):
        return value.replace("/srv/msg/", "/srv/")
    if isinstance(value, tuple | list):
        return type(value)(_srv_names(item) for item in value)
    if isinstance(value, dict):
        return {_srv_names(key): _srv_names(item) for key, item in value.items()}
    return value


def interface(name: str) -> Interface:
    """A message (``pkg/msg/Type``) or service (``pkg/srv/Type``) with its RIHS01 hash."""
    store = services() if "/srv/" in name else messages()
    return Interface(name, store.hash_rihs01(name))


def message_class(name: str) -> Any:
    """The dataclass of a message (or a service's request or response) type."""
    store = services() if "/srv/" in name else messages()
    return store.types[name]


def serialize(message: Any) -> bytes:
    """CDR, little-endian, with its 4-byte encapsulation header, as rmw_zenoh sends it."""
    name = message.__msgtype__
    store = services() if "/srv/" in name else messages()
    return bytes(store.serialize_cdr(message, name))


def deserialize(data: bytes, name: str) -> Any:
    """A message of type ``name`` from CDR; BadInput naming the type when it is not one."""
    store = services() if "/srv/" in name else messages()
    try:
        return store.deserialize_cdr(data, name)
    except Exception as error:  # noqa: BLE001 (rosbags raises what a truncated buffer makes: struct, index, value errors)
        raise BadInput(f"malformed CDR for {name}: {type(error).__name__}: {error}") from None
