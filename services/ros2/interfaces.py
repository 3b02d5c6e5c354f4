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

Actions likewise: ``nav2_msgs/action/NavigateToPose`` is built from its ``.action`` text (Jazzy's,
kept unchanged in tests/data/ros2_interfaces/ with where it came from) into the types rosidl derives
from an action: ``_Goal``, ``_Result``, ``_Feedback``, the services ``_SendGoal`` and ``_GetResult``
(each with its ``_Request``, ``_Response`` and ``_Event``), ``_FeedbackMessage``, and the action
itself, laid out as ``rosidl_adapter`` lays them out; ``action_msgs/srv/CancelGoal`` from its
``.srv``, the messages of ``action_msgs`` and ``unique_identifier_msgs`` from rosbags' Jazzy store.
Every hash is computed here, at run time; tests/test_ros2_navigate.py compares each with the type
descriptions ROS ships (action_msgs) and the one ROS's own generator writes for NavigateToPose.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from schemas.codec import BadInput

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

# rosbags (the [ros2] extra) is imported by the functions that use it: the security grants import
# the ROS graph's names from here, and every service imports the grants.

ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
JOINT_STATE = "sensor_msgs/msg/JointState"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
IMU = "sensor_msgs/msg/Imu"
OCCUPANCY_GRID = "nav_msgs/msg/OccupancyGrid"
PATH = "nav_msgs/msg/Path"
CLOCK = "rosgraph_msgs/msg/Clock"
STRING = "std_msgs/msg/String"
TWIST = "geometry_msgs/msg/Twist"
TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
TRIGGER = "std_srvs/srv/Trigger"
TRIGGER_REQUEST = f"{TRIGGER}_Request"
TRIGGER_RESPONSE = f"{TRIGGER}_Response"

_TRIGGER_SRV = ("", "bool success   # indicate successful run of triggered service\nstring message # informational")
"""std_srvs/srv/Trigger.srv: an empty request, then ``bool success`` and ``string message``."""
EMPTY = "std_srvs/srv/Empty"
EMPTY_REQUEST = f"{EMPTY}_Request"
EMPTY_RESPONSE = f"{EMPTY}_Response"
SET_ODOMETRY = "control_msgs/srv/SetOdometry"
SET_ODOMETRY_REQUEST = f"{SET_ODOMETRY}_Request"
SET_ODOMETRY_RESPONSE = f"{SET_ODOMETRY}_Response"
_SET_ODOMETRY_SRV = (
    "float64 x\nfloat64 y\nfloat64 z\nfloat64 roll\nfloat64 pitch\nfloat64 yaw",
    "bool success\nstring message",
)
"""control_msgs/srv/SetOdometry.srv (ros-controls/control_msgs, ``master`` and ``jazzy``), what
diff_drive_controller's ``~/set_odometry`` takes."""
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
POSE_ARRAY = "geometry_msgs/msg/PoseArray"
UUID = "unique_identifier_msgs/msg/UUID"
GOAL_INFO = "action_msgs/msg/GoalInfo"
GOAL_STATUS = "action_msgs/msg/GoalStatus"
GOAL_STATUS_ARRAY = "action_msgs/msg/GoalStatusArray"
CANCEL_GOAL = "action_msgs/srv/CancelGoal"
CANCEL_GOAL_REQUEST = f"{CANCEL_GOAL}_Request"
CANCEL_GOAL_RESPONSE = f"{CANCEL_GOAL}_Response"
NAVIGATE_TO_POSE = "nav2_msgs/action/NavigateToPose"
NAVIGATE_TO_POSE_GOAL = f"{NAVIGATE_TO_POSE}_Goal"
NAVIGATE_TO_POSE_RESULT = f"{NAVIGATE_TO_POSE}_Result"
NAVIGATE_TO_POSE_FEEDBACK = f"{NAVIGATE_TO_POSE}_Feedback"
NAVIGATE_TO_POSE_SEND_GOAL = f"{NAVIGATE_TO_POSE}_SendGoal"
NAVIGATE_TO_POSE_GET_RESULT = f"{NAVIGATE_TO_POSE}_GetResult"
NAVIGATE_TO_POSE_FEEDBACK_MESSAGE = f"{NAVIGATE_TO_POSE}_FeedbackMessage"

