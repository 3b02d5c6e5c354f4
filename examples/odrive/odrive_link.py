"""The driver's serial side, no zenoh: a serial port opened raw (:class:`SerialPort`, plain ``os`` and
``termios``: Linux, a USB CDC device such as ``/dev/ttyACM0``, a UART, or the emulator's
pseudo-terminal) and the two axes of an ODrive on it (:class:`ODrive`): their feedback as wheel
angles, torques or wheel speeds to them (torque or velocity control), arming and disarming.

Every exchange is bounded in time: a reply that does not come within ``reply_timeout`` raises
:class:`LinkError`, and so does a reply that does not parse. The driver counts those and goes on;
the port itself failing (unplugged) is an ``OSError``.
"""

from __future__ import annotations

import math
import os
import select
import termios
import time
from dataclasses import dataclass

from examples.odrive.protocol import (
    AXIS_STATE_CLOSED_LOOP_CONTROL,
    AXIS_STATE_IDLE,
    BadReply,
    LineSplitter,
    Wheel,
    feedback_request,
    line,
    parse_feedback,
    parse_number,
    read_property,
    torque_command,
    velocity_command,
    write_property,
)

BAUD_RATES = {9600: termios.B9600, 57600: termios.B57600, 115200: termios.B115200, 921600: termios.B921600}


ARM_TIMEOUT_S = 1.0
"""How long an axis may take to enter closed-loop control (a board does it in milliseconds once
calibrated; an uncalibrated one never does, and needs ``odrivetool`` first: README.md)."""


class LinkError(Exception):
    """An exchange that failed: no reply in time, or one that does not parse."""


class SerialPort:
    """A serial device opened raw: 8N1, no echo, no line editing, no CR/LF translation, no flow
    control. The baud rate matters on a UART only (a USB CDC device and a pty ignore it)."""

    def __init__(self, path: str, baud: int = 115200) -> None:
        if baud not in BAUD_RATES:
            raise ValueError(f"baud {baud}: one of {sorted(BAUD_RATES)}")
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        attributes = termios.tcgetattr(self.fd)
        attributes[0] = 0  # iflag: no CR/LF translation, no XON/XOFF
        attributes[1] = 0  # oflag: bytes out as written
        attributes[2] = termios.CS8 | termios.CREAD | termios.CLOCAL
        attributes[3] = 0  # lflag: raw, no echo
        attributes[4] = attributes[5] = BAUD_RATES[baud]
        termios.tcsetattr(self.fd, termios.TCSANOW, attributes)
        termios.tcflush(self.fd, termios.TCIOFLUSH)
        self.splitter = LineSplitter()
        self._lines: list[bytes] = []

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self.fd, view) :]
            except BlockingIOError:
                select.select([], [self.fd], [], 0.01)

    def read_lines(self, count: int, timeout: float) -> list[bytes]:
        """The next ``count`` lines, or fewer if ``timeout`` seconds pass first."""
        deadline = time.monotonic() + timeout
        while len(self._lines) < count:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0 or not select.select([self.fd], [], [], remaining)[0]:
                break
            self._read_available()
        taken, self._lines = self._lines[:count], self._lines[count:]
        return taken

    def discard_input(self) -> int:
        """Drop whatever arrived unasked (a late reply, noise); returns the lines dropped."""
        while select.select([self.fd], [], [], 0)[0]:
            if not self._read_available():
                break
        dropped = len(self._lines)
        self._lines.clear()
        self.splitter.clear()
        return dropped

    def _read_available(self) -> bool:
        try:
            data = os.read(self.fd, 4096)
        except BlockingIOError:
            return False
        if not data:
            raise OSError("the serial port closed")
        self._lines.extend(self.splitter.feed(data))
        return True

    def close(self) -> None:
        os.close(self.fd)


@dataclass(frozen=True)
class Axes:
    """Which axis drives which wheel, and how (:class:`~examples.odrive.protocol.Wheel`)."""

    left: Wheel
    right: Wheel

    def __post_init__(self) -> None:
        if self.left.axis == self.right.axis:
            raise ValueError(f"left and right on the same axis {self.left.axis}")


