"""The secure profile: zenoh's usrpwd authentication and access control, by role, TLS optional.

``invent secrets DIR`` and ``invent up --secure`` write one profile: fresh credentials for every
:class:`Role` (stdlib ``secrets``), the router's configuration (its user dictionary and
``access_control``, default deny) and one complete zenoh client configuration per role, so any
zenoh program opens a session as that role with ``zenoh.Config.from_file``. Every session of a
secure deployment is a **client**: zenoh applies access control on the router's transports only,
and peers talking directly would bypass it.

What each role may do is :func:`grants`; the rules are built from :class:`~schemas.keys.Keys`,
so they name exactly the keys the services use. Reading (subscribing, liveliness, queries on
``status`` and the latched keys) is open to every authenticated role; every put and every Motor
method query that no grant names is denied, and a session without valid credentials is refused
at connection.

A **fleet** (several robots in one world, :func:`write_fleet_profile`) has one user per robot for
each of :data:`PER_ROBOT_ROLES` (``rh1-motor``: the motor of ``rh1``, granted exactly what the
motor role is granted on ``rh1`` and nothing on any other robot) and one user for the whole fleet
for each of :data:`FLEET_ROLES` (``sim``: one simulator steps every robot; ``operator``,
``observer``, ``ros_node``), granted what that role may on every robot of the fleet.
"""

from __future__ import annotations

import dataclasses
import datetime
import ipaddress
import json
import os
import secrets
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from schemas.keys import (
    LATCHED_TOPICS,
    ROOT,
    Keys,
    Method,
    MethodFamily,
    Service,
    Topic,
    all_robots_status,
    validate_robot_name,
)
from services.config import Config
from services.ros2.graph import MOTOR_SERVICES, SUBSCRIPTIONS, BridgeGraph, bridge_graph
from services.ros2.wire import ADMIN_SPACE

ROUTER_CONFIG = "router.json5"
DICTIONARY = "dictionary.txt"
TLS_DIRECTORY = "tls"
CA_CERTIFICATE = "ca.pem"
ROUTER_CERTIFICATE = "router.pem"
ROUTER_KEY = "router-key.pem"
PASSWORD_BYTES = 24
CERTIFICATE_DAYS = 365
CLIENT_CONNECT_TIMEOUT_MS = 10_000
"""How long a client keeps trying to reach the router at start before it gives up (and its
process exits naming the failure): long enough for a router started a moment later, short enough
that wrong credentials are reported rather than waited on for ever."""
TLS_NAMES = ("localhost", "127.0.0.1")
"""Names the router's certificate is valid for by default (``--tls-name`` adds more)."""


DEFAULT_ROS = bridge_graph(Config(), environ={})
"""The ROS graph the ROS roles are granted by default: domain 0, the bridge's default namespace and node."""


class Role(StrEnum):
    """Who a session is. The five services, plus two for people and their tools."""

    SIM = Service.SIM.value
    MOTOR = Service.MOTOR.value
    ODOMETRY = Service.ODOMETRY.value
    LOCALIZATION = Service.LOCALIZATION.value
    DRIVE = Service.DRIVE.value
    ROS2 = Service.ROS2.value
    """The ROS 2 bridge: its ROS keys, ``drive/target_velocity`` and the Motor methods ROS calls."""
    ROS_NODE = "ros_node"
    """A ROS 2 node over rmw_zenoh (RViz, teleop, Nav2): anything in the ROS domain, reading ours."""
    OPERATOR = "operator"
    """Teleop or GUI: puts target velocities, calls the Motor methods (``motor/gui/*``); and
    ``invent up`` itself, which puts the run's summary (``up/run``) at the end of a run."""
    OBSERVER = "observer"
    """Watches: subscribes, gets ``status`` and liveliness, nothing else."""


