"""A driver that makes a differential-drive base on an ODrive a plant of the loop: it serves what
the simulator serves (docs/plant.md), so ``invent motor``, ``invent odometry`` and ``invent drive``
run against the real wheels unchanged. A template to adapt (README.md); it has not met the hardware.

    python -m examples.odrive.driver --port /dev/ttyACM0 --connect tcp/127.0.0.1:7447 \\
        --set sim.step=0.01 --set sim.observe_every=2 --set sim.torque_max_age=0.02

It always runs in realtime (``sim.mode`` is the simulator's setting; a real base cannot hold its
time). Every ``sim.step`` of wall time (divided by ``sim.realtime_factor``) a cycle reads both axes'
positions (``f 0``, ``f 1``), publishes them as ``sim/wheel_angles`` stamped with the cycle's
time (k·step: a real base's clock is its cycle count), and at the observed steps ``sim/clock``
once the cycle's torque is in; each ``motor/torque`` goes to the axes at once (``c 0``, ``c 1``).
With ``--set motor.output=velocity`` (the motor's setting, read from the same description) it
takes ``motor/wheel_velocity`` instead and the axes run the ODrive's own velocity control: each
target goes to them at once (``v 0``, ``v 1``); a target not finite or beyond
``input.max_wheel_speed`` is bad input, never sent.
It holds ``sim/alive`` and answers ``sim/status``. Not served: ``sim/body_pose`` (nobody knows
the true pose of a real base), ``sim/bump`` (an ODrive has no bumper), ``sim/world``, the sensors.

The zenoh shell is :class:`Driver`; the serial side is examples/odrive/odrive_link.py, the
protocol examples/odrive/protocol.py.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from functools import partial
from typing import Any

import zenoh

from examples.odrive.odrive_link import Axes, LinkError, ODrive, SerialPort
from examples.odrive.protocol import AXIS_ERROR_WATCHDOG_TIMER_EXPIRED, AXIS_STATE_CLOSED_LOOP_CONTROL, Wheel
from schemas.codec import BadInput
from schemas.keys import Keys, Service
from schemas.messages import NANOSECONDS_PER_SECOND, Time, TimedDoubleSeq
from schemas.status import ServiceStatus
from schemas.tokens import parse_observes_key, parse_ticks_key
from services.clock.lockstep import encode_mark
from services.clock.observation import ObservedSteps
from services.config import Config, ConfigError, load_config
from services.config.loading import parse_override
from services.runtime.executor import STOP_POLL_S
from services.runtime.inputs import Delivery
from services.runtime.logs import RateLimitedLog, configure_logging
from services.runtime.node import Node
from services.runtime.session import open_session, session_config, stop_on_signals

MAX_LAG_S = 0.1
"""A loop this far behind its schedule starts it again from now (as the realtime sim), rather
than run the cycles it missed back to back."""
START_REPLY_TIMEOUT_S = 0.5
"""What a reply may take before the loop runs (a board just plugged in answers slower)."""
STATE_POLL_S = 0.25
"""How often the axes' ``current_state`` is read: an axis that left closed-loop control takes no
torque, and the robot rolls on meanwhile (4 polls a second cost 4 short exchanges)."""
COUNTERS = (
    "steps",
    "serial_errors",
    "late_cycles",
    "resyncs",
    "torques_written",
    "wheel_velocities_written",
    "late_torques",
    "stale_torques",
    "watchdog_zero_steps",
    "axis_faults",
    "rearms",
)


class ODrivePlantStatus(ServiceStatus, kw_only=True, tag_field="plant", tag="odrive"):
    """This plant's ``sim/status``: its own, not the simulator's (``plant`` ``odrive`` says so)."""

    state: str
    output: str
    time_s: float
    rate_hz: float
    counters: dict[str, int]
    stray_lines: int
    overlong_lines: int
    axis_states: tuple[int, int] | None
    observed_rates: dict[str, float]


class Driver:
    """The plant's side of the contract on zenoh, over an :class:`ODrive` (the serial side)."""

    def __init__(self, node: Node, config: Config, odrive: ODrive) -> None:
        self.node, self.odrive = node, odrive
        sim, robot = config.sim, config.robot
        self.step_ns = round(sim.step * NANOSECONDS_PER_SECOND)
        self.period_s = sim.step / sim.realtime_factor
        self.max_age_ns = round(sim.torque_max_age * NANOSECONDS_PER_SECOND)
        self.ids = robot.left_wheel_id, robot.right_wheel_id
        self.width = max(self.ids) + 1
        self.velocity = config.motor.output == "velocity"
        self.max_wheel_speed = config.input.max_wheel_speed
        self.observation = ObservedSteps(sim.observe_every)
        self.marks = (encode_mark(None, observed=False), encode_mark(None, observed=True))
        self.counters = dict.fromkeys(COUNTERS, 0)
        self.published_ns = -1
        self.newest_ns: int | None = None
        self.clock: tuple[TimedDoubleSeq, bytes] | None = None
        self.states: tuple[int, int] | None = None
        self._warn = RateLimitedLog(node.log)
        keys = node.keys
        self._angles = node.publisher(keys.sim_wheel_angles)
        self._clock = node.publisher(keys.sim_clock)
        if self.velocity:
            node.subscribe(keys.motor_wheel_velocity, TimedDoubleSeq, self._on_wheel_velocity, Delivery.QUEUED)
        else:
            node.subscribe(keys.motor_torque, TimedDoubleSeq, self._on_torque, Delivery.QUEUED)
        # Who takes ticks (the drive's clock at each of its ticks) or observes: their steps are observed.
        liveliness = node.session.liveliness()
        self._watches = [
            liveliness.declare_subscriber(key, partial(self._on_token, parse), history=True)
            for key, parse in ((keys.every_ticks, parse_ticks_key), (keys.every_observes, parse_observes_key))
        ]
        node.set_status(self.status)

    def _on_token(self, parse: Any, sample: zenoh.Sample) -> None:
        # a zenoh callback: hand over to the service thread, never act here
        key, put = str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT
        parsed = parse(key)
        if parsed is not None:
            self.node.post(partial(self._token_changed, key, parsed[1], put))

    def _token_changed(self, key: str, rate_hz: float, put: bool) -> None:
        if put:
            self.observation.add(key, rate_hz, self.published_ns if self.published_ns >= 0 else None)
        else:
            self.observation.remove(key)

    def _on_torque(self, torque: TimedDoubleSeq) -> None:
        if len(torque.data) != self.width:
            raise BadInput(f"{len(torque.data)} torques, expected {self.width} (one per wheel id)")
        if self._fresh(torque):
            # at once, not at the next cycle: the ODrive holds a torque until told otherwise
            self.odrive.set_torques(torque.data[self.ids[0]], torque.data[self.ids[1]])
            self.counters["torques_written"] += 1
            self._answered(torque)

    def _on_wheel_velocity(self, targets: TimedDoubleSeq) -> None:
        if len(targets.data) != self.width:
            raise BadInput(f"{len(targets.data)} wheel speed targets, expected {self.width} (one per wheel id)")
        if not all(abs(target) <= self.max_wheel_speed for target in targets.data):
            raise BadInput(f"wheel speed targets {targets.data} beyond input.max_wheel_speed = {self.max_wheel_speed}")
        if self._fresh(targets):
            self.odrive.set_wheel_velocities(targets.data[self.ids[0]], targets.data[self.ids[1]])
            self.counters["wheel_velocities_written"] += 1
            self._answered(targets)

    def _fresh(self, answer: TimedDoubleSeq) -> bool:
        """Whether a torque (or target) is to be sent: not from the future (bad input), not older
        than the one sent nor than ``sim.torque_max_age`` (stale, counted)."""
        tm_ns = answer.tm.to_nanoseconds()
        if tm_ns > self.published_ns:
            raise BadInput(
                f"answer stamped {tm_ns} ns, after the latest step ({self.published_ns} ns): from the future"
            )
        if (self.newest_ns is not None and tm_ns <= self.newest_ns) or self.published_ns - tm_ns > self.max_age_ns:
            self.counters["stale_torques"] += 1  # older than the one applied, or too old to apply
            return False
        return True

    def _answered(self, answer: TimedDoubleSeq) -> None:
        tm_ns = answer.tm.to_nanoseconds()
        self.newest_ns = tm_ns
        if tm_ns == self.published_ns:
            self._publish_clock()

    def _publish_clock(self) -> None:
        pending, self.clock = self.clock, None
        if pending is not None:
            self._clock.put(*pending)

    def _read_and_publish(self, step_index: int) -> None:
        """The cycle's wheel angles, stamped with its time; a failed exchange publishes nothing (the
        motor then sees a longer step)."""
        tm_ns = step_index * self.step_ns
        try:
            left, right = self.odrive.wheel_angles()
        except LinkError as error:
            self.counters["serial_errors"] += 1
            self._warn("serial", logging.WARNING, "step %d: %s; no wheel angles this step", step_index, error)
            return
        data = [0.0] * self.width
        data[self.ids[0]], data[self.ids[1]] = left, right
        observed = self.observation.observed(step_index, tm_ns)
        angles = TimedDoubleSeq(Time.from_nanoseconds(tm_ns), data)
        self.published_ns = tm_ns
        self._angles.put(angles, self.marks[observed])
        self.counters["steps"] += 1
        if observed:
            self.clock = (angles, self.marks[observed])

    def _end_of_cycle(self, step_index: int) -> None:
        """The clock if the torque never came, and the driver's own watchdog: no torque stamped
        within ``sim.torque_max_age`` of this step means zero torque (the motor control gone or cut off)."""
        tm_ns = step_index * self.step_ns
        self._publish_clock()
        if self.newest_ns != tm_ns:
            self.counters["late_torques"] += 1
        if self.newest_ns is None or tm_ns - self.newest_ns > self.max_age_ns:
            # every cycle: it also feeds the ODrive's own watchdog (in velocity control: zero speed, held)
            if self.velocity:
                self.odrive.set_wheel_velocities(0.0, 0.0)
            else:
                self.odrive.set_torques(0.0, 0.0)
            self.counters["watchdog_zero_steps"] += 1

    def _poll_states(self) -> None:
        try:
            self.states = self.odrive.states()
        except LinkError as error:
            self.counters["serial_errors"] += 1
            self._warn("serial", logging.WARNING, "reading the axes' state: %s", error)
            return
        if all(state == AXIS_STATE_CLOSED_LOOP_CONTROL for state in self.states):
            return
        self.counters["axis_faults"] += 1
        try:
            errors = self.odrive.errors()
        except LinkError as error:
            self.counters["serial_errors"] += 1
            self._warn("serial", logging.WARNING, "reading the axes' errors: %s", error)
            return
        if all(error & ~AXIS_ERROR_WATCHDOG_TIMER_EXPIRED == 0 for error in errors):
            # Only the ODrive's own watchdog: this process was late feeding it (a stall). It is
            # back, so control again; any other error needs a person (README.md).
            self.odrive.rearm()
            self.counters["rearms"] += 1
            self._warn("rearm", logging.WARNING, "the ODrive's watchdog idled the axes %s: re-armed", self.states)
        else:
            self._warn("axes", logging.ERROR, "axes idle, errors %s: not re-armed", [hex(e) for e in errors])

    def run(self, stop: threading.Event) -> None:
        node, period = self.node, self.period_s
        origin, origin_step, step_index = time.monotonic(), 0, 0
        next_poll = origin + STATE_POLL_S
        while not stop.is_set():
            lag = time.monotonic() - (origin + (step_index - origin_step) * period)
            if lag > MAX_LAG_S:
                self.counters["resyncs"] += 1
                origin, origin_step = time.monotonic(), step_index
            elif lag > period:
                self.counters["late_cycles"] += 1
            self._read_and_publish(step_index)
            deadline = origin + (step_index + 1 - origin_step) * period
            while (remaining := deadline - time.monotonic()) > 0.0:
                node.spin_once(min(remaining, STOP_POLL_S))
            self._end_of_cycle(step_index)
            if time.monotonic() >= next_poll:
                next_poll = time.monotonic() + STATE_POLL_S
                self._poll_states()
            step_index += 1

    def status(self) -> ODrivePlantStatus:
        return ODrivePlantStatus(
            state="running",
            output="velocity" if self.velocity else "torque",
            time_s=max(self.published_ns, 0) / NANOSECONDS_PER_SECOND,
            rate_hz=NANOSECONDS_PER_SECOND / self.step_ns,
            counters=dict(self.counters),
            stray_lines=self.odrive.stray_lines,
            overlong_lines=self.odrive.port.splitter.overlong,
            axis_states=self.states,
            observed_rates=self.observation.rates(),
        )

    def close(self) -> None:
        for watch in self._watches:
            watch.undeclare()


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m examples.odrive.driver", description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", required=True, help="the ODrive's serial device, e.g. /dev/ttyACM0")
    parser.add_argument("--baud", type=int, default=115200, help="UART only (USB ignores it)")
    parser.add_argument("--connect", action="append", default=[], metavar="EP", help="zenoh endpoint")
    parser.add_argument("--robot", help="robot name (robot.name)")
    parser.add_argument("--config", help="robot description TOML, the one the services read")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--left-axis", type=int, default=0, help="the left wheel's axis (the right's is the other)")
    parser.add_argument("--left-sign", type=int, default=1, help="-1: the left motor is mounted mirrored")
    parser.add_argument("--right-sign", type=int, default=-1, help="-1: the right motor is mounted mirrored")
    parser.add_argument("--gear-ratio", type=float, default=10.0, help="motor turns per wheel turn")
    parser.add_argument("--max-motor-torque", type=float, default=0.4, help="N·m at the motor, each command clamped")
    parser.add_argument("--vel-limit", type=float, default=20.0, help="turns/s of the motor, written at start")
    parser.add_argument("--watchdog-timeout", type=float, default=0.2, help="s, the ODrive's own; 0: off")
    parser.add_argument("--reply-timeout", type=float, default=0.02, help="s an answer may take")
    parser.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))
    return parser.parse_args(argv)


