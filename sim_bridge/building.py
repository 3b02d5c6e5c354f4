"""The world's bodies in a physics client: the floor and the obstacles of a world file (where each
robot stands is a :class:`~sim_bridge.engine.Placement`). Both the simulator's world and the
lidars' ray world (:mod:`sim_bridge.ray_world`) are built with these."""

from __future__ import annotations

import pybullet as p

from sim_bridge.world import World


def build_ground(client: int) -> int:
    """The floor: an infinite plane at z = 0."""
    shape = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=client)
    return int(p.createMultiBody(0.0, shape, physicsClientId=client))


def build_obstacles(client: int, world: World) -> tuple[tuple[int, str], ...]:
    """Each obstacle of ``world`` standing on the floor: its body id and its name, boxes first."""
    built = []
    for box in world.boxes:
        half = tuple(length / 2.0 for length in box.size)
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
        body = p.createMultiBody(
            box.mass,
            shape,
            basePosition=(box.x, box.y, half[2]),
            baseOrientation=p.getQuaternionFromEuler((0.0, 0.0, box.yaw)),
            physicsClientId=client,
        )
        built.append((body, box.name))
    for cylinder in world.cylinders:
        shape = p.createCollisionShape(
            p.GEOM_CYLINDER, radius=cylinder.radius, height=cylinder.height, physicsClientId=client
        )
        body = p.createMultiBody(
            cylinder.mass,
            shape,
            basePosition=(cylinder.x, cylinder.y, cylinder.height / 2.0),
            physicsClientId=client,
        )
        built.append((body, cylinder.name))
    return tuple(built)
