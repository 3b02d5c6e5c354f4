"""The command's limits as ros2_controllers tests theirs: control_toolbox's ``test/rate_limiter.cpp``
(the limiter alone, its cases copied with upstream's signed parameters) and diff_drive_controller's
``test_speed_limiter`` (a step command through the controller, wheel speed targets per period);
hypothesis checks the limiter against a port of upstream's ``RateLimiter::limit``.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.config import InputConfig, MotorConfig, RobotConfig
from services.motor.core import MotorCore
from services.motor.speed_limiter import SpeedLimiter

NAN = math.nan
MS = 1_000_000

NO_LIMITS = {name: None for name in ("max_vx", "max_ax", "max_w", "max_aw")}


def upstream(
    min_value: float = NAN,
    max_value: float = NAN,
    min_first_derivative_neg: float = NAN,
    max_first_derivative_pos: float = NAN,
    min_first_derivative_pos: float = NAN,
    max_first_derivative_neg: float = NAN,
    min_second_derivative: float = NAN,
    max_second_derivative: float = NAN,
) -> SpeedLimiter:
    """Our limiter from control_toolbox RateLimiter's signed arguments (NaN: unset), in its order."""

    def magnitude(value: float) -> float | None:
        return None if math.isnan(value) else abs(value)

    return SpeedLimiter(
        max_velocity=magnitude(max_value),
        max_velocity_reverse=magnitude(min_value),
        max_acceleration=magnitude(max_first_derivative_pos),
        max_acceleration_reverse=magnitude(min_first_derivative_neg),
        max_deceleration=magnitude(min_first_derivative_pos),
        max_deceleration_reverse=magnitude(max_first_derivative_neg),
        max_jerk=magnitude(max_second_derivative),
        max_jerk_falling=magnitude(min_second_derivative),
    )


# --- control_toolbox's test/rate_limiter.cpp ----------------------------------------------------


def test_no_limits():
    limiter = upstream()
    assert not limiter.enabled
    assert limiter.limit(10.0, 0.0, 0.0, 0.5) == 10.0
    assert limiter.limit(-10.0, 0.0, 0.0, 0.5) == -10.0


def test_value_limits():
    value_only = upstream(-0.5, 1.0)
    assert value_only.limit(10.0, 1.0, 1.0, 0.5) == 1.0
    assert value_only.limit(-10.0, -0.5, -0.5, 0.5) == -0.5
    limiter = upstream(-0.5, 1.0, -0.5, 1.0, NAN, NAN, -2.0, 5.0)
    # The acceleration limits now, not the value: 1.0 m/s² · 0.5 s, then −0.5 m/s² · 0.5 s.
    assert limiter.limit(10.0, 0.0, 0.0, 0.5) == pytest.approx(0.5)
    assert limiter.limit(-10.0, 0.0, 0.0, 0.5) == pytest.approx(-0.25)


def test_value_no_limits():
    assert upstream(NAN, NAN, -0.5, 1.0, NAN, NAN, -2.0, 2.0).limit(10.0, 0.0, 0.0, 0.5) == pytest.approx(0.5)
    assert upstream(NAN, NAN, -0.5, 1.0, NAN, NAN, -2.0, 2.0).limit(-10.0, 0.0, 0.0, 0.5) == pytest.approx(-0.25)
    jerk_only = upstream(NAN, NAN, NAN, NAN, NAN, NAN, -0.5, 5.0)
    # The jerk limits now: 5.0 m/s³ · 0.5 s · 0.5 s, then −0.5 m/s³ · 0.5 s · 0.5 s.
    assert jerk_only.limit(10.0, 0.0, 0.0, 0.5) == pytest.approx(1.25)
    assert jerk_only.limit(-10.0, 0.0, 0.0, 0.5) == pytest.approx(-0.125)


def test_first_derivative_limits():
    limiter = upstream(NAN, NAN, -0.5, 1.0)
    assert limiter.limit(10.0, 0.0, 0.0, 0.5) == pytest.approx(0.5)
    assert limiter.limit(-10.0, 0.0, 0.0, 0.5) == pytest.approx(-0.25)


def test_first_derivative_limits_asymmetric():
    limiter = upstream(NAN, NAN, -0.5, 1.0, -5.0, 10.0)
    # Moving forward (5 m/s): rising at max_acceleration, falling at max_deceleration.
    assert limiter.limit(10.0, 5.0, 5.0, 0.5) == pytest.approx(5.5)
    assert limiter.limit(-10.0, 5.0, 5.0, 0.5) == pytest.approx(2.5)
    # Moving backward (−5 m/s): rising at max_deceleration_reverse, falling at max_acceleration_reverse.
    assert limiter.limit(10.0, -5.0, -5.0, 0.5) == pytest.approx(0.0)
    assert limiter.limit(-10.0, -5.0, -5.0, 0.5) == pytest.approx(-5.25)