PER_ROBOT_ROLES: tuple[Role, ...] = (Role.MOTOR, Role.ODOMETRY, Role.LOCALIZATION, Role.DRIVE, Role.ROS2)
"""In a fleet, each robot has its own user of each of these roles, allowed only that robot's keys."""
FLEET_ROLES: tuple[Role, ...] = tuple(role for role in Role if role not in PER_ROBOT_ROLES)
"""In a fleet, one user each for the whole fleet: the sim (one simulator steps every robot), ROS 2
nodes, the operator (``invent up`` among them) and the observer, each allowed on every robot what
its role is allowed on one."""


@dataclass(frozen=True)
class Identity:
    """Who a session logs in as: a role, and in a fleet the robot a per-robot role is for."""

    role: Role
    robot: str | None = None
    """None: a fleet-wide role, or any role of a single robot's profile."""

    @property
    def user(self) -> str:
        """The usrpwd user name, and the client file's name (``<user>.json5``): the role's name, or
        ``<robot>-<role>`` (``rh1-motor``). No role's name holds a ``-``, so the last ``-`` splits a
        user back into robot and role, and no two identities share a user or a file."""
        return str(self.role) if self.robot is None else f"{self.robot}-{self.role}"


def fleet_robots(robots: Iterable[str]) -> tuple[str, ...]:
    """``robots`` as a fleet: at least one, each a valid robot name (one key chunk), none twice;
    ValueError naming the first that is not."""
    fleet: list[str] = []
    for robot in robots:
        validate_robot_name(robot)
        if robot in fleet:
            raise ValueError(f"robot {robot!r} is named twice")
        fleet.append(robot)
    if not fleet:
        raise ValueError("a fleet has at least one robot")
    return tuple(fleet)


def fleet_identities(robots: Sequence[str]) -> tuple[Identity, ...]:
    """Every user of a fleet's profile: the fleet-wide roles, then each robot's per-robot roles."""
    return (
        *(Identity(role) for role in FLEET_ROLES),
        *(Identity(role, robot) for robot in robots for role in PER_ROBOT_ROLES),
    )


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


def _published_by(service: Service, keys: Keys) -> tuple[str, ...]:
    """The data keys a service publishes: those under its own name (``sim/...`` for the sim)."""
    return tuple(keys.topic(topic) for topic in Topic if topic.startswith(f"{service}/"))


def _methods(keys: Keys, family: MethodFamily) -> tuple[str, ...]:
    return tuple(keys.method(family, method) for method in Method)


def _ros_grants(role: Role, keys: Keys, ros: BridgeGraph) -> list[Grant]:
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
    published = tuple(ros.key(entity) for entity in ros.publications.values())
    latched = tuple(ros.key(entity) for entity in ros.publications.values() if entity.qos.transient_local)
    advanced = tuple(f"{key}/@adv/**" for key in latched)
    subscribed = tuple(ros.key(entity) for entity in SUBSCRIPTIONS)
    served = tuple(ros.key(entity) for entity in MOTOR_SERVICES.values())
    return [
        Grant((Message.PUT,), Flow.INGRESS, (*published, *advanced, keys.drive_target_velocity)),
        Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, (*served, *advanced)),
        # a latched topic's cache answers a late subscriber with the samples, on the topic's own key
        Grant((Message.REPLY,), Flow.INGRESS, latched),
        Grant((Message.LIVELINESS_TOKEN,), Flow.INGRESS, (*ros.node_tokens, *advanced)),
        Grant((Message.DECLARE_SUBSCRIBER,), Flow.INGRESS, subscribed),
        Grant((Message.PUT,), Flow.EGRESS, subscribed),
        # a ROS node subscribing a topic of the bridge: the bridge's publisher matches it
        Grant((Message.DECLARE_SUBSCRIBER,), Flow.EGRESS, published),
        Grant((Message.QUERY,), Flow.EGRESS, (*served, *advanced)),
        Grant((Message.QUERY,), Flow.INGRESS, tuple(keys.method(MethodFamily.GUI, m) for m in MOTOR_SERVICES)),
    ]


