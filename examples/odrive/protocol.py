"""ODrive's ASCII protocol, the host's side, pure (no I/O, no zenoh): the lines a driver sends, the
replies it parses, and how an axis's turns and N·m map to the robot's wheels.

The protocol (ODrive firmware 0.5, docs.odriverobotics.com "ASCII protocol"): one command per
line, ``command *checksum ; comment``, a line ending at ``\\r``, ``\\n`` or ``!``. The checksum is
the XOR of every byte before the ``*``, in decimal; given one, the device checks it (a line whose
checksum is wrong is ignored: no reply at all) and puts one on its replies (``text*N\\r\\n``).
``f <axis>`` answers ``<pos> <vel>`` in turns and turns/s of the motor's encoder; ``c <axis> <Nm>``
sets the motor's torque setpoint (torque control) and ``v <axis> <turns/s> <Nm>`` its velocity
setpoint and feed-forward torque (velocity control: the firmware's own loop), both answering nothing; ``r <property>`` answers the value,
``w <property> <value>`` nothing when it worked. Errors are text: ``unknown command``,
``invalid motor 2``, ``invalid command format``, ``invalid property``, ``not implemented``.

A driver here always sends checksums: a byte corrupted on a noisy UART then makes the device
ignore the line (the driver sees a missing reply, counted) instead of, say, taking ``c 0 9.5`` for
``c 0 0.5``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MAX_LINE_BYTES = 256
"""The firmware's line buffer: a longer line is dropped up to its end (the reply parser keeps the
same bound, so a device that never ends a line cannot grow the host's buffer)."""
AXIS_STATE_IDLE = 1
AXIS_STATE_CLOSED_LOOP_CONTROL = 8
"""``axisN.requested_state`` / ``current_state`` values (ODrive's ``AxisState``)."""
AXIS_ERROR_WATCHDOG_TIMER_EXPIRED = 0x800
"""``axisN.error``'s bit when the ODrive's own watchdog idled the axis (firmware 0.5)."""
ERROR_REPLIES = ("unknown command", "invalid command format", "invalid property", "not implemented", "invalid motor")
"""What the device answers instead of a value (the start of the line)."""


class BadReply(ValueError):
    """A reply line the host cannot use: garbled, a wrong checksum, an error text, not numbers."""


def checksum(text: bytes) -> int:
    """The XOR of every byte, as the protocol checks a line (``r vbus_voltage`` -> 93)."""
    value = 0
    for byte in text:
        value ^= byte
    return value


def line(command: str) -> bytes:
    """``command`` as one line with its checksum, ended by ``\\n`` alone (the firmware ends a line at
    ``\\r`` too, and 0.5's answers ``unknown command`` to the empty line between a ``\\r\\n``)."""
    body = command.encode("ascii")
    return body + b"*%d\n" % checksum(body)


def feedback_request(axis: int) -> bytes:
    return line(f"f {axis}")


def torque_command(axis: int, newton_metres: float) -> bytes:
    """The motor's torque setpoint; non-finite values are refused here, before they reach a wire."""
    if not math.isfinite(newton_metres):
        raise ValueError(f"torque {newton_metres} is not finite")
    return line(f"c {axis} {newton_metres:.6f}")


def velocity_command(axis: int, turns_per_second: float) -> bytes:
    """The motor's velocity setpoint (no feed-forward torque); non-finite values are refused here."""
    if not math.isfinite(turns_per_second):
        raise ValueError(f"velocity {turns_per_second} is not finite")
    return line(f"v {axis} {turns_per_second:.6f} 0")


def read_property(name: str) -> bytes:
    return line(f"r {name}")


def write_property(name: str, value: float) -> bytes:
    return line(f"w {name} {value}")