_CANCEL_GOAL_SRV = (
    f"{GOAL_INFO} goal_info",
    (
        "int8 ERROR_NONE=0\nint8 ERROR_REJECTED=1\nint8 ERROR_UNKNOWN_GOAL_ID=2\nint8 ERROR_GOAL_TERMINATED=3\n"
        f"int8 return_code\n{GOAL_INFO}[] goals_canceling"
    ),
)
"""action_msgs/srv/CancelGoal.srv (rcl_interfaces), its request and response (comments left out,
``GoalInfo`` named with its package)."""
NAVIGATE_TO_POSE_ACTION = """#goal definition
geometry_msgs/PoseStamped pose
string behavior_tree
---
#result definition

# Error codes
# Note: The expected priority order of the errors should match the message order
uint16 NONE=0

uint16 error_code
string error_msg
---
#feedback definition
geometry_msgs/PoseStamped current_pose
builtin_interfaces/Duration navigation_time
builtin_interfaces/Duration estimated_time_remaining
int16 number_of_recoveries
float32 distance_remaining
"""
"""nav2_msgs/action/NavigateToPose.action of navigation2's ``jazzy`` branch, unchanged (a test
compares it with the copy in tests/data/ros2_interfaces/, which says where it came from)."""
_ACTION_SEPARATOR = "---"
_SERVICE_EVENT_INFO = "service_msgs/msg/ServiceEventInfo"
_TIME = "builtin_interfaces/msg/Time"
_ACTION_MSGS_DEPENDENCIES = (GOAL_INFO, GOAL_STATUS, GOAL_STATUS_ARRAY, POSE_STAMPED, "builtin_interfaces/msg/Duration")
"""The messages of rosbags' Jazzy store the services and actions here refer to (with theirs)."""


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
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


@functools.cache
def services() -> Typestore:
    """A typestore of the services and actions (REP 2011 describes each for hashing), and of the
    messages they refer to: ``std_srvs/srv/Trigger``, ``action_msgs/srv/CancelGoal`` and
    ``nav2_msgs/action/NavigateToPose`` with every type derived from them."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.EMPTY)
    jazzy = messages()
    consts, fields = jazzy.fielddefs[_SERVICE_EVENT_INFO]
    store.register(
        {
            **_with_dependencies(jazzy, (_TIME, *_ACTION_MSGS_DEPENDENCIES)),
            _SERVICE_EVENT_INFO: (consts, [(name, _uint8_for_char(field)) for name, field in fields]),
        }
    )
    store.register(_service(TRIGGER, *_TRIGGER_SRV))
    store.register(_service(EMPTY, "", ""))
    store.register(_service(SET_ODOMETRY, *_SET_ODOMETRY_SRV))
    store.register(_service(CANCEL_GOAL, *_CANCEL_GOAL_SRV))
    store.register(_action(NAVIGATE_TO_POSE, NAVIGATE_TO_POSE_ACTION))
    return store


def _with_dependencies(store: Typestore, names: tuple[str, ...]) -> dict[str, Any]:
    """The field definitions of ``names`` in ``store`` and of every type they refer to."""
    found: dict[str, Any] = {}
    pending = list(names)
    while pending:
        name = pending.pop()
        if name in found:
            continue
        found[name] = store.fielddefs[name]
        pending += _referred(found[name][1])
    return found


def _referred(fields: list[tuple[str, Any]]) -> list[str]:
    """The message types a type's fields refer to (in arrays and sequences too)."""
    from rosbags.typesys.base import Nodetype

    names = []
    for _name, (kind, detail) in fields:
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            kind, detail = detail[0]
        if kind is Nodetype.NAME:
            names.append(detail)
    return names


def _service(service: str, request: str, response: str) -> dict[str, Any]:
    """The types ROS generates for a service from its ``.srv`` parts: ``_Request``, ``_Response``,
    ``_Event`` (the ServiceEventInfo and at most one of each), and the service itself, whose fields
    REP 2011 hashes: ``request_message``, ``response_message``, ``event_message``."""
    return _types(
        service,
        {
            "Request": request,
            "Response": response,
            "Event": f"{_SERVICE_EVENT_INFO} info\n{service}_Request[<=1] request\n{service}_Response[<=1] response",
            "": f"{service}_Request request_message\n{service}_Response response_message\n{service}_Event event_message",
        },
    )


def _action(action: str, text: str) -> dict[str, Any]:
    """The types rosidl derives from an ``.action`` (goal, result and feedback parts between
    ``---`` lines): ``_Goal``, ``_Result``, ``_Feedback``; the services ``_SendGoal`` (request
    ``goal_id`` and ``goal``, response ``accepted`` and ``stamp``) and ``_GetResult`` (request
    ``goal_id``, response ``status`` and ``result``); ``_FeedbackMessage`` (``goal_id``,
    ``feedback``); and the action, whose fields are the six."""
    lines = text.splitlines()
    cuts = [index for index, line in enumerate(lines) if line.strip() == _ACTION_SEPARATOR]
    if len(cuts) != 2:
        raise ValueError(f"{action}: an .action has three parts, between two {_ACTION_SEPARATOR!r} lines")
    goal, result, feedback = (
        "\n".join(part) for part in (lines[: cuts[0]], lines[cuts[0] + 1 : cuts[1]], lines[cuts[1] + 1 :])
    )
    return {
        **_types(action, {"Goal": goal, "Result": result, "Feedback": feedback}),
        **_service(f"{action}_SendGoal", f"{UUID} goal_id\n{action}_Goal goal", f"bool accepted\n{_TIME} stamp"),
        **_service(f"{action}_GetResult", f"{UUID} goal_id", f"int8 status\n{action}_Result result"),
        **_types(action, {"FeedbackMessage": f"{UUID} goal_id\n{action}_Feedback feedback"}),
        **_types(
            action,
            {
                "": f"{action}_Goal goal\n{action}_Result result\n{action}_Feedback feedback\n"
                f"{action}_SendGoal send_goal_service\n{action}_GetResult get_result_service\n"
                f"{action}_FeedbackMessage feedback_message"
            },
        ),
    }


