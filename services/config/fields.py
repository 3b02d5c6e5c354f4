"""What the sections of the robot description are built of: bounds, units, the base section, ``"none"``.

A field's unit is part of its type (``Annotated[Positive, METRES]``), so that the parameter
reference (docs/configuration.md, :mod:`services.config.reference`) reads it from the type and no
docstring has to repeat it. msgspec keeps a unit as ``extra`` metadata and ignores it when it
converts, so a unit changes neither what is accepted nor what an error says.
"""

from __future__ import annotations

import functools
import math
from typing import Annotated

import msgspec

Positive = Annotated[float, msgspec.Meta(gt=0.0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0)]
WheelId = Annotated[int, msgspec.Meta(ge=0)]


def unit(symbol: str) -> msgspec.Meta:
    """A field's unit, for the parameter reference: ``Annotated[float, unit("m")]``."""
    return msgspec.Meta(extra={"unit": symbol})


METRES = unit("m")
RADIANS = unit("rad")
KILOGRAMS = unit("kg")
NEWTON_METRES = unit("N·m")
METRES_PER_SECOND = unit("m/s")
METRES_PER_SECOND_SQUARED = unit("m/s²")
METRES_PER_SECOND_CUBED = unit("m/s³")
RADIANS_PER_SECOND = unit("rad/s")
RADIANS_PER_SECOND_SQUARED = unit("rad/s²")
RADIANS_PER_SECOND_CUBED = unit("rad/s³")
P_GAIN = unit("N·m/rad")
"""A proportional gain: the torque per radian of wheel-angle error."""
D_GAIN = unit("N·m·s/rad")
"""A derivative gain: the torque per rad/s of wheel-speed error."""
SIMULATED_SECONDS = unit("s (simulated)")
"""Seconds of simulation time: the stamps' time, which runs faster or slower than the wall clock."""
PER_SIMULATED_SECOND = unit("1/s (simulated)")
"""A rate: so many per second of simulation time."""
WALL_SECONDS = unit("s (wall clock)")
STEPS = unit("physics steps")
MEGABYTES = unit("MB (10⁶ bytes)")


NONE = "none"
"""How a file or ``--set`` turns off an optional parameter (a motor limit, the localization's seed,
the sim's world): TOML has no null, so ``max_vx = "none"`` or ``--set motor.max_vx=none`` is None."""


class Section(msgspec.Struct, frozen=True, forbid_unknown_fields=True, kw_only=True):
    """A table of the robot description: strict (an unknown key is an error), and no float of it
    is infinite or NaN."""

    def __post_init__(self) -> None:
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if isinstance(value, float) and not math.isfinite(value):
                hint = f' (write "{NONE}" to turn it off)' if name in optional_fields(type(self)) else ""
                raise ValueError(f"`{name}` must be finite, got {value}{hint}")


def require_finite_fields(table: msgspec.Struct, prefix: str = "") -> None:
    """ValueError naming the first field of ``table`` that holds an infinite or NaN float (alone or
    in a tuple), as ```<prefix><field>` must be finite, got <value>``: TOML reads ``nan`` and
    ``inf``, and msgspec takes them for a float."""
    for name in table.__struct_fields__:
        value = getattr(table, name)
        values = value if isinstance(value, tuple) else (value,)
        if any(isinstance(item, float) and not math.isfinite(item) for item in values):
            raise ValueError(f"`{prefix}{name}` must be finite, got {value}")


@functools.cache
def optional_fields(section: type[msgspec.Struct]) -> frozenset[str]:
    """The fields of ``section`` that may be None (written :data:`NONE` in a file or ``--set``)."""
    return frozenset(
        field.name
        for field in msgspec.inspect.type_info(section).fields  # type: ignore[attr-defined]
        if isinstance(field.type, msgspec.inspect.UnionType)
        and any(isinstance(member, msgspec.inspect.NoneType) for member in field.type.types)
    )
