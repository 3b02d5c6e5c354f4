"""``invent odometry``: the seed's OdometryRTC (docs/odometry.md, docs/protocol.md section 5).

- :mod:`~services.odometry.core`: the integration and its fix history (pure, no zenoh);
- :mod:`~services.odometry.service`: the service around it.
"""