def test_second_derivative_limits():
    jerk_only = upstream(NAN, NAN, NAN, NAN, NAN, NAN, -1.0, 1.0)
    assert jerk_only.limit(10.0, 0.0, 0.0, 0.5) == pytest.approx(0.25)
    assert jerk_only.limit(-10.0, 0.0, 0.0, 0.5) == pytest.approx(-0.25)
    limiter = upstream(-0.5, 1.0, -0.5, 1.0, NAN, NAN, -1.0, 1.0)
    assert limiter.limit(10.0, 0.0, 0.0, 0.5) == pytest.approx(0.25)
    # The acceleration limits bind before the jerk's: −0.5 m/s² · 0.5 s.
    assert limiter.limit(-10.0, 0.0, 0.0, 0.5) == pytest.approx(-0.25)


def test_jerk_is_limited_only_while_the_rate_grows():
    """control_toolbox issue 240: a rate that shrinks (easing into the target) is never held back."""
    jerk_only = upstream(max_second_derivative=1.0)
    # Rising 1.0 per cycle, now only 0.1: the rate shrinks by 0.9 per cycle, far beyond 1·0.1², and passes.
    assert jerk_only.limit(2.1, 2.0, 1.0, 0.1) == 2.1


def test_unset_limits_take_their_base_as_upstream_resolves_them():
    only_bases = SpeedLimiter(max_velocity=1.0, max_acceleration=2.0, max_jerk=3.0)
    every_limit = SpeedLimiter(1.0, 1.0, 2.0, 2.0, 2.0, 2.0, 3.0, 3.0)
    for value, previous, before in [(5.0, 0.5, 0.2), (-5.0, 0.5, 0.7), (5.0, -0.5, -0.7), (-5.0, -0.5, -0.2)]:
        assert only_bases.limit(value, previous, before, 0.1) == every_limit.limit(value, previous, before, 0.1)
    # max_deceleration defaults to max_acceleration_reverse, not to max_acceleration.
    assert SpeedLimiter(max_acceleration=1.0, max_acceleration_reverse=4.0).limit(-10.0, 5.0, 5.0, 0.5) == 3.0


# --- against a port of upstream's RateLimiter::limit -------------------------------------------


def reference_limit(limits: tuple[float, ...], v: float, v0: float, v1: float, dt: float) -> float:
    """control_toolbox's ``RateLimiter<double>::limit`` line for line (set_params' defaults included)."""
    min_v, max_v, min_fd_neg, max_fd_pos, min_fd_pos, max_fd_neg, min_sd, max_sd = limits
    if math.isnan(min_v):
        min_v = -max_v
    if math.isnan(min_fd_neg):
        min_fd_neg = -max_fd_pos
    if math.isnan(max_fd_neg):
        max_fd_neg = max_fd_pos
    if math.isnan(min_fd_pos):
        min_fd_pos = min_fd_neg
    if math.isnan(min_sd):
        min_sd = -max_sd
    if not math.isnan(max_sd):
        dv, dv0 = v - v0, v0 - v1
        if (dv - dv0) * (v - v0) > 0:
            v = v0 + dv0 + min(max(dv - dv0, min_sd * dt * dt), max_sd * dt * dt)
    if not math.isnan(max_fd_pos):
        if v0 > 0:
            dv_min, dv_max = min_fd_pos * dt, max_fd_pos * dt
        elif v0 < 0:
            dv_min, dv_max = min_fd_neg * dt, max_fd_neg * dt
        else:
            dv_min, dv_max = min_fd_neg * dt, max_fd_pos * dt
        v = v0 + min(max(v - v0, dv_min), dv_max)
    if not math.isnan(max_v):
        v = min(max(v, min_v), max_v)
    return v


limit = st.one_of(st.just(NAN), st.floats(0.01, 20.0))
speed = st.floats(-5.0, 5.0)


@given(
    bounds=st.tuples(limit, limit, limit, limit, limit, limit, limit, limit),
    values=st.tuples(speed, speed, speed),
    dt=st.floats(0.0005, 0.1),
)
def test_the_limiter_is_upstreams(bounds, values, dt):
    min_v, max_v, min_fd_neg, max_fd_pos, min_fd_pos, max_fd_neg, min_sd, max_sd = bounds
    # Signed as upstream's: minima non-positive, maxima non-negative.
    signed = (-min_v, max_v, -min_fd_neg, max_fd_pos, -min_fd_pos, max_fd_neg, -min_sd, max_sd)
    limiter = upstream(*signed)
    assert limiter.limit(*values, dt) == pytest.approx(reference_limit(signed, *values, dt), rel=1e-9, abs=1e-12)


