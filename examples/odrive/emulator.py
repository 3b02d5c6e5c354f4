"""An emulated ODrive on a pseudo-terminal: its ASCII protocol (firmware 0.5's, as
``Firmware/communication/ascii_protocol.cpp`` reads) driving two motors that turn the wheels of a
differential-drive robot, whose motion is the project's pure drive model
(:mod:`sim_bridge.kinematic_model`). It stands in for the hardware in the driver's test and for a
user trying the driver without a board; it is not the hardware (see README.md).

    python -m examples.odrive.emulator --link /tmp/odrive0 --report /tmp/odrive0.json

prints ``{"port": "/dev/pts/N"}`` once it serves, and writes its report (the robot's true pose,
ground truth the driver never sees, and the axes' states) at exit and on SIGUSR1.

What a driver meets here as on a board: positions in turns of the motor's encoder (quantised to
its counts per revolution, from an arbitrary start), a gearbox between motor and wheel, one motor
mounted mirrored, torques in N·m of the motor, limited by ``current_lim`` times
``torque_constant`` and, in torque mode, cut near ``vel_limit`` (2 turns/s by default); velocity
control (``v``: the firmware's PI loop on the encoder's speed, ``vel_gain`` and
``vel_integrator_gain``, the setpoint clamped to ``vel_limit``, run at each substep); an axis
that takes torque only in closed-loop control (``requested_state`` 8); the ODrive's own watchdog;
checksums; and the firmware's answers to what it does not know (``unknown command``,
``invalid property``, ...). What it leaves out: calibration, motor and encoder errors, the
rotor's inertia and the gearbox's backlash and losses, friction (an idle wheel rolls on), the
current loop (a torque applies at once), the encoder's velocity filter, the input filters, and
position control (``p``, ``q``, ``t`` answer ``not implemented``, as a board would not).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import signal
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from services.config import load_config
from services.config.loading import parse_override
from sim_bridge.kinematic_model import DiffDrivePlant, DriveModel

MAX_LINE_LENGTH = 255
"""The firmware's command buffer (``MAX_LINE_LENGTH``): a longer line is dropped to its end."""
RESPONSE_BYTES = 64
"""The firmware's reply buffer: a longer reply is cut."""
PROPERTY_CHARS = 9
"""``r`` prints a value into a 10-byte buffer: at most 9 characters of it."""
IDLE, CLOSED_LOOP = 1, 8
TORQUE_CONTROL, VELOCITY_CONTROL = 1, 2
"""``controller.config.control_mode`` values (``c`` sets the first, ``v`` the second)."""
WATCHDOG_TIMER_EXPIRED = 0x800
"""``axis.error`` bit of firmware 0.5."""
FEEDS_WATCHDOG = "pqvctu"


