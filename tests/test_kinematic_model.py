"""The kinematic engine's drive model (sim_bridge/kinematic_model.py): pure, no PyBullet."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.config import RobotConfig, SimConfig
from sim_bridge.kinematic_model import DiffDrivePlant, DriveModel

DT = 0.001
MODEL = DriveModel.from_description(RobotConfig(), SimConfig())
torque = st.floats(-30.0, 30.0, allow_nan=False)


def run(plant: DiffDrivePlant, left: float, right: float, steps: int, dt: float = DT) -> DiffDrivePlant:
    for _ in range(steps):
        plant.step(left, right, dt)
    return plant


def test_the_model_sums_the_description_s_masses_and_inertias():
    sim = SimConfig()
    assert MODEL.mass == pytest.approx(sim.body_mass + 2 * sim.wheel_mass + 2 * sim.caster_mass)
    assert MODEL.left_radius == MODEL.right_radius == RobotConfig().radius_of_left_wheel
    assert MODEL.half_axle == RobotConfig().half_axle
    assert MODEL.wheel_inertia == pytest.approx(sim.wheel_mass * 0.1**2 / 2)
    # the body's cylinder alone gives m r^2 / 2; the wheels and casters add theirs about the centre
    assert MODEL.yaw_inertia > sim.body_mass * RobotConfig().radius_of_body_area ** 2 / 2
    assert MODEL.max_torque == sim.max_wheel_torque
    matrix = MODEL.mass_matrix
    assert np.allclose(matrix, matrix.T) and np.all(np.linalg.eigvalsh(matrix) > 0.0)


def test_a_bad_model_is_refused():
    with pytest.raises(ValueError, match="half_axle"):
        DriveModel(0.1, 0.1, 0.0, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="damping"):
        DriveModel(0.1, 0.1, 0.2, 1.0, 1.0, 0.0, damping=-1.0)


def test_equal_torques_go_straight_at_the_inertia_s_acceleration():
    plant = run(DiffDrivePlant(MODEL, 1.0, 2.0, 0.5), 1.0, 1.0, 1000)
    matrix = MODEL.mass_matrix
    expected_rate = 1.0 / (matrix[0, 0] + matrix[0, 1])  # rad/s after 1 s of 1 N·m on both
    assert plant.wheel_velocities == pytest.approx((expected_rate, expected_rate), rel=1e-9)
    assert plant.theta == pytest.approx(0.5, abs=1e-12)
    travelled = math.hypot(plant.x - 1.0, plant.y - 2.0)
    assert travelled == pytest.approx(MODEL.left_radius * expected_rate / 2.0, rel=1e-9)  # ½ a t²
    assert math.atan2(plant.y - 2.0, plant.x - 1.0) == pytest.approx(0.5, abs=1e-12)


def test_opposite_torques_turn_in_place():
    plant = run(DiffDrivePlant(MODEL), -1.0, 1.0, 2000)
    assert abs(plant.x) < 1e-12 and abs(plant.y) < 1e-12
    assert plant.theta > 0.5  # left backwards, right forwards: counter-clockwise
    assert plant.angular_velocity[2] > 0.0 and plant.linear_velocity == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_torques_saturate_at_the_limit():
    fast, capped = DiffDrivePlant(MODEL), DiffDrivePlant(MODEL)
    run(fast, 100.0, -100.0, 100)
    run(capped, MODEL.max_torque, -MODEL.max_torque, 100)
    assert fast.applied == (MODEL.max_torque, -MODEL.max_torque)
    assert fast.wheel_velocities == capped.wheel_velocities and fast.theta == capped.theta


@settings(max_examples=100, deadline=None)
@given(left=torque, right=torque, steps=st.integers(1, 200))
def test_impulse_without_losses_is_the_mass_matrix_times_the_speed(left: float, right: float, steps: int):
    plant = run(DiffDrivePlant(MODEL), left, right, steps)
    impulse = np.array([MODEL.saturate(left), MODEL.saturate(right)]) * steps * DT
    assert MODEL.mass_matrix @ np.array(plant.wheel_velocities) == pytest.approx(impulse, rel=1e-9, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(left=torque, right=torque, damping=st.floats(0.001, 5.0), steps=st.integers(1, 300))
def test_losses_only_take_energy_away(left: float, right: float, damping: float, steps: int):
    lossy = DriveModel.from_description(RobotConfig(), SimConfig(), damping=damping)
    plant = run(DiffDrivePlant(lossy), left, right, 200)
    energy = lossy.kinetic_energy(*plant.wheel_velocities)
    for _ in range(steps):
        plant.step(0.0, 0.0, DT)
        now = lossy.kinetic_energy(*plant.wheel_velocities)
        assert now <= energy * (1 + 1e-12)
        energy = now


@settings(max_examples=50, deadline=None)
@given(left=torque, right=torque, steps=st.integers(1, 100))
def test_the_step_is_exact_one_long_step_is_many_short(left: float, right: float, steps: int):
    lossy = DriveModel.from_description(RobotConfig(), SimConfig(), damping=0.3)
    short, long = run(DiffDrivePlant(lossy), left, right, steps * 4, DT / 4), DiffDrivePlant(lossy)
    long.step(left, right, steps * DT)
    assert short.wheel_velocities == pytest.approx(long.wheel_velocities, rel=1e-9, abs=1e-12)
    assert short.wheel_angles == pytest.approx(long.wheel_angles, rel=1e-9, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(left=torque, right=torque, spin_up=st.integers(1, 2000))
def test_the_brakes_stop_the_wheels_within_the_torque_limit(left: float, right: float, spin_up: int):
    plant = run(DiffDrivePlant(MODEL), left, right, spin_up)
    energy = MODEL.kinetic_energy(*plant.wheel_velocities)
    for _ in range(10_000):
        if plant.wheel_velocities == (0.0, 0.0):
            break
        plant.brake()
        plant.step(5.0, 5.0, DT)  # ignored while braking
        assert all(abs(t) <= MODEL.max_torque for t in plant.applied)
        now = MODEL.kinetic_energy(*plant.wheel_velocities)
        assert now <= energy * (1 + 1e-12)
        energy = now
    assert plant.wheel_velocities == (0.0, 0.0)
    at_rest = (plant.x, plant.y, plant.theta)
    plant.brake()
    plant.step(0.0, 0.0, DT)
    assert (plant.x, plant.y, plant.theta) == at_rest and plant.braking is False


def test_a_brake_lasts_one_step():
    plant = run(DiffDrivePlant(MODEL), 1.0, 1.0, 10)  # slow enough to stop within the limit in one step
    plant.brake()
    plant.step(1.0, 1.0, DT)
    assert plant.wheel_velocities == (0.0, 0.0)
    plant.step(1.0, 1.0, DT)
    assert plant.wheel_velocities[0] > 0.0


@settings(max_examples=30, deadline=None)
@given(torques=st.lists(st.tuples(torque, torque), min_size=1, max_size=50))
def test_the_same_torques_give_the_same_floats(torques: list[tuple[float, float]]):
    def replay() -> tuple[object, ...]:
        plant = DiffDrivePlant(MODEL, 0.3, -0.2, 1.0)
        for left, right in torques:
            plant.step(left, right, DT)
        return plant.x, plant.y, plant.theta, plant.wheel_angles, plant.wheel_velocities

    assert replay() == replay()


@settings(max_examples=100, deadline=None)
@given(left=torque, right=torque, steps=st.integers(1, 500))
def test_the_body_rolls_with_the_wheels(left: float, right: float, steps: int):
    """Ideal rolling: the heading is the wheels' difference over the axle; each step's travel an arc."""
    plant = run(DiffDrivePlant(MODEL), left, right, steps)
    angle_l, angle_r = plant.wheel_angles
    expected = (MODEL.right_radius * angle_r - MODEL.left_radius * angle_l) / (2 * MODEL.half_axle)
    assert plant.theta == pytest.approx(expected, rel=1e-9, abs=1e-12)
    v, w = MODEL.body_velocity(*plant.wheel_velocities)
    assert plant.linear_velocity == pytest.approx((v * math.cos(plant.theta), v * math.sin(plant.theta), 0.0))
    assert plant.angular_velocity == (0.0, 0.0, w)
