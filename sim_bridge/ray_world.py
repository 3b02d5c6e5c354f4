"""The lidars' ray world: a second physics client, never stepped, holding a copy of the simulated
world (the floor, the obstacles, every robot's body), in which a robot's lidar casts its rays.

Why a second world: PyBullet tests a ray against every body whose bounding box the ray crosses, and
a ray that starts beside the robot's own body crosses that body's box: the test against its
cylinder costs ~2.5 µs a ray, ~1 ms for a scan of 360 rays. Neither a collision filter mask
(PyBullet applies it after that test) nor lifting the robot out of the simulated world for the cast
(which changes the physics: measured) helps. In a world that is never stepped, poses can be set at
will: the casting robot's copy is moved out of the way and every other robot's (and any obstacle
that moves) set to its simulated pose, so the rays see exactly the simulated shapes where they are.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy.typing as npt
import pybullet as p

from services.config import SimConfig
from sim_bridge.building import build_ground, build_obstacles
from sim_bridge.engine import Placement
from sim_bridge.robot import build_robot
from sim_bridge.sensors import RayHit
from sim_bridge.world import World

_AWAY = (0.0, 0.0, -1000.0)
"""Where the casting robot's copy waits while its own rays are cast: far below the floor."""
_UPRIGHT = (0.0, 0.0, 0.0, 1.0)


class RayWorld:
    """The copy of ``source``'s world: the robots of ``placements`` (simulated as ``robot_bodies``)
    and ``world``'s obstacles (simulated as ``obstacle_bodies``, in the world's order)."""

    def __init__(
        self,
        source: int,
        world: World,
        sim: SimConfig,
        placements: Sequence[Placement],
        robot_bodies: Sequence[int],
        obstacle_bodies: Sequence[int],
    ) -> None:
        self.source = source
        self.client = p.connect(p.DIRECT)
        client = self.client
        build_ground(client)
        copies = build_obstacles(client, world)
        self.names = dict(copies)
        """Every body a ray may hit, by its id in this world: obstacles and robots by name."""
        masses = [box.mass for box in world.boxes] + [cylinder.mass for cylinder in world.cylinders]
        self._moving = [
            (simulated, copy)
            for simulated, (copy, _), mass in zip(obstacle_bodies, copies, masses, strict=True)
            if mass > 0.0
        ]
        """(simulated body, copy) of each obstacle that can move."""
        self._robots: list[tuple[int, int]] = []
        for placement, simulated in zip(placements, robot_bodies, strict=True):
            copy = build_robot(client, placement.robot, sim, placement.pose).body
            self.names[copy] = placement.name
            self._robots.append((simulated, copy))

    def cast(self, caster: int, starts: npt.ArrayLike, ends: npt.ArrayLike) -> list[RayHit]:
        """Cast the rays of robot ``caster`` (its index in the placements) in the world as it is
        simulated now, without that robot."""
        client = self.client
        for index, (simulated, copy) in enumerate(self._robots):
            if index == caster:
                p.resetBasePositionAndOrientation(copy, _AWAY, _UPRIGHT, physicsClientId=client)
            else:
                self._follow(simulated, copy)
        for simulated, copy in self._moving:
            self._follow(simulated, copy)
        hits: list[RayHit] = p.rayTestBatch(starts, ends, numThreads=1, physicsClientId=client)
        return hits

    def _follow(self, simulated: int, copy: int) -> None:
        position, orientation = p.getBasePositionAndOrientation(simulated, physicsClientId=self.source)
        p.resetBasePositionAndOrientation(copy, position, orientation, physicsClientId=self.client)

    def close(self) -> None:
        p.disconnect(physicsClientId=self.client)