@given(
    max_v=st.floats(0.1, 2.0),
    max_a=st.floats(0.1, 10.0),
    max_j=st.one_of(st.none(), st.floats(1.0, 100.0)),
    targets=st.lists(speed, min_size=1, max_size=30),
    dt=st.floats(0.001, 0.05),
)
def test_symmetric_limits_are_the_same_forward_and_backward(max_v, max_a, max_j, targets, dt):
    """Only the bases set (``max_vx``, ``max_ax``, ``max_jerk_x``): a mirrored command is mirrored."""
    limiter = SpeedLimiter(max_velocity=max_v, max_acceleration=max_a, max_jerk=max_j)
    forward = backward = (0.0, 0.0)
    for target in targets:
        out = limiter.limit(target, forward[0], forward[1], dt)
        mirrored = limiter.limit(-target, backward[0], backward[1], dt)
        assert mirrored == pytest.approx(-out, abs=1e-12)
        assert abs(out) <= max_v
        assert abs(out - forward[0]) <= max_a * dt * (1 + 1e-9)
        forward, backward = (out, forward[0]), (mirrored, backward[0])


@given(
    limits=st.tuples(*[st.floats(0.1, 10.0)] * 6),
    previous=speed,
    target=speed,
    dt=st.floats(0.001, 0.05),
)
def test_each_direction_of_motion_has_its_own_acceleration_range(limits, previous, target, dt):
    acc, acc_reverse, dec, dec_reverse, max_v, max_v_reverse = limits
    limiter = SpeedLimiter(max_v, max_v_reverse, acc, acc_reverse, dec, dec_reverse)
    out = limiter.limit(target, previous, previous, dt)
    assert -max_v_reverse <= out <= max_v
    change = out - previous
    if previous > 0.0:
        low, high = dec, acc
    elif previous < 0.0:
        low, high = acc_reverse, dec_reverse
    else:
        low, high = acc_reverse, acc
    tolerance = 1e-9 * (1.0 + abs(previous))
    within_velocity = -max_v_reverse <= previous <= max_v
    if within_velocity:
        assert -low * dt - tolerance <= change <= high * dt + tolerance


@given(values=st.tuples(speed, speed, speed), dt=st.floats(0.001, 0.05))
def test_a_value_within_every_limit_passes_bit_for_bit(values, dt):
    value, previous, before = values
    generous = SpeedLimiter(10.0, 10.0, 1e6, 1e6, 1e6, 1e6, 1e12, 1e12)
    assert generous.limit(value, previous, before, dt) == value


# --- diff_drive_controller's test_speed_limiter ----------------------------------------------


def controller(**limits: object) -> MotorCore:
    """diff_drive_controller's test robot: wheel radius 0.1 m; only the limits named."""
    motor = MotorConfig(**{**NO_LIMITS, "command_timeout": 0.0, **limits})  # type: ignore[arg-type]
    core = MotorCore(RobotConfig(), motor, InputConfig(stamp_horizon=1e9, max_wheel_speed=1e9))
    core.set_target(0.0, 0.0)
    core.step(0, [0.0, 0.0])
    return core


class Clock:
    def __init__(self) -> None:
        self.ns = 0

    def update(self, core: MotorCore, period_ns: int) -> float:
        """One controller update: the left wheel's speed target (rad/s)."""
        self.ns += period_ns
        core.step(self.ns, [0.0, 0.0])
        assert core.dq_ref is not None
        return core.dq_ref[0]


def test_speed_limiter_steps_forward_then_backward_as_diff_drive_controller():
    """diff_drive_controller's test_speed_limiter, its limits and steps: each step reaches its wheel
    speed only after speed / limit seconds, at 1 ms periods."""
    max_acceleration, max_deceleration, max_acceleration_reverse, max_deceleration_reverse = 2.0, -4.0, -8.0, 10.0
    core = controller(
        max_ax=max_acceleration,
        max_decel_x=-max_deceleration,
        max_ax_reverse=-max_acceleration_reverse,
        max_decel_x_reverse=max_deceleration_reverse,
    )
    clock, dt_ns, wheel_radius = Clock(), 1 * MS, 0.1
    for _ in range(3):  # fill the limiter's history
        assert clock.update(core, 10 * MS) == pytest.approx(0.0, abs=1e-3)
    phases = [
        (1.0, 1.0 / max_acceleration),
        (0.0, -1.0 / max_deceleration),
        (-1.0, -1.0 / max_acceleration_reverse),
        (0.0, 1.0 / max_deceleration_reverse),
    ]
    previous = 0.0
    for linear, time_to_reach in phases:
        core.set_target(linear, 0.0)
        wheel = linear / wheel_radius
        for i in range(math.floor(time_to_reach / 0.001) - 1):
            speed = clock.update(core, dt_ns)
            assert min(previous, wheel) < speed < max(previous, wheel), (
                f"at t {i * 0.001:g} s, before {time_to_reach} s"
            )
        assert clock.update(core, dt_ns) == pytest.approx(wheel, abs=1e-3)
        for _ in range(3):
            assert clock.update(core, 10 * MS) == pytest.approx(wheel, abs=1e-3)
        previous = wheel


