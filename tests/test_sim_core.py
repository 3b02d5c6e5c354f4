"""The simulator core (no zenoh): shapes, directions, saturation, determinism and bump contacts."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
import pybullet as p
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.codec import BadInput
from services.config import ConfigError, RobotConfig, SimConfig
from sim_bridge.display import DISPLAY_VARIABLE
from sim_bridge.simulator import Contact, Placement, Simulator, connect
from sim_bridge.world import InitialPose, load_world, parse_world

Torques = Callable[[int], list[float]]


@pytest.fixture
def sim() -> Iterator[Simulator]:
    with Simulator(RobotConfig(), SimConfig(), load_world(None)) as simulator:
        yield simulator


def drive(sim: Simulator, torques: Torques, steps: int) -> list[Contact]:
    """Step ``steps`` times with ``torques(step_index)``; return the contacts that began."""
    began: list[Contact] = []
    for _ in range(steps):
        sim.set_torques(torques(sim.step_index))
        began.extend(sim.step())
    return began


def constant(left: float, right: float) -> Torques:
    return lambda _k: [left, right]


def yaw(pose: list[float]) -> float:
    return math.atan2(pose[6], pose[3])


def rotation(pose: list[float]) -> np.ndarray:
    return np.array(pose[3:12]).reshape(3, 3)


def assert_proper_rotation(pose: list[float]) -> None:
    matrix = rotation(pose)
    np.testing.assert_allclose(matrix @ matrix.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(matrix) == pytest.approx(1.0, abs=1e-9)


def test_state_shapes_and_the_robot_at_rest(sim: Simulator):
    angles, pose = sim.wheel_angles(), sim.body_pose()
    assert angles == [0.0, 0.0]
    assert len(pose) == 12 and all(isinstance(v, float) for v in pose)
    assert pose[:3] == pytest.approx([0.0, 0.0, RobotConfig().radius_of_left_wheel])
    np.testing.assert_allclose(rotation(pose), np.eye(3), atol=1e-12)
    assert sim.time_ns == 0 and sim.step_ns == 1_000_000


def test_simulation_time_counts_steps(sim: Simulator):
    drive(sim, constant(0.0, 0.0), 25)
    assert sim.step_index == 25 and sim.time_ns == 25_000_000


def test_constant_positive_torque_drives_forward_without_slip(sim: Simulator):
    drive(sim, constant(1.0, 1.0), 1000)
    pose, (left, right) = sim.body_pose(), sim.wheel_angles()
    radius = RobotConfig().radius_of_left_wheel
    assert pose[0] > 0.1
    assert abs(pose[1]) < 1e-6 and abs(yaw(pose)) < 1e-6
    assert left > 0 and right > 0 and left == pytest.approx(right, rel=1e-6)
    assert pose[0] == pytest.approx(left * radius, rel=0.02)


def test_negative_torque_drives_backward(sim: Simulator):
    drive(sim, constant(-1.0, -1.0), 500)
    assert sim.body_pose()[0] < -0.02
    assert all(angle < 0 for angle in sim.wheel_angles())


def test_opposite_torques_spin_in_place(sim: Simulator):
    drive(sim, constant(1.0, -1.0), 1000)
    pose, (left, right) = sim.body_pose(), sim.wheel_angles()
    assert yaw(pose) < -0.2, "left forward, right backward turns clockwise"
    assert math.hypot(pose[0], pose[1]) < 0.01
    assert left > 0 > right and left == pytest.approx(-right, rel=0.01)
    assert_proper_rotation(pose)


def test_the_yaw_matches_the_wheel_angles(sim: Simulator):
    drive(sim, constant(-0.5, 0.5), 800)
    (left, right), robot = sim.wheel_angles(), RobotConfig()
    expected = (right - left) * robot.radius_of_left_wheel / robot.length_of_axle
    assert yaw(sim.body_pose()) == pytest.approx(expected, rel=0.02)


def test_wheel_angles_and_torques_follow_the_wheel_ids():
    robot = RobotConfig(left_wheel_id=2, right_wheel_id=0)
    with Simulator(robot, SimConfig(), load_world(None)) as sim:
        assert sim.wheel_count == 3
        drive(sim, lambda _k: [0.0, 0.0, 1.0], 500)
        right, unused, left = sim.wheel_angles()
        assert unused == 0.0 and left > 0.1 and abs(right) < left
        assert yaw(sim.body_pose()) < 0, "only the left wheel driving turns clockwise"
        assert sim.applied_torques == [0.0, 0.0, 1.0]


def test_torques_are_saturated_at_the_motor_limit():
    limit = SimConfig().max_wheel_torque
    with (
        Simulator(RobotConfig(), SimConfig(), load_world(None)) as over,
        Simulator(RobotConfig(), SimConfig(), load_world(None)) as at_limit,
    ):
        over.set_torques([1e6, -1e6])
        assert over.applied_torques == [limit, -limit]
        drive(over, constant(1e6, -1e6), 200)
        drive(at_limit, constant(limit, -limit), 200)
        assert over.body_pose() == at_limit.body_pose()


def test_zero_torques_clear_the_applied_torques(sim: Simulator):
    sim.set_torques([2.0, 3.0])
    sim.set_zero_torques()
    assert sim.applied_torques == [0.0, 0.0]
    sim.step()
    assert sim.body_pose()[0] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("torques", [[1.0], [1.0, 2.0, 3.0], []])
def test_a_torque_vector_of_the_wrong_length_is_bad_input(sim: Simulator, torques: list[float]):
    with pytest.raises(BadInput, match="expected 2"):
        sim.set_torques(torques)


def varying(k: int) -> list[float]:
    return [3.0 * math.sin(k / 37.0) + 1.0, 2.0 * math.cos(k / 23.0)]


def test_two_runs_with_the_same_torques_end_bit_identical():
    with (
        Simulator(RobotConfig(), SimConfig(), load_world("bump")) as first,
        Simulator(RobotConfig(), SimConfig(), load_world("bump")) as second,
    ):
        drive(first, varying, 1500)
        drive(second, varying, 1500)
        assert first.body_pose() == second.body_pose()
        assert first.wheel_angles() == second.wheel_angles()


@settings(max_examples=15, deadline=None)
@given(st.lists(st.tuples(st.floats(-30.0, 30.0), st.floats(-30.0, 30.0), st.integers(1, 150)), min_size=1, max_size=4))
def test_the_body_rotation_is_always_proper(segments: list[tuple[float, float, int]]):
    with Simulator(RobotConfig(), SimConfig(), load_world(None)) as sim:
        for left, right, steps in segments:
            drive(sim, constant(left, right), steps)
            assert_proper_rotation(sim.body_pose())


def test_the_initial_pose_comes_from_the_world():
    world = parse_world("[initial_pose]\nx = 1.0\ny = -2.0\ntheta = 1.5707963267948966\n")
    with Simulator(RobotConfig(), SimConfig(), world) as sim:
        pose = sim.body_pose()
        assert pose[:2] == pytest.approx([1.0, -2.0])
        assert yaw(pose) == pytest.approx(math.pi / 2)
        drive(sim, constant(1.0, 1.0), 500)
        moved = sim.body_pose()
        assert moved[1] > -2.0 + 0.02 and moved[0] == pytest.approx(1.0, abs=1e-4), "forward is +y when facing +y"


def test_driving_into_the_box_begins_one_contact_on_its_near_face():
    with Simulator(RobotConfig(), SimConfig(), load_world("bump")) as sim:
        began = drive(sim, constant(2.0, 2.0), 2000)
        (contact,) = began
        box = sim.world.boxes[0]
        assert contact.obstacle == "box"
        assert contact.x == pytest.approx(box.x - box.size[0] / 2, abs=1e-3)
        assert abs(contact.y) < RobotConfig().radius_of_body_area and 0.0 < contact.z < box.size[2]
        touching_x = box.x - box.size[0] / 2 - RobotConfig().radius_of_body_area
        assert sim.body_pose()[0] == pytest.approx(touching_x, abs=0.01), "the box stops the body"


def test_the_ground_is_not_an_obstacle(sim: Simulator):
    assert drive(sim, varying, 1000) == []


def test_leaving_and_touching_again_is_a_second_bump():
    with Simulator(RobotConfig(), SimConfig(), load_world("bump")) as sim:
        first = drive(sim, constant(2.0, 2.0), 1200)
        backing = drive(sim, constant(-3.0, -3.0), 400)
        again = drive(sim, constant(3.0, 3.0), 1500)
        assert [c.obstacle for c in first] == ["box"] and backing == []
        assert [c.obstacle for c in again] == ["box"]


def test_a_step_shorter_than_a_nanosecond_is_a_config_error():
    with pytest.raises(ConfigError, match="sim.step"):
        Simulator(RobotConfig(), SimConfig(step=1e-10), load_world(None))


def test_gui_without_a_display_is_a_config_error(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv(DISPLAY_VARIABLE, raising=False)
    with pytest.raises(ConfigError, match=r"--gui needs a display.*\$DISPLAY"):
        connect(gui=True)


def test_two_robots_in_one_world_move_independently_and_a_head_on_meeting_is_a_contact_for_each():
    facing = (
        Placement("rh0", RobotConfig(name="rh0"), InitialPose(x=0.0, y=0.0, theta=0.0)),
        Placement("rh1", RobotConfig(name="rh1"), InitialPose(x=1.0, y=0.0, theta=math.pi)),
    )
    with Simulator(RobotConfig(), SimConfig(), load_world(None), fleet=facing) as sim:
        first, second = sim.robots
        assert [robot.name for robot in sim.robots] == ["rh0", "rh1"]
        assert second.body_pose()[0] == pytest.approx(1.0) and sim.body_pose() == first.body_pose()
        began: list[Contact] = []
        for _ in range(3000):
            first.set_torques([1.0, 1.0])
            second.set_torques([1.0, 1.0])
            began.extend(sim.step())
            if began:
                break
        assert sorted((contact.robot, contact.obstacle) for contact in began) == [(0, "rh1"), (1, "rh0")]
        assert all(contact.x == pytest.approx(0.5, abs=0.01) for contact in began), "they meet half-way"
        assert first.body_pose()[0] == pytest.approx(1.0 - second.body_pose()[0], abs=1e-6), "mirror images"


def test_a_fleet_of_one_at_the_worlds_start_is_the_one_robot_simulator():
    alone = (Placement("rh0", RobotConfig(), InitialPose()),)
    with (
        Simulator(RobotConfig(), SimConfig(), load_world(None)) as single,
        Simulator(RobotConfig(), SimConfig(), load_world(None), fleet=alone) as fleet,
    ):
        for sim in (single, fleet):
            for step in range(500):
                sim.set_torques(varying(step))
                sim.step()
        assert fleet.body_pose() == single.body_pose() and fleet.wheel_angles() == single.wheel_angles()


def test_a_braked_robot_comes_to_rest_and_torques_release_the_brakes(sim: Simulator):
    drive(sim, constant(2.0, 2.0), 1000)
    moving = sim.body_pose()[0]
    robot = sim.robots[0]
    for _ in range(300):
        robot.brake()
        sim.step()
    stopped = sim.body_pose()[0]
    for _ in range(100):
        robot.brake()
        sim.step()
    assert stopped > moving and sim.body_pose()[0] == pytest.approx(stopped, abs=1e-4), "at rest, held"
    assert robot.braking and robot.applied_torques == [0.0, 0.0]
    drive(sim, constant(2.0, 2.0), 500)
    assert not robot.braking and sim.body_pose()[0] > stopped + 0.05, "torques drive it again"


class PairwiseContacts:
    """The straightforward contact check, the reference: ``getContactPoints`` for each (robot,
    obstacle) pair then each pair of robots, a pair's first touching point when it has not touched
    for ``sim.bump_release``, a contact between two robots once for each."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        robots = sim.robots
        self.pairs = [
            (index, robot.body, obstacle, name, None)
            for index, robot in enumerate(robots)
            for obstacle, name in sim._obstacles
        ] + [
            (index, robot.body, robots[other].body, robots[other].name, other)
            for index, robot in enumerate(robots)
            for other in range(index + 1, len(robots))
        ]
        self.last_touch: dict[int, int] = {}
        self.release_steps = round(sim.sim_config.bump_release / sim.sim_config.step)

    def began(self) -> list[Contact]:
        sim, began = self.sim, []
        for pair_index, (robot, body, other, name, other_robot) in enumerate(self.pairs):
            points = p.getContactPoints(bodyA=body, bodyB=other, physicsClientId=sim.client)
            # A point: [5] its position on body A, [6] on body B, [8] the distance (> 0: not yet touching).
            touching = [point for point in points if point[8] <= 0.0]
            if not touching:
                continue
            last = self.last_touch.get(pair_index)
            if last is None or sim.step_index - last > self.release_steps:
                began.append(Contact(robot, name, *touching[0][6]))
                if other_robot is not None:
                    began.append(Contact(other_robot, sim.robots[robot].name, *touching[0][5]))
            self.last_touch[pair_index] = sim.step_index
        return began


