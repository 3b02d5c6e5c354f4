"""How far the world's run is, as every robot link of the sim bridge reads it. Pure: the bridge's
loop writes it, the links and the torque policy read it."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(slots=True)
class RunProgress:
    published_ns: int = -1
    """The stamp of the latest step published: no torque can answer a later one."""
    started: bool = False
    """The first step is under way: a participant that comes now did not wait from the start."""

    def present(self) -> int | None:
        """The stamp of the latest step published; None before the first."""
        return self.published_ns if self.published_ns >= 0 else None
