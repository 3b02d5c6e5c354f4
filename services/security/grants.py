"""What each role may do: the access-control rules of a secure deployment, made from what the services declare.

:func:`grants` gives a role's rules on one robot, :func:`fleet_grants` an identity's in a fleet;
:func:`access_control` and :func:`fleet_access_control` turn them into the router's
``access_control`` section (default deny). A service's role is granted exactly its declaration
(:mod:`services.interfaces`, :func:`interface_grants`), which its node enforces; the ROS roles'
ROS side is the ROS graph of :mod:`services.ros2.graph`; the tools' roles read every key.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from schemas.interface import Interface
from schemas.keys import ROOT, Keys, Service, UserServiceName, all_robots_status
from schemas.topics import LATCHED_TOPICS, GoalMethod, LocalizationMethod, Method, MethodFamily
from services import interfaces
from services.config import Config
from services.config.sections import LocalizationMode
from services.ros2.graph import ACTION_SERVICES, ACTION_TOPICS, MOTOR_SERVICES, SUBSCRIPTIONS, BridgeGraph, bridge_graph
from services.ros2.wire import ADMIN_SPACE
from services.security.roles import FLEET_ROLES, SINGLE_ROBOT_ROLES, Identity, Role

DEFAULT_LOCALIZATION: LocalizationMode = "stub"
"""The localization mode a profile is granted for when none is said (``localization.mode``'s default)."""
DEFAULT_ROS = bridge_graph(Config(), environ={})
"""The ROS graph the ROS roles are granted by default: domain 0, the bridge's default namespace and node."""


def robot_bridge(ros: BridgeGraph, robot: str, publishes_clock: bool = True) -> BridgeGraph:
    """The ROS 2 bridge of ``robot`` in a fleet, by default: ``ros``'s domain, node name and TF
    layout, in the namespace ``<ros.namespace>/<robot>`` (``/rh1/odom``, ``/rh1/tf``, ``/rh1/cmd_vel``,
    ``/rh1/motor/stop``), so that no two robots' bridges are granted the same topics; ``/clock``, one
    for the world, only if ``publishes_clock`` (the fleet's first robot's bridge publishes it). With
    ``ros.tf_shared`` every bridge of the domain may publish on the shared ``/tf`` and ``/tf_static``."""
    return dataclasses.replace(ros, namespace=f"{ros.namespace}/{robot}", publishes_clock=publishes_clock)


class Message(StrEnum):
    """Zenoh's access-control message types."""

    PUT = "put"
    DECLARE_SUBSCRIBER = "declare_subscriber"
    DECLARE_QUERYABLE = "declare_queryable"
    QUERY = "query"
    REPLY = "reply"
    LIVELINESS_TOKEN = "liveliness_token"
    DECLARE_LIVELINESS_SUBSCRIBER = "declare_liveliness_subscriber"
    LIVELINESS_QUERY = "liveliness_query"


class Flow(StrEnum):
    """Seen from the router: ``ingress`` is what a session sends, ``egress`` what it is sent."""

    INGRESS = "ingress"
    EGRESS = "egress"


@dataclass(frozen=True)
class Grant:
    """One allow rule: these messages, in this flow, on these key expressions."""

    messages: tuple[Message, ...]
    flow: Flow
    key_exprs: tuple[str, ...]


def _methods(keys: Keys, family: MethodFamily) -> tuple[str, ...]:
    return tuple(keys.method(family, method) for method in Method)


def _goal_methods(keys: Keys) -> tuple[str, ...]:
    """The drive's goal queryables, ``drive/goal/send`` and ``drive/goal/cancel``: sending and
    canceling goals is a right of its own (docs/protocol.md section 8.8), the operator's and the
    robot's ROS 2 bridge's; only the drive serves them."""
    return tuple(keys.goal_method(method) for method in GoalMethod)


def _localization_methods(keys: Keys) -> tuple[str, ...]:
    """The localization's queryables, ``localization/initial_pose`` and ``.../global_localization``
    (amcl's): where the robot is, a right of the operator (``invent localize``) and the robot's ROS 2
    bridge (ROS's ``/initialpose``: ``initial_pose`` only)."""
    return tuple(keys.localization_method(method) for method in LocalizationMethod)


def interface_grants(interface: Interface, keys: Keys, followed: Sequence[UserServiceName] = ()) -> list[Grant]:
    """What a service may do, exactly what its :class:`Interface` declares (least privilege): put
    what it publishes; subscribe (and be sent) what it subscribes; serve its status, its latched
    keys and what it serves; query (and be answered on) what it queries; hold its own tokens. Liveliness (tokens carry no data) it may watch everywhere. ``followed``: the user
    services whose outputs and status a service that follows the lockstep participants (the sim) may
    subscribe and query."""
    everything = (f"{ROOT}/**",)
    service = interface.service
    subscribed = (
        *interface.subscribes,
        *((f"{keys.prefix}/{name}/**" for name in followed) if interface.follows_participants else ()),
    )
    served = (keys.status(service), *interface.serves, *interface.latched_published(keys))
    followed_statuses = (keys.status(name) for name in followed) if interface.follows_participants else ()
    queried = (*interface.queries, *followed_statuses)
    tokens = (
        keys.alive(service),
        *((keys.ticks_at_any_rate(service),) if interface.participates else ()),
        *((keys.observes_at_any_rate(service),) if interface.observes else ()),
    )
    granted = [
        Grant((Message.PUT,), Flow.INGRESS, interface.publishes),
        Grant((Message.DECLARE_SUBSCRIBER,), Flow.INGRESS, subscribed),
        Grant((Message.PUT,), Flow.EGRESS, subscribed),
        Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, served),
        # Queries reach a queryable only if the querier was let in; this lets them be delivered
        # (also a query on invent/*/*/status, which a rule must let through whole).
        Grant((Message.QUERY,), Flow.EGRESS, everything),
        Grant((Message.QUERY,), Flow.INGRESS, queried),
        Grant((Message.REPLY,), Flow.EGRESS, queried),
        Grant((Message.LIVELINESS_TOKEN,), Flow.INGRESS, tokens),
        Grant((Message.DECLARE_LIVELINESS_SUBSCRIBER, Message.LIVELINESS_QUERY), Flow.INGRESS, everything),
        # the tokens it watches, and the declarations that tell its publishers and queriers that
        # someone matches (no data)
        Grant(
            (Message.LIVELINESS_TOKEN, Message.DECLARE_SUBSCRIBER, Message.DECLARE_QUERYABLE), Flow.EGRESS, everything
        ),
    ]
    return [grant for grant in granted if grant.key_exprs]


