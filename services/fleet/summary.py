"""What a fleet run's report says of the robots together: how close they came, and who bumped whom. Pure."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from typing import Any

Track = Sequence[tuple[float, float, float]]
"""(simulation time in s, x, y) of a robot's ground truth, in time order."""


def closest_approach(tracks: Mapping[str, Track]) -> dict[str, Any] | None:
    """The smallest distance between two robots' axle centres at the same simulation time, with
    when and which two; None with fewer than two robots (or no common stamps)."""
    positions = {name: {t: (x, y) for t, x, y in track} for name, track in tracks.items()}
    closest: dict[str, Any] | None = None
    for first, second in itertools.combinations(sorted(positions), 2):
        here, there = positions[first], positions[second]
        for t in here.keys() & there.keys():
            distance = math.dist(here[t], there[t])
            if closest is None or distance < closest["distance_m"]:
                closest = {"distance_m": distance, "t_s": t, "robots": [first, second]}
    return closest


def bumps_between(bumps: Mapping[str, Sequence[tuple[float, str]]], robots: Sequence[str]) -> list[dict[str, Any]]:
    """The bumps of one robot into another (``bumps``: each robot's (t, what it touched)), in time order."""
    between = [
        {"t_s": t, "robot": name, "other": obstacle}
        for name, events in bumps.items()
        for t, obstacle in events
        if obstacle in robots
    ]
    return sorted(between, key=lambda bump: (bump["t_s"], bump["robot"]))