def _uint8_for_char(field: Any) -> Any:
    """``char[N]`` as ROS's type description has it: ``uint8[N]``."""
    from rosbags.typesys.base import Nodetype

    kind, detail = field
    if kind is Nodetype.ARRAY and detail[0] == (Nodetype.BASE, ("char", 0)):
        return (Nodetype.ARRAY, ((Nodetype.BASE, ("uint8", 0)), detail[1]))
    return field


def _types(base: str, parts: dict[str, str]) -> dict[str, Any]:
    """rosbags' field definitions of ``<base>_<part>`` (``<base>`` for the part ``""``) from ``.msg``
    text. rosbags files any type under ``msg``; a service's parts keep ROS's name
    (``std_srvs/srv/Trigger_Request``), an action's are ROS's already (``nav2_msgs/action/...``)."""
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    for part, text in parts.items():
        name = f"{base}_{part}" if part else base
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


def _store(name: str) -> Typestore:
    """The typestore of a message (``pkg/msg/Type``), or of a service's or action's type (and of
    ServiceEventInfo, corrected there)."""
    return messages() if "/msg/" in name and name != _SERVICE_EVENT_INFO else services()


TYPE_HASHES = {
    CLOCK: "RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564",
    ODOMETRY: "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    TF_MESSAGE: "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    JOINT_STATE: "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    STRING: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    LASER_SCAN: "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828",
    IMU: "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
    OCCUPANCY_GRID: "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    PATH: "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
    POSE_ARRAY: "RIHS01_af0cc36d190e104d546d168d6b39df04fa4b4ccecf59cb4c9ed328d3d5004aa0",
    POSE_STAMPED: "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    POSE_WITH_COVARIANCE_STAMPED: "RIHS01_26432f9803e43727d3c8f668d1fdb3c630f548af631e2f4e31382371bfea3b6e",
    TWIST: "RIHS01_9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    TWIST_STAMPED: "RIHS01_5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
    TRIGGER: "RIHS01_eeff2cd6fa5ad9d27cdf4dec64818317839b62f212a91e6b5304b634b2062c5f",
    EMPTY: "RIHS01_5888399dedec5ccc85ea6451949fd2c9f97bfdf963f9a588821639fcd31b5d19",
    SET_ODOMETRY: "RIHS01_cf3fe2bf6627a67b4883ba6e876a7b46cdd991417ece9f4f4dac5452fbfdea48",
    GOAL_STATUS_ARRAY: "RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e",
    CANCEL_GOAL: "RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a",
    NAVIGATE_TO_POSE_SEND_GOAL: "RIHS01_a4fcb3bee1bf32e21a0e541a943b221aa0826996e2c98f079b47022b256f48b5",
    NAVIGATE_TO_POSE_GET_RESULT: "RIHS01_c407920357d566771e8882b4ef4d1f1a84ee922d609920ccd57faa6d6e391dc5",
    NAVIGATE_TO_POSE_FEEDBACK_MESSAGE: "RIHS01_9d1f6fa2eb975ce733b419ac2e97b134d8ff92b6478b6559feed9a50bdfd82b3",
}
"""The hash of every interface of the bridge's graph (services/ros2/graph.py), as rosbags computes it
(tests/test_extras.py checks each, and that the graph names no other): the secure profiles' grants
hold the bridge's keys, with these, and `invent secrets` runs where rosbags (the [ros2] extra) is not."""


def interface(name: str) -> Interface:
    """A message (``pkg/msg/Type``), service (``pkg/srv/Type``) or action type
    (``pkg/action/Type_SendGoal``, ...) with its RIHS01 hash."""
    known = TYPE_HASHES.get(name)
    return Interface(name, known if known is not None else _store(name).hash_rihs01(name))


def message_class(name: str) -> Any:
    """The dataclass of a message (or a service's or action's request, response, ...) type."""
    return _store(name).types[name]


def serialize(message: Any) -> bytes:
    """CDR, little-endian, with its 4-byte encapsulation header, as rmw_zenoh sends it."""
    name = message.__msgtype__
    return bytes(_store(name).serialize_cdr(message, name))


def deserialize(data: bytes, name: str) -> Any:
    """A message of type ``name`` from CDR; BadInput naming the type when it is not one."""
    store = _store(name)
    try:
        return store.deserialize_cdr(data, name)
    except Exception as error:  # noqa: BLE001 (rosbags raises what a truncated buffer makes: struct, index, value errors)
        raise BadInput(f"malformed CDR for {name}: {type(error).__name__}: {error}") from None