def _ros_grants(role: Role, ros: BridgeGraph) -> list[Grant]:
    """The ROS side of the bridge (``ros2``) or of a ROS node (``ros_node``): rmw_zenoh's keys of
    domain ``ros.domain``, the graph's tokens, and a zenoh-ext advanced publisher's own keys
    (``<key>/@adv/...``: its cache's queryable, its detection token, its heartbeats)."""
    # ``**`` does not match a verbatim chunk (``@adv``): an advanced publisher's keys are named apart.
    domain = (f"{ros.domain}/**", f"{ros.domain}/**/@adv/**", f"{ADMIN_SPACE}/{ros.domain}/**")
    if role is Role.ROS_NODE:
        everything = (
            Message.PUT,
            Message.DECLARE_SUBSCRIBER,
            Message.DECLARE_QUERYABLE,
            Message.QUERY,
            Message.REPLY,
            Message.LIVELINESS_TOKEN,
            Message.DECLARE_LIVELINESS_SUBSCRIBER,
            Message.LIVELINESS_QUERY,
        )
        return [Grant(everything, Flow.INGRESS, domain), Grant(everything, Flow.EGRESS, domain)]
    # the NavigateToPose action server: its status and feedback topics and its three services
    topics = (*ros.publications.values(), *ACTION_TOPICS.values())
    published = tuple(ros.key(entity) for entity in topics)
    latched = tuple(ros.key(entity) for entity in topics if entity.qos.transient_local)
    advanced = tuple(f"{key}/@adv/**" for key in latched)
    subscribed = tuple(ros.key(entity) for entity in SUBSCRIPTIONS)
    services = (*MOTOR_SERVICES.values(), *ACTION_SERVICES.values(), *ros.odometry_services.values())
    served = tuple(ros.key(entity) for entity in services)
    return [
        Grant((Message.PUT,), Flow.INGRESS, (*published, *advanced)),
        Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, (*served, *advanced)),
        # a latched topic's cache answers a late subscriber with the samples, on the topic's own key
        Grant((Message.REPLY,), Flow.INGRESS, latched),
        Grant((Message.LIVELINESS_TOKEN,), Flow.INGRESS, (*ros.node_tokens, *advanced)),
        Grant((Message.DECLARE_SUBSCRIBER,), Flow.INGRESS, subscribed),
        Grant((Message.PUT,), Flow.EGRESS, subscribed),
        # a ROS node subscribing a topic of the bridge: the bridge's publisher matches it
        Grant((Message.DECLARE_SUBSCRIBER,), Flow.EGRESS, published),
        Grant((Message.QUERY,), Flow.EGRESS, (*served, *advanced)),
    ]