def reply_text(raw: bytes) -> str:
    """The text of one reply line (its ``\\r``/``\\n`` already split off), its checksum verified and
    removed. Raises BadReply for bytes that are not ASCII, a missing or wrong checksum."""
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise BadReply(f"not ASCII: {raw[:40]!r}") from None
    body, star, given = text.rpartition("*")
    if not star:
        raise BadReply(f"no checksum: {text[:40]!r}")
    if not given.isdigit() or int(given) != checksum(body.encode("ascii")):
        raise BadReply(f"wrong checksum: {text[:40]!r}")
    if body.startswith(ERROR_REPLIES):
        raise BadReply(f"the device answered {body!r}")
    return body


def parse_feedback(raw: bytes) -> tuple[float, float]:
    """``f``'s reply: (position in turns, velocity in turns/s), both finite."""
    fields = reply_text(raw).split()
    if len(fields) != 2:
        raise BadReply(f"feedback is two numbers, not {fields[:4]!r}")
    try:
        position, velocity = float(fields[0]), float(fields[1])
    except ValueError:
        raise BadReply(f"feedback is two numbers, not {fields!r}") from None
    if not (math.isfinite(position) and math.isfinite(velocity)):
        raise BadReply(f"feedback not finite: {fields!r}")
    return position, velocity


def parse_number(raw: bytes) -> float:
    """``r``'s reply for a number (an int property reads as one too)."""
    text = reply_text(raw).strip()
    try:
        value = float(text)
    except ValueError:
        raise BadReply(f"not a number: {text[:40]!r}") from None
    if not math.isfinite(value):
        raise BadReply(f"not finite: {text!r}")
    return value


class LineSplitter:
    """Bytes from the port in, whole lines out (``\\r``, ``\\n`` and ``!`` end a line; empty lines
    are dropped). A line longer than :data:`MAX_LINE_BYTES` is dropped to its end and counted: the
    buffer never holds more than that."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._dropping = False
        self.overlong = 0

    def feed(self, data: bytes) -> list[bytes]:
        lines: list[bytes] = []
        for byte in data:
            if byte in b"\r\n!":
                if self._buffer and not self._dropping:
                    lines.append(bytes(self._buffer))
                self._buffer.clear()
                self._dropping = False
            elif not self._dropping:
                self._buffer.append(byte)
                if len(self._buffer) > MAX_LINE_BYTES:
                    self._buffer.clear()
                    self._dropping = True
                    self.overlong += 1
        return lines

    def clear(self) -> None:
        self._buffer.clear()
        self._dropping = False


@dataclass(frozen=True)
class Wheel:
    """One wheel as its ODrive axis sees it. ``sign`` is -1 for a motor mounted mirrored (on a
    differential drive one of the two usually is: the same turn of both motors spins the robot),
    ``gear_ratio`` the motor's turns per wheel turn (1 for a hub motor): the encoder is on the
    motor, so the wheel turns ``1/gear_ratio`` as much, and gets ``gear_ratio`` times the torque
    (an ideal gearbox: no losses, no backlash)."""

    axis: int
    sign: int = 1
    gear_ratio: float = 1.0

    def __post_init__(self) -> None:
        if self.axis not in (0, 1):
            raise ValueError(f"axis must be 0 or 1, not {self.axis}")
        if self.sign not in (-1, 1):
            raise ValueError(f"sign must be 1 or -1, not {self.sign}")
        if not (math.isfinite(self.gear_ratio) and self.gear_ratio > 0.0):
            raise ValueError(f"gear_ratio must be > 0, not {self.gear_ratio}")

    def wheel_angle(self, motor_turns: float) -> float:
        """rad of the wheel, positive forward, from the motor's encoder turns."""
        return self.sign * 2.0 * math.pi * motor_turns / self.gear_ratio

    def motor_torque(self, wheel_newton_metres: float) -> float:
        """N·m the motor must give for the wheel's torque (positive forward)."""
        return self.sign * wheel_newton_metres / self.gear_ratio

    def motor_velocity(self, wheel_radians_per_second: float) -> float:
        """turns/s of the motor for the wheel's speed in rad/s (positive forward)."""
        return self.sign * wheel_radians_per_second * self.gear_ratio / (2.0 * math.pi)
