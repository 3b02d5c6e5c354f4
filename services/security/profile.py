"""The files of a secure deployment (a profile): fresh credentials, the router's configuration with
its user dictionary and access control, and one complete zenoh client configuration per user.

One writer, :func:`_write_files`, writes every profile; :func:`write_profile` (one robot) and
:func:`write_fleet_profile` (several) differ only in who the users are and what they are granted.
"""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Required, TypedDict, Unpack

from schemas.keys import Keys
from services.config.sections import LocalizationMode
from services.ros2.graph import BridgeGraph
from services.security.grants import (
    DEFAULT_LOCALIZATION,
    DEFAULT_ROS,
    UserServiceGrant,
    access_control,
    access_control_section,
    fleet_access_control,
    robot_bridge,
    user_service_grants,
)
from services.security.roles import FLEET_ROLES, SINGLE_ROBOT_ROLES, Identity, Role, fleet_identities, fleet_robots
from services.security.tls import CA_CERTIFICATE, ROUTER_CERTIFICATE, ROUTER_KEY, TLS_DIRECTORY, TLS_NAMES, certificates

ROUTER_CONFIG = "router.json5"
DICTIONARY = "dictionary.txt"
PASSWORD_BYTES = 24
CLIENT_CONNECT_TIMEOUT_MS = 10_000
"""How long a client keeps trying to reach the router at start before it gives up (and its
process exits naming the failure): long enough for a router started a moment later, short enough
that wrong credentials are reported rather than waited on for ever."""


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
    user_services: tuple[str, ...] = ()
    """The users of the services of one's own (services/extension/): ``<name>``, in a fleet
    ``<robot>-<name>``; each has its client file ``<user>.json5``."""

    def user_service_config(self, name: str, robot: str | None = None) -> Path:
        """The client file of user service ``name`` (of ``robot``'s, in a fleet): ``<name>.json5`` or
        ``<robot>-<name>.json5`` (no role is named as a user service may be: schemas.keys.RESERVED_NAMES,
        and no name holds a ``-``). ValueError for one the profile does not have."""
        user = name if robot is None else f"{robot}-{name}"
        if user not in self.user_services:
            raise ValueError(f"user service {user!r} has no credentials in {self.directory}")
        return self.directory / f"{user}.json5"

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
        the robot; a per-robot role of a fleet needs one of its robots; a fleet has no control role
        (:data:`SINGLE_ROBOT_ROLES`: it is one robot's). ValueError otherwise."""
        if not self.robots:
            if robot is not None:
                raise ValueError(f"a single robot's profile has no per-robot users (asked for {robot!r})")
            return Identity(role)
        if role in SINGLE_ROBOT_ROLES:
            raise ValueError(f"a fleet has no {role} role (it is one robot's)")
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


class Deployment(TypedDict, total=False):
    """Where a profile's router listens and its clients connect, and how: the keyword arguments
    :func:`write_profile` and :func:`write_fleet_profile` share.

    ``endpoint`` is where clients connect, ``router_listen`` where the router listens (default:
    ``endpoint``). ``seen_as`` is the path the router and clients will see the profile's directory
    at (a container's mount point; default the directory itself). ``router_base`` holds extra
    sections of the router's configuration (zenohd's plugins). With ``tls`` every endpoint is
    ``tls/`` and a local CA signs the router's certificate for ``localhost``, ``127.0.0.1`` and
    ``tls_names``."""

    endpoint: Required[str]
    router_listen: Sequence[str]
    tls: bool
    tls_names: Iterable[str]
    seen_as: Path | None
    router_base: dict[str, Any] | None


def write_profile(
    directory: Path,
    keys: Keys,
    *,
    ros: BridgeGraph = DEFAULT_ROS,
    user_services: Sequence[UserServiceGrant] = (),
    localization: LocalizationMode = DEFAULT_LOCALIZATION,
    **where: Unpack[Deployment],
) -> Profile:
    """Write a fresh profile for robot ``keys.robot`` into ``directory`` (created 0700; every file
    0600), placed as ``where`` says (:class:`Deployment`). ``ros`` is the ROS domain and the
    bridge's namespace the ROS roles are granted; each of ``user_services`` gets a user and a
    client file of its own (``<name>.json5``), granted :func:`user_service_grants`. ValueError for
    a bad endpoint. ``localization`` is the robot's ``localization.mode``: the localization is granted
    what that mode reads and serves (only the stub reads a ground truth)."""
    credentials = fresh_credentials()
    followed = [user.name for user in user_services]
    rules = access_control({role: c.user for role, c in credentials.items()}, keys, ros, localization, followed)
    users: dict[str, Credentials] = {user.name: Credentials(user.name, _fresh_password()) for user in user_services}
    for user in user_services:
        _add_subject(rules, user.name, users[user.name].user, user_service_grants(user, keys))
    return _write_files(
        directory, {Identity(role): login for role, login in credentials.items()}, rules, users=users, **where
    )


def _add_subject(rules: dict[str, Any], name: str, user: str, granted: Sequence[Any]) -> None:
    """Add subject ``name`` (usrpwd ``user``) with ``granted`` to a router's ``access_control``."""
    section = access_control_section([(name, user, list(granted))])
    for part in ("rules", "subjects", "policies"):
        rules[part].extend(section[part])


def write_fleet_profile(
    directory: Path,
    robots: Iterable[str],
    *,
    ros: BridgeGraph = DEFAULT_ROS,
    bridges: Mapping[str, BridgeGraph] | None = None,
    user_services: Mapping[str, Sequence[UserServiceGrant]] | None = None,
    localization: Mapping[str, LocalizationMode] | None = None,
    **where: Unpack[Deployment],
) -> Profile:
    """Write a fresh profile for the fleet of ``robots`` (several robots in one world) into
    ``directory``, as :func:`write_profile` does for one robot (same arguments, same files).

    The users (:func:`fleet_identities`, :attr:`Identity.user`) are the fleet-wide roles
    (``sim``, ``ros_node``, ``operator``, ``observer``) and, for each robot, ``<robot>-<role>`` for
    each of :data:`PER_ROBOT_ROLES` (``rh1-motor``); each has its client file ``<user>.json5``
    beside ``router.json5`` (:meth:`Profile.client_config`). Robot ``r``'s ROS 2 bridge is granted
    ``bridges[r]``, by default :func:`robot_bridge` of ``ros`` (namespace ``/<r>``; ``/clock`` for the
    first robot's only); ``ros_node`` the domains of them all. Each of ``user_services[r]`` gets the
    user ``<r>-<name>``, granted :func:`user_service_grants` on robot ``r``. Robot ``r``'s
    localization is granted for ``localization[r]``, its ``localization.mode`` (default the stub's).
    ValueError for a bad fleet (:func:`fleet_robots`) or endpoint.
    """
    fleet = fleet_robots(robots)
    graphs = {
        robot: (bridges or {}).get(robot) or robot_bridge(ros, robot, publishes_clock=index == 0)
        for index, robot in enumerate(fleet)
    }
    credentials = {identity: Credentials(identity.user, _fresh_password()) for identity in fleet_identities(fleet)}
    followed = {robot: [user.name for user in granted] for robot, granted in (user_services or {}).items()}
    logins = {identity: c.user for identity, c in credentials.items()}
    rules = fleet_access_control(logins, fleet, graphs, localization, followed)
    users: dict[str, Credentials] = {}
    for robot, granted in (user_services or {}).items():
        for user in granted:
            login = users[f"{robot}-{user.name}"] = Credentials(f"{robot}-{user.name}", _fresh_password())
            _add_subject(rules, login.user, login.user, user_service_grants(user, Keys(robot)))
    return _write_files(directory, credentials, rules, robots=fleet, users=users, **where)


def _write_files(
    directory: Path,
    credentials: Mapping[Identity, Credentials],
    rules: dict[str, Any],
    *,
    endpoint: str,
    router_listen: Sequence[str] = (),
    tls: bool = False,
    tls_names: Iterable[str] = (),
    seen_as: Path | None = None,
    router_base: dict[str, Any] | None = None,
    robots: tuple[str, ...] = (),
    users: Mapping[str, Credentials] | None = None,
) -> Profile:
    """The files of every profile: one user and one client file per identity of ``credentials``,
    the router's configuration with ``rules``, its ``access_control``."""
    directory.mkdir(parents=True, exist_ok=True)
    directory.chmod(0o700)
    seen = (seen_as or directory).absolute()
    endpoint = _with_scheme(endpoint, tls)
    listen = [_with_scheme(address, tls) for address in router_listen] or [endpoint]
    users = users or {}
    logins = [*credentials.values(), *users.values()]
    _write_private(directory / DICTIONARY, "".join(f"{c.user}:{c.password}\n" for c in logins))
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
        _write_tls(directory / TLS_DIRECTORY, (*TLS_NAMES, *tls_names))
        tls_dir = seen / TLS_DIRECTORY
        router["transport"]["link"] = {
            "tls": {
                "listen_certificate": str(tls_dir / ROUTER_CERTIFICATE),
                "listen_private_key": str(tls_dir / ROUTER_KEY),
            }
        }
        client_tls = {"link": {"tls": {"root_ca_certificate": str(tls_dir / CA_CERTIFICATE)}}}
    _write_private(directory / ROUTER_CONFIG, _json5(router, "the router of an invent secure deployment"))
    profile = Profile(directory, endpoint, tuple(listen), tls, robots=robots, user_services=tuple(users))
    clients: list[tuple[Path, Credentials, str, bool]] = [
        (
            profile.client_config(identity.role, identity.robot),
            login,
            f"role {identity.role}" + (f" of robot {identity.robot}" if identity.robot is not None else ""),
            # zenoh-ext advanced publishers with a cache (ROS's transient-local topics) need timestamps.
            identity.role in (Role.ROS2, Role.ROS_NODE),
        )
        for identity, login in credentials.items()
    ]
    clients += [
        (profile.user_service_config(name), login, f"user service {name}", False) for name, login in users.items()
    ]
    for path, login, what, timestamped in clients:
        client = {
            "mode": "client",
            "connect": {"endpoints": [endpoint], "timeout_ms": CLIENT_CONNECT_TIMEOUT_MS},
            "listen": {"endpoints": []},
            "scouting": {"multicast": {"enabled": False}},
            "transport": {"auth": {"usrpwd": {"user": login.user, "password": login.password}}, **client_tls},
        }
        if timestamped:
            client["timestamping"] = {"enabled": True}
        _write_private(path, _json5(client, f"{what} of an invent secure deployment"))
    return profile


def _with_scheme(endpoint: str, tls: bool) -> str:
    """``endpoint`` (``tcp/HOST:PORT`` or ``tls/HOST:PORT``) with the profile's scheme; ValueError
    for anything else."""
    scheme, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    if scheme not in ("tcp", "tls") or not host or not port.isdigit():
        raise ValueError(f"endpoint {endpoint!r}: expected tcp/HOST:PORT or tls/HOST:PORT")
    return f"{'tls' if tls else scheme}/{address}"


def _write_tls(directory: Path, names: Sequence[str]) -> None:
    """The TLS files (:func:`~services.security.tls.certificates`) into ``directory`` (created 0700)."""
    directory.mkdir(parents=True, exist_ok=True)
    directory.chmod(0o700)
    for name, text in certificates(names).items():
        _write_private(directory / name, text)


def _json5(config: dict[str, Any], what: str) -> str:
    return f"// zenoh configuration: {what}. Generated; holds secrets.\n{json.dumps(config, indent=2)}\n"


def _write_private(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` readable by its owner only, from the moment it exists."""
    path.unlink(missing_ok=True)
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(descriptor, "w") as file:
        file.write(text)