@dataclass
class Axis:
    """One axis's properties the emulator knows (name below ``axisN.``: value), with 0.5's defaults."""

    values: dict[str, float] = field(
        default_factory=lambda: {
            "requested_state": 0,
            "current_state": IDLE,
            "error": 0,
            "controller.input_torque": 0.0,
            "controller.input_vel": 0.0,
            "controller.vel_integrator_torque": 0.0,
            "controller.config.control_mode": 3,
            "controller.config.vel_limit": 2.0,
            "controller.config.vel_gain": 1.0 / 6.0,
            "controller.config.vel_integrator_gain": 1.0 / 3.0,
            "controller.config.enable_torque_mode_vel_limit": 1,
            "motor.config.torque_constant": 0.04,
            "motor.config.current_lim": 10.0,
            "encoder.config.cpr": 8192,
            "encoder.pos_estimate": 0.0,
            "encoder.vel_estimate": 0.0,
            "config.enable_watchdog": 0,
            "config.watchdog_timeout": 0.0,
        }
    )
    integers: ClassVar[frozenset[str]] = frozenset(
        {
            "requested_state",
            "current_state",
            "error",
            "controller.config.control_mode",
            "controller.config.enable_torque_mode_vel_limit",
            "encoder.config.cpr",
            "config.enable_watchdog",
        }
    )
    read_only: ClassVar[frozenset[str]] = frozenset({"current_state", "encoder.pos_estimate", "encoder.vel_estimate"})
    fed_at: float = 0.0

    def motor_torque(self, velocity_turns: float, dt: float) -> float:
        """N·m the motor gives now, as the firmware's controller computes it (``Controller::update``)
        in torque mode, or in velocity mode over a control period of ``dt`` s."""
        v = self.values
        if v["current_state"] != CLOSED_LOOP:
            return 0.0
        limit = v["motor.config.current_lim"] * v["motor.config.torque_constant"]
        if v["controller.config.control_mode"] == VELOCITY_CONTROL:
            return self._velocity_control(velocity_turns, dt, limit)
        torque = min(max(v["controller.input_torque"], -limit), limit)
        if v["controller.config.enable_torque_mode_vel_limit"]:
            vel_limit, gain = v["controller.config.vel_limit"], v["controller.config.vel_gain"]
            torque = min(max(torque, (-vel_limit - velocity_turns) * gain), (vel_limit - velocity_turns) * gain)
        return min(max(torque, -limit), limit)

    def _velocity_control(self, velocity_turns: float, dt: float, limit: float) -> float:
        """The PI loop: the integrator grows while the torque is within the limit, decays while not."""
        v = self.values
        vel_limit = v["controller.config.vel_limit"]
        error = min(max(v["controller.input_vel"], -vel_limit), vel_limit) - velocity_turns
        torque = v["controller.input_torque"] + v["controller.config.vel_gain"] * error
        torque += v["controller.vel_integrator_torque"]
        limited = abs(torque) > limit
        if limited:
            v["controller.vel_integrator_torque"] *= 0.99
        else:
            v["controller.vel_integrator_torque"] += v["controller.config.vel_integrator_gain"] * dt * error
        return min(max(torque, -limit), limit)


@dataclass(frozen=True)
class Mechanics:
    """How the two axes turn the wheels: which axis is the left wheel's, which motor is mounted
    mirrored, the gear ratio (motor turns per wheel turn) and where each encoder starts (turns)."""

    left_axis: int = 0
    mirrored: tuple[bool, bool] = (False, True)
    gear_ratio: float = 10.0
    offsets: tuple[float, float] = (0.25, -3.5)