def grants(role: Role, keys: Keys, ros: BridgeGraph = DEFAULT_ROS) -> list[Grant]:
    """Everything ``role`` may do on robot ``keys.robot`` (and, for the ROS roles, in the ROS domain
    and namespace of ``ros``); the router denies anything else."""
    everything = (f"{ROOT}/**",)
    reading = [
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
    if role is Role.OBSERVER:
        # `invent view` answers its own status; the queries on it are delivered, also as
        # invent/*/*/status (a rule lets through the key expressions it includes).
        return [
            *reading,
            Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, (keys.view_status,)),
            Grant((Message.QUERY,), Flow.EGRESS, (all_robots_status(),)),
        ]
    if role in (Role.ROS2, Role.ROS_NODE):
        own_status = [
            Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, (keys.status(Service.ROS2),)),
            # as for every service: a query on invent/*/*/status must be let through to it whole
            Grant((Message.QUERY,), Flow.EGRESS, everything),
        ]
        own_token = [
            Grant(
                (Message.LIVELINESS_TOKEN,),
                Flow.INGRESS,
                (keys.alive(Service.ROS2), keys.observes_at_any_rate(Service.ROS2)),
            )
        ]
        service_own = [*own_status, *own_token] if role is Role.ROS2 else []
        return [*reading, *service_own, *_ros_grants(role, keys, ros)]
    if role is Role.OPERATOR:
        return [
            *reading,
            Grant((Message.PUT,), Flow.INGRESS, (keys.drive_target_velocity, keys.run_summary)),
            Grant((Message.QUERY,), Flow.INGRESS, _methods(keys, MethodFamily.GUI)),
        ]
    service = Service(role.value)
    served = (keys.status(service),) + tuple(
        keys.topic(topic) for topic in LATCHED_TOPICS if topic.startswith(f"{service}/")
    )
    if service is Service.MOTOR:
        served += _methods(keys, MethodFamily.GUI) + _methods(keys, MethodFamily.BUMP)
    own = [
        Grant((Message.LIVELINESS_TOKEN,), Flow.INGRESS, (keys.alive(service), keys.ticks_at_any_rate(service))),
        Grant((Message.DECLARE_QUERYABLE, Message.REPLY), Flow.INGRESS, served),
        # Queries reach a queryable only if the querier was let in; this lets them be delivered.
        Grant((Message.QUERY,), Flow.EGRESS, everything),
        Grant((Message.PUT,), Flow.INGRESS, _published_by(service, keys)),
    ]
    if service is Service.SIM:
        own.append(Grant((Message.QUERY,), Flow.INGRESS, _methods(keys, MethodFamily.BUMP)))
    return [*reading, *own]


def fleet_grants(identity: Identity, robots: Sequence[str], bridges: Mapping[str, BridgeGraph]) -> list[Grant]:
    """Everything ``identity`` may do in the fleet of ``robots``, whose ROS 2 bridges are
    ``bridges[robot]``: a per-robot role exactly what :func:`grants` gives its role on its own robot,
    nothing on any other; a fleet-wide role what :func:`grants` gives it on each robot of the fleet,
    merged (one rule per message set and flow, on the union of their key expressions)."""
    if (identity.robot is None) != (identity.role in FLEET_ROLES):
        raise ValueError(f"role {identity.role} is {'fleet-wide' if identity.role in FLEET_ROLES else 'per robot'}")
    if identity.robot is not None:
        if identity.robot not in robots:
            raise ValueError(f"robot {identity.robot!r} is not in the fleet {', '.join(robots)}")
        return grants(identity.role, Keys(identity.robot), bridges[identity.robot])
    return _merged(grant for robot in robots for grant in grants(identity.role, Keys(robot), bridges[robot]))


