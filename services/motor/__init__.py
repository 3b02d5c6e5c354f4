"""``invent motor``: MotorControl (docs/motor.md, docs/protocol.md section 4).

- :mod:`~services.motor.core`: the PD law, the states, the command limits (pure, no zenoh);
- :mod:`~services.motor.state`: the state file that keeps a stop latched across restarts;
- :mod:`~services.motor.service`: the service around them.
"""
