"""The secure profile: zenoh's usrpwd authentication and access control, by role, TLS optional.

``invent secrets DIR`` and ``invent up --secure`` write one profile: fresh credentials for every
:class:`Role` (stdlib ``secrets``), the router's configuration (its user dictionary and
``access_control``, default deny) and one complete zenoh client configuration per role, so any
zenoh program opens a session as that role with ``zenoh.Config.from_file``. Every session of a
secure deployment is a **client**: zenoh applies access control on the router's transports only,
and peers talking directly would bypass it.

What each role may do is :func:`grants`: a service's role exactly what its service declares
(:mod:`services.interfaces`: the keys it puts, subscribes, serves and queries), the tools' roles
(operator, observer, a ROS node) reading every key. Every put, subscription and query that no grant
names is denied, and a session without valid credentials is refused at connection.

A **fleet** (several robots in one world, :func:`write_fleet_profile`) has one user per robot for
each of :data:`PER_ROBOT_ROLES` (``rh1-motor``: the motor of ``rh1``, granted exactly what the
motor role is granted on ``rh1`` and nothing on any other robot) and one user for the whole fleet
for each of :data:`FLEET_ROLES` (``sim``: one simulator steps every robot; ``operator``,
``observer``, ``ros_node``), granted what that role may on every robot of the fleet. The
``control`` role (``invent control``: the sim and the motor composed on one session, granted both
their rights) is one robot's only (:data:`SINGLE_ROBOT_ROLES`): a fleet has none.

Its rooms: :mod:`~services.security.roles` (who), :mod:`~services.security.grants` (what each may
do: the access-control rules), :mod:`~services.security.profile` (the files) and
:mod:`~services.security.tls` (the certificates). The names below are what the rest of the project
imports, from ``services.security``.
"""

from services.security.grants import (
    DEFAULT_ROS,
    Flow,
    Message,
    UserServiceGrant,
    fleet_grants,
    grants,
    robot_bridge,
    user_service_grants,
)
from services.security.profile import (
    DICTIONARY,
    ROUTER_CONFIG,
    Profile,
    write_fleet_profile,
    write_profile,
)
from services.security.roles import (
    FLEET_ROLES,
    PER_ROBOT_ROLES,
    SINGLE_ROBOT_ROLES,
    Identity,
    Role,
    fleet_identities,
    fleet_robots,
)
from services.security.tls import (
    CA_CERTIFICATE,
    TLS_DIRECTORY,
)

__all__ = [
    "CA_CERTIFICATE",
    "DEFAULT_ROS",
    "DICTIONARY",
    "FLEET_ROLES",
    "PER_ROBOT_ROLES",
    "ROUTER_CONFIG",
    "SINGLE_ROBOT_ROLES",
    "TLS_DIRECTORY",
    "Flow",
    "Identity",
    "Message",
    "Profile",
    "Role",
    "UserServiceGrant",
    "fleet_grants",
    "fleet_identities",
    "fleet_robots",
    "grants",
    "robot_bridge",
    "user_service_grants",
    "write_fleet_profile",
    "write_profile",
]