def _merged(many: Iterable[Grant]) -> list[Grant]:
    """``many`` as one grant per (messages, flow), in first-seen order, each on the union of the key
    expressions, each once."""
    merged: dict[tuple[tuple[Message, ...], Flow], dict[str, None]] = {}
    for grant in many:
        merged.setdefault((grant.messages, grant.flow), {}).update(dict.fromkeys(grant.key_exprs))
    return [Grant(messages, flow, tuple(key_exprs)) for (messages, flow), key_exprs in merged.items()]


def access_control(users: dict[Role, str], keys: Keys, ros: BridgeGraph = DEFAULT_ROS) -> dict[str, Any]:
    """The router's ``access_control`` section: one subject per role (by username), its grants."""
    return _access_control((str(role), user, grants(role, keys, ros)) for role, user in users.items())


def fleet_access_control(
    users: Mapping[Identity, str], robots: Sequence[str], bridges: Mapping[str, BridgeGraph]
) -> dict[str, Any]:
    """The router's ``access_control`` section for a fleet: one subject per identity (by username),
    its :func:`fleet_grants`."""
    return _access_control(
        (identity.user, user, fleet_grants(identity, robots, bridges)) for identity, user in users.items()
    )


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


@dataclass(frozen=True)
class Credentials:
    user: str
    password: str


def fresh_credentials() -> dict[Role, Credentials]:
    """One user per role, named after it, with a new random password."""
    return {role: Credentials(str(role), _fresh_password()) for role in Role}


def _fresh_password() -> str:
    return secrets.token_urlsafe(PASSWORD_BYTES)


@dataclass(frozen=True)
class Profile:
    """The files of one secure deployment, as written by :func:`write_profile`."""

    directory: Path
    endpoint: str
    """Where the clients connect (``tls/...`` with TLS)."""
    router_listen: tuple[str, ...]
    tls: bool
    roles: tuple[Role, ...] = field(default=tuple(Role))
    robots: tuple[str, ...] = ()
    """The fleet's robots (:func:`write_fleet_profile`); empty for a single robot's profile."""

    @property
    def router_config(self) -> Path:
        return self.directory / ROUTER_CONFIG

    @property
    def identities(self) -> tuple[Identity, ...]:
        """Every user of the profile, one client file each: each role, for a single robot; the
        fleet-wide roles and each robot's per-robot roles, for a fleet."""
        return fleet_identities(self.robots) if self.robots else tuple(Identity(role) for role in self.roles)

    def identity(self, role: Role, robot: str | None = None) -> Identity:
        """Who runs ``role`` (for ``robot``, in a fleet): a fleet-wide role is one identity whatever
        the robot; a per-robot role of a fleet needs one of its robots. ValueError otherwise."""
        if not self.robots:
            if robot is not None:
                raise ValueError(f"a single robot's profile has no per-robot users (asked for {robot!r})")
            return Identity(role)
        if robot is not None and robot not in self.robots:
            raise ValueError(f"robot {robot!r} is not in the fleet {', '.join(self.robots)}")
        if role in FLEET_ROLES:
            return Identity(role)
        if robot is None:
            raise ValueError(f"role {role} is per robot in a fleet: name one of {', '.join(self.robots)}")
        return Identity(role, robot)

    def client_config(self, role: Role, robot: str | None = None) -> Path:
        """The client file of ``role`` (of ``robot``'s, for a per-robot role in a fleet): ``<role>.json5``,
        or ``<robot>-<role>.json5`` (:attr:`Identity.user`); ValueError as :meth:`identity`."""
        return self.directory / f"{self.identity(role, robot).user}.json5"


def _with_scheme(endpoint: str, tls: bool) -> str:
    """``endpoint`` (``tcp/HOST:PORT`` or ``tls/HOST:PORT``) with the profile's scheme; ValueError
    for anything else."""
    scheme, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    if scheme not in ("tcp", "tls") or not host or not port.isdigit():
        raise ValueError(f"endpoint {endpoint!r}: expected tcp/HOST:PORT or tls/HOST:PORT")
    return f"{'tls' if tls else scheme}/{address}"


