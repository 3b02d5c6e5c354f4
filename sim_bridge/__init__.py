"""The PyBullet simulator bridge (docs/protocol.md section 6): ``invent sim``.

- :mod:`sim_bridge.world`: world files (ground, obstacles, the robot's initial pose).
- :mod:`sim_bridge.robot`: the diff-drive robot model built from the robot description.
- :mod:`sim_bridge.simulator`: the zenoh-free stepping core (torques in, wheel angles, body
  pose and bump contacts out).
- :mod:`sim_bridge.bridge`: the service, lockstep and realtime modes over zenoh.
"""
