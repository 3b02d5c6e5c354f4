"""The bridge's TF tree (pure, no zenoh): the newest transform of each frame from its parent, as the
bridge computes them (services/ros2/outputs.py keeps every one, whether ``ros2.enable_*_tf``
publishes it or not), and a pose given in one frame expressed in another through their common
ancestor, in 3D as tf2 does it. A NavigateToPose goal may so be given in any frame the tree holds
(``map``, ``odom``, ``base_link``: a goal relative to the robot, a wheel, a sensor's frame) and is
sent to the drive in ``map`` (services/ros2/navigate.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np


class TransformError(Exception):
    """A frame the tree cannot transform: unknown, or not connected to the target (Nav2's TF_ERROR)."""


def _multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def unit_quaternion(rotation: Iterable[float]) -> np.ndarray:
    """``rotation`` (x, y, z, w) of any length scaled to length 1: divided by its largest component
    first, so that squares of components as large as 1e300 cannot overflow (nor those of 1e-300
    vanish). ValueError naming it for one not finite or zero (no rotation)."""
    quaternion = np.array(list(rotation), dtype=float)
    if not np.all(np.isfinite(quaternion)):
        raise ValueError(f"orientation {tuple(quaternion.tolist())} is not finite")
    largest = float(np.max(np.abs(quaternion)))
    if largest == 0.0:
        raise ValueError("orientation (0, 0, 0, 0) is no rotation")
    scaled = quaternion / largest
    return scaled / math.sqrt(float(scaled @ scaled))


@dataclass(frozen=True)
class Rigid:
    """A rigid transform ``parent_T_child``: ``translation`` (m) and unit ``rotation`` (x, y, z, w)."""

    translation: np.ndarray
    rotation: np.ndarray

    @staticmethod
    def identity() -> Rigid:
        return Rigid(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))

    @staticmethod
    def of(translation: Iterable[float], rotation: Iterable[float]) -> Rigid:
        """From a translation and any finite non-zero quaternion (:func:`unit_quaternion`)."""
        return Rigid(np.array(list(translation), dtype=float), unit_quaternion(rotation))

    def rotate(self, vector: np.ndarray) -> np.ndarray:
        u, w = self.rotation[:3], self.rotation[3]
        return vector + 2.0 * w * np.cross(u, vector) + 2.0 * np.cross(u, np.cross(u, vector))

    def compose(self, child: Rigid) -> Rigid:
        """``self * child``: ``a_T_b * b_T_c = a_T_c``."""
        return Rigid(self.translation + self.rotate(child.translation), _multiply(self.rotation, child.rotation))

    def inverse(self) -> Rigid:
        conjugate = self.rotation * np.array([-1.0, -1.0, -1.0, 1.0])
        inverted = Rigid(np.zeros(3), conjugate)
        return Rigid(-inverted.rotate(self.translation), conjugate)

    @property
    def yaw(self) -> float:
        """The heading of the rotation's x axis projected on the xy plane."""
        x, y, z, w = self.rotation
        return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


class TfTree:
    """The newest ``parent -> child`` transform of each child frame (a frame has one parent, as in tf2)."""

    def __init__(self) -> None:
        self._parents: dict[str, tuple[str, Rigid]] = {}

    @property
    def frames(self) -> set[str]:
        return {*self._parents, *(parent for parent, _ in self._parents.values())}

    def set(self, parent: str, child: str, transform: Rigid) -> None:
        self._parents[child] = (parent, transform)

    def update(self, transforms: Iterable[Any]) -> None:
        """Take ``geometry_msgs/TransformStamped`` messages (the bridge's own: finite, unit rotations)."""
        for stamped in transforms:
            moved = stamped.transform
            t, r = moved.translation, moved.rotation
            self.set(stamped.header.frame_id, stamped.child_frame_id, Rigid.of((t.x, t.y, t.z), (r.x, r.y, r.z, r.w)))

    def forget(self, child: str) -> None:
        self._parents.pop(child, None)

    def _from_root(self, frame: str) -> tuple[list[str], Rigid]:
        """The frame's ancestors from itself up to its root, and ``root_T_frame``."""
        chain, transform = [frame], Rigid.identity()
        while chain[-1] in self._parents and len(chain) <= len(self._parents):
            parent, step = self._parents[chain[-1]]
            transform = step.compose(transform)
            chain.append(parent)
        return chain, transform

    def lookup(self, target: str, source: str) -> Rigid:
        """``target_T_source``; TransformError naming why for a frame unknown or not connected to ``target``."""
        if source == target:
            return Rigid.identity()
        if source not in self.frames:
            raise TransformError(f"frame {source!r} is not in the bridge's TF tree")
        source_chain, root_T_source = self._from_root(source)
        target_chain, root_T_target = self._from_root(target)
        if source_chain[-1] != target_chain[-1]:
            raise TransformError(
                f"frame {source!r} is not connected to {target!r} (the tree has no {target_chain[-1]!r} -> "
                f"{source_chain[-1]!r} yet)"
            )
        return root_T_target.inverse().compose(root_T_source)