def settings(args: argparse.Namespace) -> tuple[Config, Axes]:
    """The robot description and the axes, or ConfigError naming what is wrong (exit 2)."""
    overrides = dict(parse_override(text) for text in args.set)
    if args.robot:
        overrides["robot.name"] = args.robot
    config = load_config(args.config, overrides)
    if config.sim.torque_max_age < config.sim.step:
        raise ConfigError(
            f"sim.torque_max_age = {config.sim.torque_max_age} s: at least sim.step ({config.sim.step} s)"
        )
    for flag in ("gear_ratio", "max_motor_torque", "vel_limit", "reply_timeout"):
        if not getattr(args, flag) > 0.0:
            raise ConfigError(f"--{flag.replace('_', '-')} must be > 0, not {getattr(args, flag)}")
    if args.watchdog_timeout < 0.0:
        raise ConfigError(f"--watchdog-timeout must be >= 0, not {args.watchdog_timeout}")
    try:
        axes = Axes(
            Wheel(args.left_axis, args.left_sign, args.gear_ratio),
            Wheel(1 - args.left_axis, args.right_sign, args.gear_ratio),
        )
    except ValueError as error:
        raise ConfigError(f"axes: {error}") from None
    return config, axes


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    configure_logging(args.log_level)
    log = logging.getLogger("invent.odrive")
    try:
        config, axes = settings(args)
    except ConfigError as error:
        log.error("%s", error)
        return 2
    stop = stop_on_signals()
    try:
        port = SerialPort(args.port, args.baud)
    except OSError as error:
        log.error("cannot open %s: %s", args.port, error.strerror or error)
        return 1
    odrive = ODrive(port, axes, START_REPLY_TIMEOUT_S, args.max_motor_torque, config.motor.output == "velocity")
    try:
        # before anything is announced: is there an ODrive, speaking ASCII, on this port?
        log.info("ODrive on %s: vbus %.1f V", args.port, odrive.read("vbus_voltage"))
        with open_session(session_config(connect=args.connect)) as session:
            node = Node(session, Keys(config.robot.name), Service.SIM)
            driver = Driver(node, config, odrive)
            try:
                # armed last: the ODrive's own watchdog runs from here, and the loop feeds it
                odrive.arm(args.vel_limit, args.watchdog_timeout or None)
                odrive.reply_timeout = args.reply_timeout
                log.info("axes in closed-loop control; %g Hz", 1.0 / config.sim.step)
                driver.run(stop)
            finally:
                driver.close()
                node.close()
        log.info("stopped: %s", driver.counters)
        return 0
    except LinkError as error:
        log.error("the ODrive on %s: %s (the port, its baud rate, the ASCII protocol enabled?)", args.port, error)
        return 1
    except OSError as error:
        log.error("the serial port %s failed: %s", args.port, error)
        return 1
    finally:
        try:
            odrive.disarm()
            log.info("axes idle")
        except OSError as error:
            log.error("could not idle the axes: %s", error)
        port.close()


if __name__ == "__main__":
    raise SystemExit(main())
