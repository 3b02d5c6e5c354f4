"""What rmw_zenoh puts on the wire, as pure functions (no zenoh): data keys, liveliness tokens of
the ROS graph, QoS in the tokens' format, and the attachment every sample carries.

The layout is rmw_zenoh's (``docs/design.md`` and ``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``
of ros2/rmw_zenoh; docs/ros2.md says which releases, and what was checked against what):

- a topic's data key is ``<domain>/<name without its leading slash>/<type>/<type hash>``, with the
  type as ``<pkg>::msg::dds_::<Type>_`` and the hash ``RIHS01_<64 hex>``; a service's likewise
  (``<pkg>::srv::dds_::<Type>_``), served by a queryable;
- an entity of the graph holds a liveliness token
  ``@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>[/<name>/<type>/<hash>/<qos>]``
  in which every ``/`` inside a name is written ``%`` (an empty namespace or enclave is ``%``);
  ``ros2 node list``, ``ros2 topic list`` and ``ros2 service list`` are built from these tokens only;
- every sample, request and reply carries a 33-byte attachment: the sequence number (int64, from
  1, +1 per sample of a publisher), the source timestamp (int64 ns) and the 16-byte GID of the
  publisher (or, on a request and its reply, of the client), as zenoh-ext serialises
  ``(int64, int64, bytes)``. An rmw_zenoh subscriber drops a sample that has none.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass
from enum import IntEnum, StrEnum

from schemas.codec import BadInput

ADMIN_SPACE = "@ros2_lv"
TYPE_HASH_NOT_SUPPORTED = "TypeHashNotSupported"
"""What Humble's rmw_zenoh writes where later releases write the type's RIHS01 hash."""
GID_LENGTH = 16
_ATTACHMENT = struct.Struct("<qqB")
ATTACHMENT_LENGTH = _ATTACHMENT.size + GID_LENGTH
"""33 bytes: int64 sequence number, int64 source timestamp, the GID's length (16) and the GID."""
_SLASH_REPLACEMENT = "%"


class EntityKind(StrEnum):
    """The kind chunk of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


class Reliability(IntEnum):
    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(IntEnum):
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


class History(IntEnum):
    KEEP_LAST = 1
    KEEP_ALL = 2


@dataclass(frozen=True)
class Qos:
    """The QoS a ROS tool reads from an entity's token (deadline, lifespan and liveliness are
    always ROS's defaults here: infinite, infinite, automatic)."""

    depth: int = 10
    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    history: History = History.KEEP_LAST

    @property
    def transient_local(self) -> bool:
        return self.durability is Durability.TRANSIENT_LOCAL

    def token_chunk(self) -> str:
        """``R:D:H,depth:DLs,DLns:LSs,LSns:LV,LVs,LVns``, a field left empty where it equals
        rmw_zenoh's default (reliable, volatile, keep-last, depth 42, the rest ROS's defaults)."""

        def unless(value: int, default: int) -> str:
            return "" if value == default else str(value)

        return (
            f"{unless(self.reliability, Reliability.RELIABLE)}:{unless(self.durability, Durability.VOLATILE)}:"
            f"{unless(self.history, History.KEEP_LAST)},{unless(self.depth, RMW_ZENOH_DEFAULT_DEPTH)}:,:,:,,"
        )


RMW_ZENOH_DEFAULT_DEPTH = 42
"""The depth rmw_zenoh leaves out of a token (its QoS defaults' depth)."""
SYSTEM_DEFAULT = Qos()
"""ROS's default for a topic: reliable, volatile, keep-last 10."""
TF = Qos(depth=100)
"""What tf2's broadcaster and listener use for ``/tf``."""
LATCHED = Qos(depth=1, durability=Durability.TRANSIENT_LOCAL)
"""Reliable, transient-local, keep-last 1: a late subscriber still gets the last message.
``/tf_static`` and ``/robot_description``; ``map`` as Nav2's map_server offers it and
``global_costmap/costmap`` as Nav2's costmap publisher does (both
``rclcpp::QoS(rclcpp::KeepLast(1)).transient_local().reliable()``, navigation2's ``jazzy`` and
``kilted``; ``nav2::qos::LatchedPublisherQoS()`` after them, the same); ``amcl_pose`` as nav2_amcl
offers it (``rclcpp::QoS(rclcpp::KeepLast(1)).transient_local().reliable()``)."""
PLAN = Qos(depth=1)
"""Nav2's planner_server's ``plan`` (``create_publisher<nav_msgs::msg::Path>("plan", 1)``, ``jazzy``
and ``kilted``): reliable, volatile, keep-last 1 (navigation2's ``main`` keeps 10; a depth never
decides whether a subscription matches)."""
CLOCK = Qos(depth=1, reliability=Reliability.BEST_EFFORT)
"""rclcpp's ``ClockQoS``, what a node with ``use_sim_time`` subscribes ``/clock`` with."""
SENSOR_DATA = Qos(depth=5, reliability=Reliability.BEST_EFFORT)
"""rclcpp's ``SensorDataQoS`` (best effort, volatile, keep-last 5): ``scan`` and ``imu``, what
Nav2, slam_toolbox and robot_localization subscribe sensors with; ``particle_cloud``, as nav2_amcl
offers it."""
SERVICES = Qos()
"""ROS's services default (reliable, volatile, keep-last 10)."""
ACTION_STATUS = Qos(depth=1, durability=Durability.TRANSIENT_LOCAL)
"""rcl_action's status topic (``rcl_action_qos_profile_status_default``): reliable, transient-local,
keep-last 1."""


