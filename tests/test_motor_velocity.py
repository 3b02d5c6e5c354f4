"""The motor's velocity output (``motor.output = "velocity"``), pure: MotorCore sends wheel speed
targets instead of torques, with the same states, stop, timeout and limits; the targets change on
the grid of ``motor.velocity_rate`` and are held between; never beyond ``input.max_wheel_speed``.
Hand-computed values and hypothesis properties."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.config import InputConfig, MotorConfig, RobotConfig
from services.motor.core import MotorCore, MotorState
from services.motor.wheel_velocity import WheelVelocityOutput

MS = 1_000_000
NO_LIMITS = {"max_vx": None, "max_ax": None, "max_w": None, "max_aw": None}
RADIUS, HALF_AXLE = RobotConfig().radius_of_left_wheel, RobotConfig().half_axle


def velocity_core(rate: float = 100.0, limits: InputConfig = InputConfig(), **motor: object) -> MotorCore:
    config = MotorConfig(**{"output": "velocity", "velocity_rate": rate, **NO_LIMITS, **motor})  # type: ignore[arg-type]
    return MotorCore(RobotConfig(), config, limits)


def wheel_speeds(vx: float, w: float) -> tuple[float, float]:
    return (vx - HALF_AXLE * w) / RADIUS, (vx + HALF_AXLE * w) / RADIUS


def test_the_default_output_is_torque_and_the_velocity_output_is_off():
    assert MotorConfig().output == "torque"
    assert MotorCore(RobotConfig(), MotorConfig()).velocity_output is None


def test_a_running_core_sends_the_wheel_speeds_of_its_command():
    motor = velocity_core()
    motor.set_target(0.3, 0.5)
    assert motor.step(0, [0.0, 0.0]) == [0.0, 0.0], "the first sample only initialises"
    targets = motor.step(1 * MS, [0.0, 0.0])
    assert targets == pytest.approx(list(wheel_speeds(0.3, 0.5)))
    assert motor.state is MotorState.RUNNING and motor.q_ref is None
    assert motor.status().output == "velocity" and motor.status().velocity_rate == 100.0


def test_targets_change_on_the_rate_grid_and_are_held_between():
    motor = velocity_core(rate=100.0)  # a 10 ms grid
    motor.set_target(0.2, 0.0)
    motor.step(0, [0.0, 0.0])
    first = motor.step(1 * MS, [0.0, 0.0])
    motor.set_target(0.4, 0.0, stamp_ns=1 * MS)
    held = [motor.step(t * MS, [0.0, 0.0]) for t in range(2, 10)]
    assert all(sample == first for sample in held), "held until the next period of the grid"
    assert motor.step(10 * MS, [0.0, 0.0]) == pytest.approx([4.0, 4.0]), "taken by the period's first sample"


def test_a_stop_sends_zero_at_once_and_targets_are_ignored_until_clear():
    motor = velocity_core()
    motor.set_target(0.3, 0.0)
    motor.step(0, [0.0, 0.0])
    assert motor.step(1 * MS, [0.0, 0.0]) == pytest.approx([3.0, 3.0])
    motor.stop()
    assert motor.step(2 * MS, [0.0, 0.0]) == [0.0, 0.0], "within the grid's period: at once"
    assert motor.set_target(0.3, 0.0) is False and motor.targets_ignored == 1
    assert motor.step(20 * MS, [0.0, 0.0]) == [0.0, 0.0]
    motor.clear()
    assert motor.step(21 * MS, [0.0, 0.0]) == [0.0, 0.0], "clear keeps the zero target"


def test_finished_and_idle_send_zero_targets():
    motor = velocity_core()
    motor.step(0, [0.0, 0.0])
    assert motor.step(1 * MS, [0.0, 0.0]) == [0.0, 0.0] and motor.state is MotorState.IDLE
    motor.set_target(0.3, 0.0)
    assert motor.step(2 * MS, [0.0, 0.0]) == pytest.approx([3.0, 3.0])
    motor.finish()
    assert motor.step(3 * MS, [0.0, 0.0]) == [0.0, 0.0]
    motor.start()
    assert motor.step(4 * MS, [0.0, 0.0]) == pytest.approx([3.0, 3.0]), "a new target at once after a rest"


def test_the_command_timeout_brakes_the_targets_to_zero():
    motor = velocity_core(command_timeout=0.05)
    motor.set_target(0.3, 0.0)
    motor.step(0, [0.0, 0.0])
    assert motor.step(10 * MS, [0.0, 0.0]) == pytest.approx([3.0, 3.0])
    assert motor.step(60 * MS, [0.0, 0.0]) == [0.0, 0.0] and motor.command_timeouts == 1


def test_the_acceleration_limit_ramps_the_targets():
    motor = velocity_core(rate=1000.0, max_ax=1.0)
    motor.set_target(0.5, 0.0)
    motor.step(0, [0.0, 0.0])
    targets = [motor.step(t * MS, [0.0, 0.0])[0] for t in range(1, 11)]
    assert targets == pytest.approx([0.001 * t / RADIUS for t in range(1, 11)]), "1 m/s² over 1 ms steps"


def test_targets_are_scaled_down_together_to_the_plausible_wheel_speed():
    output = WheelVelocityOutput(100.0, max_wheel_speed=10.0)
    assert output.follow(0, 20.0, -5.0) == (10.0, -2.5)


def test_a_non_finite_request_rests_at_zero():
    output = WheelVelocityOutput(100.0, max_wheel_speed=10.0)
    output.follow(0, 1.0, 1.0)
    assert output.follow(10 * MS, math.nan, 1.0) is None and output.targets == (0.0, 0.0)


@given(
    requests=st.lists(st.tuples(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6)), min_size=1, max_size=60),
    rate=st.floats(1.0, 1000.0),
    step_ns=st.integers(100_000, 20 * MS),
    limit=st.floats(0.1, 1000.0),
)
def test_targets_are_bounded_and_change_only_at_the_first_sample_of_a_period(requests, rate, step_ns, limit):
    output = WheelVelocityOutput(rate, limit)
    previous: tuple[float, float] | None = None
    previous_period: int | None = None
    for index, (left, right) in enumerate(requests):
        stamp_ns = index * step_ns
        targets = output.follow(stamp_ns, left, right)
        assert targets is not None
        assert all(abs(target) <= limit * (1 + 1e-12) for target in targets)
        period = stamp_ns // output.period_ns
        if period == previous_period:
            assert targets == previous, "held within a period"
        else:
            fastest = max(abs(left), abs(right))
            scale = min(1.0, limit / fastest) if fastest else 1.0
            assert targets == pytest.approx((left * scale, right * scale)), "taken at a period's first sample"
        previous, previous_period = targets, period


@given(vx=st.floats(-0.5, 0.5), w=st.floats(-1.0, 1.0), samples=st.integers(2, 40))
def test_a_steady_command_sends_its_wheel_speeds_at_every_sample(vx, w, samples):
    motor = velocity_core(rate=50.0)
    motor.set_target(vx, w)
    outputs = [motor.step(index * MS, [0.0, 0.0]) for index in range(samples)]
    assert outputs[0] == [0.0, 0.0]
    for output in outputs[1:]:
        assert output == pytest.approx(list(wheel_speeds(vx, w)))