def _reading(keys: Keys) -> list[Grant]:
    """What the tools' roles (operator, observer, a ROS node) may do to read: subscribe to every key,
    liveliness, ``status`` and the latched keys."""
    everything = (f"{ROOT}/**",)
    return [
        Grant(
            (Message.DECLARE_SUBSCRIBER, Message.DECLARE_LIVELINESS_SUBSCRIBER, Message.LIVELINESS_QUERY),
            Flow.INGRESS,
            everything,
        ),
        # What a reader is sent: samples, replies, tokens, and the declarations that tell a
        # publisher or querier that someone matches.
        Grant(
            (
                Message.PUT,
                Message.REPLY,
                Message.LIVELINESS_TOKEN,
                Message.DECLARE_SUBSCRIBER,
                Message.DECLARE_QUERYABLE,
            ),
            Flow.EGRESS,
            everything,
        ),
        # Zenoh's rules match keys they include: this one lets a `get` on invent/*/*/status through;
        # the latched keys answer what was last published on them (a viewer started mid-run).
        Grant((Message.QUERY,), Flow.INGRESS, (all_robots_status(), *(keys.topic(t) for t in LATCHED_TOPICS))),
    ]


def grants(
    role: Role,
    keys: Keys,
    ros: BridgeGraph = DEFAULT_ROS,
    localization: LocalizationMode = DEFAULT_LOCALIZATION,
    followed: Sequence[UserServiceName] = (),
) -> list[Grant]:
    """Everything ``role`` may do on robot ``keys.robot`` (and, for the ROS roles, in the ROS domain
    and namespace of ``ros``); the router denies anything else. A service's role may do exactly what
    its interface declares (services/interfaces.py, :func:`interface_grants`), the localization's
    for ``localization.mode`` ``localization``; ``control`` gets the sim's and the motor's merged
    (:func:`_merged`) and its own ``control/status``; the tools' roles (operator, observer, a ROS
    node) read everything. ``followed``: the user services of the run, whose outputs the sim may
    subscribe (a lockstep participant's)."""
    config = Config()  # the rates of the tokens are not granted: every rate is
    if role is Role.CONTROL:
        # `invent control` runs the sim and the motor in one process on one session, logged in as
        # one user: it needs each one's rights (the sim's puts and bump queries, the motor's puts and
        # its methods served), and no more than the two together but the process's own status.
        process_status = Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, (keys.control_status,))
        sim_and_motor = [*grants(Role.SIM, keys, followed=followed), *grants(Role.MOTOR, keys)]
        return _merged([*sim_and_motor, process_status])
    if role is Role.OBSERVER:
        # `invent view` answers its own status; the queries on it are delivered, also as
        # invent/*/*/status (a rule lets through the key expressions it includes).
        return [
            *_reading(keys),
            Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, (keys.view_status,)),
            Grant((Message.QUERY,), Flow.EGRESS, (all_robots_status(),)),
        ]
    if role is Role.ROS_NODE:
        return [*_reading(keys), *_ros_grants(role, ros)]
    if role is Role.ROS2:
        # the bridge of a robot whose localization is amcl offers its topics and /initialpose
        graph = dataclasses.replace(ros, localization=ros.localization or localization == "amcl")
        return [*interface_grants(interfaces.ros2(keys, config, graph), keys), *_ros_grants(role, graph)]
    if role is Role.OPERATOR:
        return [
            *_reading(keys),
            Grant((Message.PUT,), Flow.INGRESS, (keys.drive_target_velocity, keys.run_summary)),
            Grant((Message.QUERY,), Flow.INGRESS, _methods(keys, MethodFamily.GUI)),
            Grant((Message.QUERY,), Flow.INGRESS, _goal_methods(keys)),
            Grant((Message.QUERY,), Flow.INGRESS, _localization_methods(keys)),  # invent localize
            Grant((Message.QUERY,), Flow.INGRESS, (keys.odometry_set_pose,)),  # invent call odometry/set_pose
        ]
    service = Service(role.value)
    if service is Service.LOCALIZATION:
        return interface_grants(interfaces.localization_in(keys, localization, config.localization.rate), keys)
    return interface_grants(interfaces.declared(service, keys, config), keys, followed)