CROWDED_WORLD = """
[[boxes]]
name = "wall"
x = 1.0
y = 0.0
size = [0.2, 1.0, 0.5]

[[boxes]]
name = "crate"
x = 1.0
y = -3.0
size = [0.2, 0.4, 0.3]
mass = 2.0

[[cylinders]]
name = "post"
x = 1.6
y = -3.0
radius = 0.1
height = 0.5

[[boxes]]
name = "curb"
x = 1.0
y = 6.0
size = [0.2, 1.0, 0.04]

[[boxes]]
name = "mat"
x = 0.0
y = 9.0
size = [1.0, 1.0, 0.01]
"""


def placed(name: str, x: float, y: float, theta: float = 0.0) -> Placement:
    return Placement(name, RobotConfig(name=name), InitialPose(x=x, y=y, theta=theta))


def forward_back_forward(k: int) -> list[float]:
    """Into what is ahead, back off, into it again turning (a second bump, elsewhere on the body)."""
    return [2.0, 2.0] if k < 1500 else [-3.0, -3.0] if k < 1800 else [3.0, 2.6]


@pytest.mark.parametrize(
    ("world", "fleet", "one_query", "bumps"),
    [
        # r0 into a fixed box, r1 and r2 head-on, r3 pushing a crate into a post (their contact is no bump),
        # r4 over a curb (Bullet names the curb first in their points), r5 starting on a mat (wheels and
        # casters on it: several points begin at once): more pairs than robots, so the simulator asks
        # for the world's contact points in one query.
        (
            CROWDED_WORLD,
            (
                placed("r0", 0.0, 0.0),
                placed("r1", 0.0, 3.0),
                placed("r2", 1.4, 3.0, math.pi),
                placed("r3", 0.0, -3.0),
                placed("r4", 0.0, 6.0),
                placed("r5", 0.0, 9.0),
            ),
            True,
            [(0, "wall"), (1, "r2"), (2, "r1"), (3, "crate"), (4, "curb"), (5, "mat")],
        ),
        # Two robots head-on on the empty floor: one pair, asked for by itself.
        ("", (placed("r0", 0.0, 0.0), placed("r1", 1.4, 0.0, math.pi)), False, [(0, "r1"), (1, "r0")]),
    ],
    ids=["one-query", "pair-by-pair"],
)
def test_the_contacts_of_each_step_are_those_of_the_pairwise_check(
    world: str, fleet: tuple[Placement, ...], one_query: bool, bumps: list[tuple[int, str]]
):
    with Simulator(RobotConfig(), SimConfig(), parse_world(world), fleet=fleet) as sim:
        assert sim._one_query is one_query
        reference = PairwiseContacts(sim)
        began: list[Contact] = []
        for step in range(3000):
            for robot in sim.robots:
                robot.set_torques(forward_back_forward(step))
            contacts = list(sim.step())
            assert contacts == reference.began(), f"step {sim.step_index}"
            began.extend(contacts)
    touched = [(contact.robot, contact.obstacle) for contact in began]
    assert sorted(set(touched)) == bumps and len(touched) > len(bumps), "every pair touched, some twice"