def write_profile(
    directory: Path,
    keys: Keys,
    *,
    endpoint: str,
    router_listen: Sequence[str] = (),
    tls: bool = False,
    tls_names: Iterable[str] = (),
    seen_as: Path | None = None,
    router_base: dict[str, Any] | None = None,
    ros: BridgeGraph = DEFAULT_ROS,
) -> Profile:
    """Write a fresh profile into ``directory`` (created 0700; every file 0600).

    ``endpoint`` is where clients connect, ``router_listen`` where the router listens (default:
    ``endpoint``). ``seen_as`` is the path the router and clients will see ``directory`` at (a
    container's mount point; default the directory itself). ``router_base`` holds extra sections
    of the router's configuration (zenohd's plugins). With ``tls`` every endpoint is ``tls/``
    and a local CA signs the router's certificate for ``localhost``, ``127.0.0.1`` and
    ``tls_names``. ``ros`` is the ROS domain and the bridge's namespace the ROS roles are granted.
    """
    credentials = fresh_credentials()
    return _write_profile(
        directory,
        {Identity(role): login for role, login in credentials.items()},
        access_control({role: c.user for role, c in credentials.items()}, keys, ros),
        endpoint=endpoint,
        router_listen=router_listen,
        tls=tls,
        tls_names=tls_names,
        seen_as=seen_as,
        router_base=router_base,
    )


def write_fleet_profile(
    directory: Path,
    robots: Iterable[str],
    *,
    endpoint: str,
    router_listen: Sequence[str] = (),
    tls: bool = False,
    tls_names: Iterable[str] = (),
    seen_as: Path | None = None,
    router_base: dict[str, Any] | None = None,
    ros: BridgeGraph = DEFAULT_ROS,
    bridges: Mapping[str, BridgeGraph] | None = None,
) -> Profile:
    """Write a fresh profile for the fleet of ``robots`` (several robots in one world) into
    ``directory``, as :func:`write_profile` does for one robot (same arguments, same files).

    The users (:func:`fleet_identities`, :attr:`Identity.user`) are the fleet-wide roles
    (``sim``, ``ros_node``, ``operator``, ``observer``) and, for each robot, ``<robot>-<role>`` for
    each of :data:`PER_ROBOT_ROLES` (``rh1-motor``); each has its client file ``<user>.json5``
    beside ``router.json5`` (:meth:`Profile.client_config`). Robot ``r``'s ROS 2 bridge is granted
    ``bridges[r]``, by default :func:`robot_bridge` of ``ros`` (namespace ``/<r>``; ``/clock`` for the
    first robot's only); ``ros_node`` the domains of them all. ValueError for a bad fleet
    (:func:`fleet_robots`) or endpoint.
    """
    fleet = fleet_robots(robots)
    graphs = {
        robot: (bridges or {}).get(robot) or robot_bridge(ros, robot, publishes_clock=index == 0)
        for index, robot in enumerate(fleet)
    }
    credentials = {identity: Credentials(identity.user, _fresh_password()) for identity in fleet_identities(fleet)}
    return _write_profile(
        directory,
        credentials,
        fleet_access_control({identity: c.user for identity, c in credentials.items()}, fleet, graphs),
        endpoint=endpoint,
        router_listen=router_listen,
        tls=tls,
        tls_names=tls_names,
        seen_as=seen_as,
        router_base=router_base,
        robots=fleet,
    )