@dataclass(frozen=True)
class UserServiceGrant:
    """A user service of a secure run (services/extension/): its name, the keys of other services it
    reads and the queryables it calls (each relative to the robot: ``odometry/pose``, ``drive/goal/send``)."""

    name: UserServiceName
    calls: tuple[str, ...] = ()
    reads: tuple[str, ...] = ()


def user_service_grants(user: UserServiceGrant, keys: Keys) -> list[Grant]:
    """What a user service may do on robot ``keys.robot``, as a built-in's (:func:`interface_grants`):
    read its ``reads``, its own keys and ``sim/clock`` (its runtime's); put, serve queryables and hold
    liveliness tokens only under its own name (``invent/<robot>/<name>/**``: its outputs, status,
    queryables, alive, ticks and observes tokens); query only its ``calls``."""
    own = f"{keys.prefix}/{user.name}/**"
    declared = Interface(
        user.name,
        publishes=(own,),
        subscribes=(own, keys.sim_clock, *(f"{keys.prefix}/{key}" for key in user.reads)),
        serves=(own,),
        queries=tuple(f"{keys.prefix}/{call}" for call in user.calls),
    )
    lockstep = (keys.ticks_at_any_rate(user.name), keys.observes_at_any_rate(user.name))
    return [*interface_grants(declared, keys), Grant((Message.LIVELINESS_TOKEN,), Flow.INGRESS, lockstep)]