class Device:
    """The ODrive, pure: bytes in and out and the time given (s since its start), the robot's drive
    stepped in fixed substeps up to that time as the firmware's control loop runs at a fixed rate."""

    def __init__(self, plant: DiffDrivePlant, mechanics: Mechanics, substep: float = 0.001) -> None:
        self.plant, self.mechanics, self.substep = plant, mechanics, substep
        self.axes = (Axis(), Axis())
        self.time = 0.0
        self._buffer = bytearray()
        self._active = True
        self.counters = dict.fromkeys(
            ("lines", "unknown_commands", "bad_checksums", "watchdog_expiries", "dropped_replies"), 0
        )

    # --- the motors and the robot ---

    def _wheel_of(self, axis: int) -> int:
        return 0 if axis == self.mechanics.left_axis else 1

    def _sign(self, axis: int) -> float:
        return -1.0 if self.mechanics.mirrored[axis] else 1.0

    def motor_turns(self, axis: int) -> tuple[float, float]:
        """(position, velocity) of the motor in turns, turns/s: the wheel's through the gearbox."""
        wheel, ratio = self._wheel_of(axis), self.mechanics.gear_ratio * self._sign(axis)
        angle, rate = self.plant.wheel_angles[wheel], self.plant.wheel_velocities[wheel]
        return self.mechanics.offsets[axis] + angle * ratio / (2 * math.pi), rate * ratio / (2 * math.pi)

    def advance(self, now: float) -> None:
        while self.time + self.substep <= now:
            torques = [0.0, 0.0]
            for number, axis in enumerate(self.axes):
                v = axis.values
                expired = self.time - axis.fed_at > v["config.watchdog_timeout"]
                if v["config.enable_watchdog"] and v["current_state"] == CLOSED_LOOP and expired:
                    v["current_state"], v["error"] = IDLE, int(v["error"]) | WATCHDOG_TIMER_EXPIRED
                    self.counters["watchdog_expiries"] += 1
                velocity = self.motor_turns(number)[1]
                motor_torque = axis.motor_torque(velocity, self.substep)
                wheel_torque = motor_torque * self.mechanics.gear_ratio * self._sign(number)
                torques[self._wheel_of(number)] = wheel_torque
            self.plant.step(torques[0], torques[1], self.substep)
            self.time += self.substep

    # --- the protocol ---

    def receive(self, data: bytes, now: float) -> bytes:
        """Bytes from the host at ``now``; the replies, as the firmware frames lines."""
        self.advance(now)
        out = bytearray()
        for byte in data:
            if byte in b"\r\n!":
                if self._active:
                    out += self.process_line(bytes(self._buffer), now)
                self._buffer.clear()
                self._active = True
            else:
                self._buffer.append(byte)
                if len(self._buffer) > MAX_LINE_LENGTH:
                    self._buffer.clear()
                    self._active = False  # the rest of an overlong line is not a command
        return bytes(out)

    def process_line(self, line: bytes, now: float) -> bytes:
        self.counters["lines"] += 1
        line = line.split(b";", 1)[0]
        star = line.find(b"*")
        use_checksum = star >= 0
        if use_checksum:
            expected = 0
            for byte in line[:star]:
                expected ^= byte
            given = line[star + 1 :].strip()
            if not given.isdigit() or int(given) != expected:
                self.counters["bad_checksums"] += 1
                return b""  # a line whose checksum is wrong is ignored
            line = line[:star]
        text = line[:MAX_LINE_LENGTH].decode("latin-1")
        return b"".join(self._respond(reply, use_checksum) for reply in self.command(text, now))

    @staticmethod
    def _respond(text: str, use_checksum: bool) -> bytes:
        body = text.encode("latin-1")[: RESPONSE_BYTES - 1]
        if use_checksum:
            value = 0
            for byte in body:
                value ^= byte
            body += b"*%d" % value
        return body[: RESPONSE_BYTES - 3] + b"\r\n"

    def command(self, text: str, now: float) -> list[str]:
        """The replies to one command line (its checksum and comment gone)."""
        letter, fields = text[:1], text.split()
        if letter and letter in FEEDS_WATCHDOG + "f":
            return self._axis_command(letter, fields, now)
        if letter in ("r", "w"):
            return self._property(letter, fields)
        if letter == "s":
            if text[1:2] == "c":
                for axis in self.axes:
                    axis.values["error"] = 0
            elif text[1:2] == "r":
                self.axes = (Axis(), Axis())
            return []
        if letter == "i":
            return ["Hardware version: 3.6-56V", "Firmware version: 0.5.6", "Serial number: EMULATED"]
        if letter == "h":
            return ["Please see documentation for more details", "", "Torque: c axis T", "Read: r property"]
        self.counters["unknown_commands"] += 1
        return ["unknown command"]  # the empty line too, as 0.5's switch reads

    def _axis_command(self, letter: str, fields: list[str], now: float) -> list[str]:
        needed = 3 if letter in "cv" else 2
        try:
            number = int(fields[1])
            setpoint = float(fields[2]) if letter in "cv" else 0.0
            feed_forward = float(fields[3]) if letter == "v" and len(fields) > 3 else 0.0
        except (IndexError, ValueError):
            return ["invalid command format"]
        if len(fields) < needed or number < 0 or not (math.isfinite(setpoint) and math.isfinite(feed_forward)):
            return ["invalid command format"]
        if number >= len(self.axes):
            return [f"invalid motor {number}"]
        axis = self.axes[number]
        if letter == "f":
            position, velocity = self.motor_turns(number)
            counts = axis.values["encoder.config.cpr"]
            return [f"{math.floor(position * counts) / counts:f} {velocity:f}"]
        if letter == "c":
            axis.values["controller.input_torque"] = setpoint
            axis.values["controller.config.control_mode"] = TORQUE_CONTROL
        elif letter == "v":
            axis.values["controller.input_vel"], axis.values["controller.input_torque"] = setpoint, feed_forward
            axis.values["controller.config.control_mode"] = VELOCITY_CONTROL
        elif letter != "u":
            return ["not implemented"]  # position control: not emulated
        axis.fed_at = now
        return []

    def _property(self, letter: str, fields: list[str]) -> list[str]:
        if len(fields) < 2:
            return ["invalid command format"]
        name = fields[1]
        if name == "vbus_voltage":
            return ["24.000000"] if letter == "r" else ["not implemented"]
        prefix, _, rest = name.partition(".")
        number = {"axis0": 0, "axis1": 1}.get(prefix)
        if number is None or rest not in self.axes[number].values:
            return ["invalid property"]
        axis = self.axes[number]
        if rest in ("encoder.pos_estimate", "encoder.vel_estimate"):
            position, velocity = self.motor_turns(number)
            axis.values["encoder.pos_estimate"], axis.values["encoder.vel_estimate"] = position, velocity
        if letter == "r":
            value = axis.values[rest]
            return [(f"{int(value)}" if rest in axis.integers else f"{value:f}")[:PROPERTY_CHARS]]
        try:
            value = float(fields[2])
            if rest in axis.integers:
                value = int(fields[2])
        except (IndexError, ValueError):
            return ["not implemented"]
        if rest in axis.read_only or not math.isfinite(value):
            return ["not implemented"]
        axis.values[rest] = value
        if rest == "requested_state":
            # taken at once and consumed, as the firmware's state machine does; calibration is assumed done
            accepted = value == CLOSED_LOOP and axis.values["error"] == 0
            axis.values["current_state"] = CLOSED_LOOP if accepted else IDLE
            axis.values["requested_state"] = 0
            axis.fed_at = self.time
        return []

    def report(self) -> dict[str, Any]:
        plant = self.plant
        axes = [
            {key: axis.values[key] for key in ("current_state", "error", "controller.input_torque")}
            for axis in self.axes
        ]
        return {"time_s": self.time, "x": plant.x, "y": plant.y, "theta": plant.theta, "axes": axes, **self.counters}


