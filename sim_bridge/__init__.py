"""The simulator bridge (docs/protocol.md section 6): ``invent sim``, on PyBullet or the kinematic engine.

The core (no zenoh):

- :mod:`sim_bridge.world`: world files (ground, obstacles, the robot's initial pose).
- :mod:`sim_bridge.robot`: the diff-drive robot model built from the robot's body
  (:mod:`services.body.geometry`).
- :mod:`sim_bridge.engine`: what the bridge needs of an engine (``sim.engine``), as protocols.
- :mod:`sim_bridge.simulator`: the stepping core on PyBullet (torques in, wheel angles, body pose and
  bump contacts out).
- :mod:`sim_bridge.kinematic`: the same without physics (:mod:`sim_bridge.kinematic_model`: the
  drive; :mod:`sim_bridge.kinematic_world`: shapes, contacts and rays by geometry).
- :mod:`sim_bridge.torque_policy`: which torque a step applies when torques come late, not at all,
  or too old.
- :mod:`sim_bridge.latency`, :mod:`sim_bridge.progress`, :mod:`sim_bridge.status`: the torque
  latency, how far the run is, what the status and the summary say.

The service (the shell, over zenoh):

- :mod:`sim_bridge.bridge`: ``SimService`` and its flags, lockstep and realtime modes.
- :mod:`sim_bridge.link`: one robot's keys, publishers, inputs and status; :mod:`sim_bridge.liveness`:
  who is there for it.
- :mod:`sim_bridge.loops`: the lockstep and realtime loops; :mod:`sim_bridge.handshakes`: before
  the first step.
"""