def fleet_grants(
    identity: Identity,
    robots: Sequence[str],
    bridges: Mapping[str, BridgeGraph],
    localization: Mapping[str, LocalizationMode] | None = None,
    followed: Mapping[str, Sequence[UserServiceName]] | None = None,
) -> list[Grant]:
    """Everything ``identity`` may do in the fleet of ``robots``, whose ROS 2 bridges are
    ``bridges[robot]``: a per-robot role exactly what :func:`grants` gives its role on its own robot,
    nothing on any other; a fleet-wide role what :func:`grants` gives it on each robot of the fleet,
    merged (one rule per message set and flow, on the union of their key expressions). ValueError
    for :data:`SINGLE_ROBOT_ROLES` (a fleet has no control role). ``localization[robot]`` is robot's
    ``localization.mode`` (default :data:`DEFAULT_LOCALIZATION`)."""
    modes = localization or {}
    users = followed or {}
    if identity.role in SINGLE_ROBOT_ROLES:
        raise ValueError(f"a fleet has no {identity.role} role (it is one robot's)")
    if (identity.robot is None) != (identity.role in FLEET_ROLES):
        raise ValueError(f"role {identity.role} is {'fleet-wide' if identity.role in FLEET_ROLES else 'per robot'}")
    if identity.robot is not None:
        if identity.robot not in robots:
            raise ValueError(f"robot {identity.robot!r} is not in the fleet {', '.join(robots)}")
        robot = identity.robot
        return grants(
            identity.role, Keys(robot), bridges[robot], modes.get(robot, DEFAULT_LOCALIZATION), users.get(robot, ())
        )
    return _merged(
        grant
        for robot in robots
        for grant in grants(
            identity.role, Keys(robot), bridges[robot], modes.get(robot, DEFAULT_LOCALIZATION), users.get(robot, ())
        )
    )


def _merged(many: Iterable[Grant]) -> list[Grant]:
    """``many`` as one grant per (messages, flow), in first-seen order, each on the union of the key
    expressions, each once."""
    merged: dict[tuple[tuple[Message, ...], Flow], dict[str, None]] = {}
    for grant in many:
        merged.setdefault((grant.messages, grant.flow), {}).update(dict.fromkeys(grant.key_exprs))
    return [Grant(messages, flow, tuple(key_exprs)) for (messages, flow), key_exprs in merged.items()]


def access_control(
    users: dict[Role, str],
    keys: Keys,
    ros: BridgeGraph = DEFAULT_ROS,
    localization: LocalizationMode = DEFAULT_LOCALIZATION,
    followed: Sequence[UserServiceName] = (),
) -> dict[str, Any]:
    """The router's ``access_control`` section: one subject per role (by username), its grants (the
    localization's for ``localization.mode`` ``localization``; the sim's following ``followed``)."""
    return _access_control(
        (str(role), user, grants(role, keys, ros, localization, followed)) for role, user in users.items()
    )


def fleet_access_control(
    users: Mapping[Identity, str],
    robots: Sequence[str],
    bridges: Mapping[str, BridgeGraph],
    localization: Mapping[str, LocalizationMode] | None = None,
    followed: Mapping[str, Sequence[UserServiceName]] | None = None,
) -> dict[str, Any]:
    """The router's ``access_control`` section for a fleet: one subject per identity (by username),
    its :func:`fleet_grants` (each robot's localization for its mode in ``localization``, its sim
    following the user services ``followed[robot]``)."""
    return _access_control(
        (identity.user, user, fleet_grants(identity, robots, bridges, localization, followed))
        for identity, user in users.items()
    )


def access_control_section(entries: Iterable[tuple[str, str, list[Grant]]]) -> dict[str, Any]:
    """:func:`_access_control` of ``entries``: (subject's name, usrpwd user, its grants)."""
    return _access_control(entries)


def _access_control(entries: Iterable[tuple[str, str, list[Grant]]]) -> dict[str, Any]:
    """Default deny; for each (name, username, grants): subject ``role-<name>``, rules
    ``<name>-<n>``, policy ``policy-<name>``."""
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for role, user, granted in entries:
        subject = f"role-{role}"
        subjects.append({"id": subject, "usernames": [user]})
        ids = []
        for number, grant in enumerate(granted):
            rule_id = f"{role}-{number}"
            ids.append(rule_id)
            rules.append(
                {
                    "id": rule_id,
                    "permission": "allow",
                    "flows": [grant.flow.value],
                    "messages": [message.value for message in grant.messages],
                    "key_exprs": list(grant.key_exprs),
                }
            )
        policies.append({"id": f"policy-{role}", "rules": ids, "subjects": [subject]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