def test_the_symmetric_names_keep_their_meaning():
    """``max_vx`` and ``max_ax`` alone: backward as forward."""
    core = controller(max_vx=0.5, max_ax=2.0)
    clock = Clock()
    core.set_target(-1.0, 0.0)
    speeds = [clock.update(core, MS) for _ in range(300)]
    assert speeds[0] == pytest.approx(-0.02)
    assert speeds[-1] == pytest.approx(-5.0), "−max_vx, in wheel speed"
    assert sum(1 for speed in speeds if speed > -5.0 + 1e-9) == 249, "0.5 m/s at 2 m/s² from rest: 250 ms"


def test_reverse_velocity_limit_applies_backward_only():
    core = controller(max_vx=1.0, max_vx_reverse=0.2)
    clock = Clock()
    core.set_target(-1.0, 0.0)
    assert clock.update(core, MS) == pytest.approx(-2.0)
    core.set_target(1.0, 0.0)
    assert clock.update(core, MS) == pytest.approx(10.0)


def test_a_jerk_limit_ramps_the_acceleration():
    """max_jerk_x 100 m/s³ at 1 ms: the acceleration grows 0.1 m/s² per cycle, vx by k·1e-4 m/s at cycle k."""
    core = controller(max_ax=2.0, max_jerk_x=100.0)
    core.set_target(1.0, 0.0)
    clock = Clock()
    commands = []
    for _ in range(30):
        clock.update(core, MS)
        commands.append(core.command[0])
    rises = [b - a for a, b in zip([0.0, *commands], commands, strict=False)]
    assert rises[:20] == pytest.approx([k * 1e-4 for k in range(1, 21)])
    assert rises[25] == pytest.approx(2e-3), "then max_ax binds: 2 m/s² · 1 ms"


def test_the_angular_limits_are_set_apart_too():
    core = controller(max_w=2.0, max_w_reverse=1.0, max_aw=10.0, max_aw_reverse=5.0, max_jerk_w=1e9)
    clock = Clock()
    core.set_target(0.0, -3.0)
    clock.update(core, MS)
    assert core.command[1] == pytest.approx(-0.005), "max_aw_reverse 5 rad/s² · 1 ms"
    for _ in range(1000):
        clock.update(core, MS)
    assert core.command[1] == -1.0, "max_w_reverse"


def test_a_stop_bypasses_the_limits_and_the_jerk_starts_from_it():
    core = controller(max_ax=2.0, max_jerk_x=100.0)
    core.set_target(1.0, 0.0)
    clock = Clock()
    for _ in range(50):
        clock.update(core, MS)
    core.stop()
    clock.update(core, MS)
    assert core.command == (0.0, 0.0)
    core.clear()
    core.set_target(1.0, 0.0)
    clock.update(core, MS)
    assert core.command[0] == pytest.approx(1e-4), "from rest, the jerk ramps again"


@given(
    limits=st.tuples(*[st.floats(0.1, 5.0)] * 6),
    jerk=st.one_of(st.none(), st.floats(10.0, 1000.0)),
    targets=st.lists(st.floats(-1.5, 1.5), min_size=1, max_size=40),
)
def test_the_controllers_commands_keep_every_directional_limit(limits, jerk, targets):
    """Through MotorCore at 1 ms cycles: each command within [−max_vx_reverse, max_vx] and its change
    within the range the previous command's direction selects, whatever the jerk limit does first."""
    acc, acc_reverse, dec, dec_reverse, max_v, max_v_reverse = limits
    core = controller(
        max_vx=max_v,
        max_vx_reverse=max_v_reverse,
        max_ax=acc,
        max_ax_reverse=acc_reverse,
        max_decel_x=dec,
        max_decel_x_reverse=dec_reverse,
        max_jerk_x=jerk,
    )
    clock, dt = Clock(), 0.001
    previous = 0.0
    for target in targets:
        core.set_target(target, 0.0)
        clock.update(core, MS)
        now = core.command[0]
        assert -max_v_reverse <= now <= max_v
        low, high = (
            (dec, acc) if previous > 0.0 else (acc_reverse, dec_reverse) if previous < 0.0 else (acc_reverse, acc)
        )
        assert -low * dt * (1 + 1e-9) <= now - previous <= high * dt * (1 + 1e-9)
        previous = now