class ODrive:
    """An ODrive's two axes over a :class:`SerialPort`, in wheel units: rad, rad/s and N·m at the
    wheel. ``velocity``: the axes run the firmware's velocity control (``v``), not torque control
    (``c``): zero, arming and disarming say so in that mode."""

    def __init__(
        self, port: SerialPort, axes: Axes, reply_timeout: float, max_motor_torque: float, velocity: bool = False
    ) -> None:
        self.port, self.axes = port, axes
        self.reply_timeout = reply_timeout
        self.max_motor_torque = max_motor_torque
        self.velocity = velocity
        self.vel_limit = math.inf
        """turns/s of the motor, each velocity command clamped (what :meth:`arm` wrote)."""
        self.stray_lines = 0
        """Lines that came unasked (dropped before an exchange)."""

    def _ask(self, requests: bytes, count: int) -> list[bytes]:
        self.stray_lines += self.port.discard_input()
        self.port.write(requests)
        replies = self.port.read_lines(count, self.reply_timeout)
        if len(replies) < count:
            raise LinkError(
                f"{count - len(replies)} of {count} replies missing after {self.reply_timeout * 1e3:.0f} ms"
            )
        return replies

    def wheel_angles(self) -> tuple[float, float]:
        """(left, right) wheel angles in rad, positive forward: both axes asked at once (one round
        trip, not two)."""
        left, right = self.axes.left, self.axes.right
        replies = self._ask(feedback_request(left.axis) + feedback_request(right.axis), 2)
        try:
            (left_turns, _), (right_turns, _) = parse_feedback(replies[0]), parse_feedback(replies[1])
        except BadReply as error:
            raise LinkError(str(error)) from None
        return left.wheel_angle(left_turns), right.wheel_angle(right_turns)

    def set_torques(self, left_newton_metres: float, right_newton_metres: float) -> None:
        """Wheel torques (N·m, positive forward) as motor torques, clamped to ``max_motor_torque``;
        ``c`` answers nothing, and feeds the ODrive's own watchdog."""
        limit = self.max_motor_torque
        commands = b""
        for wheel, torque in ((self.axes.left, left_newton_metres), (self.axes.right, right_newton_metres)):
            commands += torque_command(wheel.axis, max(-limit, min(limit, wheel.motor_torque(torque))))
        self.port.write(commands)

    def set_wheel_velocities(self, left_radians_per_second: float, right_radians_per_second: float) -> None:
        """Wheel speeds (rad/s, positive forward) as the motors' velocity setpoints, clamped to the
        ``vel_limit`` written at :meth:`arm`; ``v`` answers nothing, and feeds the ODrive's own watchdog."""
        limit = self.vel_limit
        commands = b""
        for wheel, speed in ((self.axes.left, left_radians_per_second), (self.axes.right, right_radians_per_second)):
            commands += velocity_command(wheel.axis, max(-limit, min(limit, wheel.motor_velocity(speed))))
        self.port.write(commands)

    def zero(self, axis: int) -> bytes:
        """The line that zeroes an axis in its mode: zero torque, or zero speed (the wheel held)."""
        return velocity_command(axis, 0.0) if self.velocity else torque_command(axis, 0.0)

    def read(self, name: str) -> float:
        (reply,) = self._ask(read_property(name), 1)
        try:
            return parse_number(reply)
        except BadReply as error:
            raise LinkError(f"r {name}: {error}") from None

    def write_checked(self, name: str, value: float) -> None:
        """``w``, then ``r`` to see it took: a write answers only when it fails, and a line the
        device ignored (a bad checksum) answers nothing either."""
        self.port.write(write_property(name, value))
        if not math_close(self.read(name), value):
            raise LinkError(f"w {name} {value}: it reads back otherwise")

    def arm(self, vel_limit: float, watchdog_timeout: float | None) -> None:
        """Set what the driver relies on, then closed-loop control on both axes (torque or velocity
        control comes with the first ``c`` or ``v``). Raises LinkError naming what did not take."""
        self.vel_limit = vel_limit
        for wheel in (self.axes.left, self.axes.right):
            axis = f"axis{wheel.axis}"
            # In torque mode the firmware cuts the torque as the motor nears vel_limit (2 turns/s by
            # default: a geared wheel reaches it at a walking pace).
            self.write_checked(f"{axis}.controller.config.vel_limit", vel_limit)
            if watchdog_timeout is not None:
                # The ODrive's own watchdog: if this process dies, the axis goes idle by itself.
                self.write_checked(f"{axis}.config.watchdog_timeout", watchdog_timeout)
                self.write_checked(f"{axis}.config.enable_watchdog", 1)
            self.port.write(self.zero(wheel.axis))
            self.port.write(write_property(f"{axis}.requested_state", AXIS_STATE_CLOSED_LOOP_CONTROL))
        deadline = time.monotonic() + ARM_TIMEOUT_S
        while (states := self.states()) != (AXIS_STATE_CLOSED_LOOP_CONTROL,) * 2:
            if time.monotonic() > deadline:
                raise LinkError(f"the axes did not enter closed-loop control: current_state {states}")
            time.sleep(0.01)

    def states(self) -> tuple[int, int]:
        """(left, right) axes' ``current_state``."""
        left, right = self.axes.left.axis, self.axes.right.axis
        return int(self.read(f"axis{left}.current_state")), int(self.read(f"axis{right}.current_state"))

    def errors(self) -> tuple[int, int]:
        """(left, right) axes' ``error`` bits."""
        left, right = self.axes.left.axis, self.axes.right.axis
        return int(self.read(f"axis{left}.error")), int(self.read(f"axis{right}.error"))

    def rearm(self) -> None:
        """After the ODrive's own watchdog idled the axes (this process was late feeding it): clear
        the errors (``sc``), zero torque (or speed), closed-loop control again. The next poll says if it took."""
        self.port.write(line("sc"))
        for wheel in (self.axes.left, self.axes.right):
            self.port.write(self.zero(wheel.axis))
            self.port.write(write_property(f"axis{wheel.axis}.requested_state", AXIS_STATE_CLOSED_LOOP_CONTROL))

    def disarm(self) -> None:
        """Zero torque (or speed), then both axes idle (the motors unpowered: the wheels roll freely)."""
        for wheel in (self.axes.left, self.axes.right):
            self.port.write(self.zero(wheel.axis))
            self.port.write(write_property(f"axis{wheel.axis}.requested_state", AXIS_STATE_IDLE))


def math_close(a: float, b: float) -> bool:
    """A property read back as the firmware prints it (``%f``: six decimals)."""
    return abs(a - b) <= 1e-6 * max(1.0, abs(b))