def absolute_namespace(namespace: str) -> str:
    """A namespace as ROS writes it: ``""`` (none) or ``/name[/name...]`` (``rh0`` and ``/rh0/`` are
    ``/rh0``; the configuration checks the names themselves)."""
    stripped = namespace.strip("/")
    return f"/{stripped}" if stripped else ""


def full_name(namespace: str, name: str) -> str:
    """The absolute name of a topic or service: ``("/rh0", "odom")`` -> ``/rh0/odom``; a name
    that starts with ``/`` is already absolute (``/tf`` and ``/clock`` are global by convention)."""
    return name if name.startswith("/") else f"{namespace}/{name}"


def mangle(name: str) -> str:
    """A name as one key chunk: every ``/`` written ``%`` (``/`` alone: ``%``)."""
    return name.replace("/", _SLASH_REPLACEMENT) if name else _SLASH_REPLACEMENT


def dds_type_name(interface: str) -> str:
    """``nav_msgs/msg/Odometry`` -> ``nav_msgs::msg::dds_::Odometry_`` (services likewise, ``srv``;
    an action's types, ``action``: ``nav2_msgs::action::dds_::NavigateToPose_SendGoal_``)."""
    package, kind, name = interface.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def data_key(domain: int, name: str, interface: str, type_hash: str) -> str:
    """The key a topic's samples (or a service's queries) travel on."""
    return f"{domain}/{name.strip('/')}/{dds_type_name(interface)}/{type_hash}"


def interface_of_dds_type(dds_type: str) -> str:
    """``nav_msgs::msg::dds_::Odometry_`` -> ``nav_msgs/msg/Odometry`` (services' and actions' types
    likewise); BadInput for another layout."""
    chunks = dds_type.split("::")
    if (
        len(chunks) != 4
        or chunks[1] not in ("msg", "srv", "action")
        or chunks[2] != "dds_"
        or not chunks[3].endswith("_")
    ):
        raise BadInput(f"{dds_type!r} is not a type as rmw_zenoh names one")
    return f"{chunks[0]}/{chunks[1]}/{chunks[3][:-1]}"


def parse_data_key(key: str) -> tuple[int, str, str, str]:
    """(domain, absolute name, interface, type hash) of a topic's data key (:func:`data_key`);
    BadInput for a key of another layout."""
    chunks = key.split("/")
    if len(chunks) < 4 or not chunks[0].isdigit():
        raise BadInput(f"{key!r} is not an rmw_zenoh data key (<domain>/<name>/<type>/<hash>)")
    return int(chunks[0]), "/" + "/".join(chunks[1:-2]), interface_of_dds_type(chunks[-2]), chunks[-1]


@dataclass(frozen=True)
class NodeIdentity:
    """One node of the ROS graph, as its tokens name it."""

    domain: int
    zid: str
    """The zenoh session's id, as ``str(session.zid())``."""
    namespace: str
    name: str
    node_id: int = 0
    enclave: str = ""

    def token(self) -> str:
        return self._prefix(self.node_id, EntityKind.NODE)

    def entity_token(
        self, entity_id: int, kind: EntityKind, name: str, interface: str, type_hash: str, qos: Qos
    ) -> str:
        """The token of a publisher, subscription, service or client of this node on ``name``."""
        return (
            f"{self._prefix(entity_id, kind)}/{mangle(name)}/{mangle(dds_type_name(interface))}/"
            f"{type_hash}/{qos.token_chunk()}"
        )

    def _prefix(self, entity_id: int, kind: EntityKind) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain}/{self.zid}/{self.node_id}/{entity_id}/{kind}/"
            f"{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}"
        )


def gid_of(token: str) -> bytes:
    """A publisher's (or client's) 16-byte GID: a hash of its liveliness token, as rmw_zenoh's
    is (it uses XXH3-128; any 16 bytes fixed for the entity serve, and BLAKE2b is in the stdlib)."""
    return hashlib.blake2b(token.encode(), digest_size=GID_LENGTH).digest()


@dataclass(frozen=True)
class Attachment:
    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        return _ATTACHMENT.pack(self.sequence_number, self.source_timestamp_ns, GID_LENGTH) + self.gid

    @classmethod
    def decode(cls, data: bytes | None) -> Attachment:
        """BadInput unless ``data`` is rmw_zenoh's 33-byte attachment with a non-negative sequence
        number and timestamp (what rmw_zenoh itself refuses)."""
        if data is None:
            raise BadInput("no attachment: not an rmw_zenoh sample (rmw_zenoh drops those too)")
        if len(data) != ATTACHMENT_LENGTH:
            raise BadInput(f"attachment of {len(data)} bytes, not {ATTACHMENT_LENGTH}")
        sequence_number, timestamp_ns, gid_length = _ATTACHMENT.unpack_from(data)
        if gid_length != GID_LENGTH:
            raise BadInput(f"attachment GID of {gid_length} bytes, not {GID_LENGTH}")
        if sequence_number < 0 or timestamp_ns < 0:
            raise BadInput(f"attachment sequence number {sequence_number} or timestamp {timestamp_ns} is negative")
        return cls(sequence_number, timestamp_ns, data[_ATTACHMENT.size :])


class Sequence:
    """One publisher's attachments: its GID, and sequence numbers from 1, +1 per sample."""

    def __init__(self, gid: bytes) -> None:
        self.gid = gid
        self.last = 0

    def next(self, timestamp_ns: int) -> bytes:
        self.last += 1
        return Attachment(self.last, timestamp_ns, self.gid).encode()