def serve(device: Device, master: int, stop: list[bool], report: Path | None, time_scale: float) -> None:
    """The pty's loop: wall time (times ``time_scale``) is the device's clock, as hardware's is."""
    start = time.monotonic()
    while not stop[0]:
        readable = select.select([master], [], [], 0.01)[0]
        now = (time.monotonic() - start) * time_scale
        if readable:
            replies = device.receive(os.read(master, 4096), now)
            try:
                written = os.write(master, replies)
            except BlockingIOError:
                written = 0
            if written < len(replies):  # nobody reads the port: replies lost, as a board's would be
                device.counters["dropped_replies"] += 1
        else:
            device.advance(now)
        if stop[1] and report is not None:
            stop[1] = False
            report.write_text(json.dumps(device.report()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m examples.odrive.emulator", description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", help="robot description TOML (the robot's geometry and masses)")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--gear-ratio", type=float, default=Mechanics.gear_ratio)
    parser.add_argument("--left-axis", type=int, choices=(0, 1), default=Mechanics.left_axis)
    parser.add_argument("--mirrored-axis", type=int, choices=(0, 1), default=1, help="the motor mounted mirrored")
    parser.add_argument("--time-scale", type=float, default=1.0, help="device seconds per wall second (1: real time)")
    parser.add_argument("--link", help="a symlink to the pty, e.g. /tmp/odrive0")
    parser.add_argument("--report", type=Path, help="where the true pose goes (at exit and on SIGUSR1)")
    args = parser.parse_args(argv)
    config = load_config(args.config, dict(parse_override(text) for text in args.set))
    mirrored = (args.mirrored_axis == 0, args.mirrored_axis == 1)
    mechanics = Mechanics(args.left_axis, mirrored, args.gear_ratio)
    device = Device(DiffDrivePlant(DriveModel.from_description(config.robot, config.sim)), mechanics)
    master, slave = os.openpty()
    os.set_blocking(master, False)
    tty.setraw(slave)  # the pty's own line discipline would echo and translate, as no ODrive does
    port = os.ttyname(slave)
    if args.link:
        Path(args.link).unlink(missing_ok=True)
        Path(args.link).symlink_to(port)
    stop = [False, False]  # [stop, report now]

    def on_signal(signum: int, _frame: object) -> None:
        stop[signum == signal.SIGUSR1] = True

    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1):
        signal.signal(signum, on_signal)
    print(json.dumps({"port": port}), flush=True)
    try:
        serve(device, master, stop, args.report, args.time_scale)
    finally:
        if args.report is not None:
            args.report.write_text(json.dumps(device.report()))
        if args.link:
            Path(args.link).unlink(missing_ok=True)
        os.close(master)
        os.close(slave)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