def _write_profile(
    directory: Path,
    credentials: Mapping[Identity, Credentials],
    rules: dict[str, Any],
    *,
    endpoint: str,
    router_listen: Sequence[str],
    tls: bool,
    tls_names: Iterable[str],
    seen_as: Path | None,
    router_base: dict[str, Any] | None,
    robots: tuple[str, ...] = (),
) -> Profile:
    """The files of :func:`write_profile` and :func:`write_fleet_profile`: one user and one client
    file per identity of ``credentials``, the router's configuration with ``rules``, its ``access_control``."""
    directory.mkdir(parents=True, exist_ok=True)
    directory.chmod(0o700)
    seen = (seen_as or directory).absolute()
    endpoint = _with_scheme(endpoint, tls)
    listen = [_with_scheme(address, tls) for address in router_listen] or [endpoint]
    _write_private(directory / DICTIONARY, "".join(f"{c.user}:{c.password}\n" for c in credentials.values()))
    router: dict[str, Any] = {
        **(router_base or {}),
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "delay": 0},
        "transport": {"auth": {"usrpwd": {"dictionary_file": str(seen / DICTIONARY)}}},
        "access_control": rules,
    }
    client_tls: dict[str, Any] = {}
    if tls:
        names = (*TLS_NAMES, *tls_names)
        _write_tls(directory / TLS_DIRECTORY, names)
        tls_dir = seen / TLS_DIRECTORY
        router["transport"]["link"] = {
            "tls": {
                "listen_certificate": str(tls_dir / ROUTER_CERTIFICATE),
                "listen_private_key": str(tls_dir / ROUTER_KEY),
            }
        }
        client_tls = {"link": {"tls": {"root_ca_certificate": str(tls_dir / CA_CERTIFICATE)}}}
    _write_private(directory / ROUTER_CONFIG, _json5(router, "the router of an invent secure deployment"))
    profile = Profile(directory, endpoint, tuple(listen), tls, robots=robots)
    for identity, login in credentials.items():
        client = {
            "mode": "client",
            "connect": {"endpoints": [endpoint], "timeout_ms": CLIENT_CONNECT_TIMEOUT_MS},
            "listen": {"endpoints": []},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"auth": {"usrpwd": {"user": login.user, "password": login.password}}, **client_tls},
        }
        if identity.role in (Role.ROS2, Role.ROS_NODE):
            # zenoh-ext advanced publishers with a cache (ROS's transient-local topics) need timestamps.
            client["timestamping"] = {"enabled": True}
        what = f"role {identity.role}" + (f" of robot {identity.robot}" if identity.robot is not None else "")
        _write_private(
            profile.client_config(identity.role, identity.robot),
            _json5(client, f"{what} of an invent secure deployment"),
        )
    return profile


def _json5(config: dict[str, Any], what: str) -> str:
    return f"// zenoh configuration: {what}. Generated; holds secrets.\n{json.dumps(config, indent=2)}\n"


def _write_private(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` readable by its owner only, from the moment it exists."""
    path.unlink(missing_ok=True)
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(descriptor, "w") as file:
        file.write(text)


def _write_tls(directory: Path, names: Sequence[str]) -> None:
    """A local CA (its key is not kept) and the router's key and certificate, signed by it."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    directory.mkdir(parents=True, exist_ok=True)
    directory.chmod(0o700)
    now = datetime.datetime.now(datetime.UTC)
    valid_until = now + datetime.timedelta(days=CERTIFICATE_DAYS)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "invent-zenoh local CA")])
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(valid_until)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                key_cert_sign=True,
                crl_sign=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    router_key = ec.generate_private_key(ec.SECP256R1())
    router = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, names[0])]))
        .issuer_name(ca_name)
        .public_key(router_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now)
        .not_valid_after(valid_until)
        .add_extension(x509.SubjectAlternativeName([_general_name(name) for name in names]), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    _write_private(directory / CA_CERTIFICATE, ca.public_bytes(serialization.Encoding.PEM).decode())
    _write_private(directory / ROUTER_CERTIFICATE, router.public_bytes(serialization.Encoding.PEM).decode())
    _write_private(
        directory / ROUTER_KEY,
        router_key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        ).decode(),
    )


def _general_name(name: str) -> Any:
    from cryptography import x509

    try:
        return x509.IPAddress(ipaddress.ip_address(name))
    except ValueError:
        return x509.DNSName(name)
