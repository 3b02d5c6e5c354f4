"""invent-zenoh services, one room each (docs/architecture.md):

- ``motor/``, ``odometry/``, ``localization/``, ``drive/``: each service, its shell beside its pure core(s);
- ``clock/``: simulation time, lockstep and the simulator watch every service shares;
- ``runtime/``: the runtime every service stands on (session, inputs, executor, node);
- ``recording/``: recording, reports, replay and the live view;
- ``cli/``: the ``invent`` command, the launcher (``up``, composition) and the zenoh tools;
- ``config/``: the robot description (its sections, loading, the parameter reference);
- ``security/``: the secure profile (roles, access control, credentials, TLS);
- ``errors.py`` (the project's exceptions), ``service.py`` (what a service command is),
  ``planar.py`` (planar geometry).

The simulator bridge is the top-level package ``sim_bridge``.
"""
