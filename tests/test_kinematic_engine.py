"""The kinematic engine (sim_bridge/kinematic.py, kinematic_world.py) in-process: its robots move as
PyBullet's do under the same torques, stop against obstacles and robots with a bump that begins as
PyBullet's, its lidar sees what PyBullet's sees, and it runs where PyBullet cannot be imported."""

from __future__ import annotations

import ast
import math
import subprocess
import sys
from pathlib import Path

import pytest

from schemas.codec import BadInput
from schemas.messages import Time
from services.config import ImuConfig, LidarConfig, RobotConfig, SimConfig, SimEngine, load_config
from services.exits import ExitStatus
from sim_bridge.engine import Contact, Placement
from sim_bridge.kinematic import KinematicSimulator
from sim_bridge.kinematic_world import Circle, Rectangle
from sim_bridge.simulator import Simulator
from sim_bridge.world import InitialPose, load_world, parse_world
from tests.harness import REPO, free_port, refused

AHEAD = 180
"""The ray straight ahead (angle_min is -π, one ray a degree)."""
BOX_FACE_X = 0.9
POST_WORLD = '[[cylinders]]\nname = "post"\nx = 0.0\ny = 1.5\nradius = 0.1\nheight = 0.5\n'


def drive(sim: KinematicSimulator | Simulator, left: float, right: float, steps: int) -> list[Contact]:
    began: list[Contact] = []
    for _ in range(steps):
        sim.set_torques([left, right])
        began.extend(sim.step())
    return began


def planar(pose: list[float]) -> tuple[float, float, float]:
    return pose[0], pose[1], math.atan2(pose[6], pose[3])


@pytest.mark.parametrize(("left", "right"), [(1.0, 1.0), (-1.0, 1.0), (2.0, 1.0)])
def test_the_same_torques_move_the_robot_as_pybullet_does(left: float, right: float):
    world = load_world(None)
    with (
        Simulator(RobotConfig(), SimConfig(), world) as physics,
        KinematicSimulator(RobotConfig(), SimConfig(), world) as model,
    ):
        drive(physics, left, right, 1000)
        drive(model, left, right, 1000)
        x, y, theta = planar(physics.body_pose())
        mx, my, mtheta = planar(model.body_pose())
        assert math.hypot(mx - x, my - y) < 0.01, "within 1 cm after 1 s"
        assert mtheta == pytest.approx(theta, abs=0.01)
        assert model.wheel_angles() == pytest.approx(physics.wheel_angles(), rel=0.01, abs=0.01)
        assert model.body_pose()[2] == pytest.approx(physics.body_pose()[2], abs=1e-3), "axle height"


def test_a_robot_stops_against_the_box_with_one_bump_as_pybullet_s_begins():
    world = load_world("bump")
    with KinematicSimulator(RobotConfig(), SimConfig(), world) as sim:
        began = drive(sim, 3.0, 3.0, 1500)
        assert len(began) == 1 and began[0].robot == 0 and began[0].obstacle == "box", began
        assert (began[0].x, began[0].y) == pytest.approx((BOX_FACE_X, 0.0))
        x, y, _ = planar(sim.body_pose())
        assert 0.44 < x <= 0.45 and y == pytest.approx(0.0, abs=1e-9), "against the face, the body's radius away"
        assert sim.robots[0].plant.wheel_velocities == (0.0, 0.0)
        # backing off past the release time, then driving on again, is a new bump
        assert drive(sim, -3.0, -3.0, 200) == []
        assert drive(sim, 0.0, 0.0, 100) == []
        again = drive(sim, 3.0, 3.0, 1500)
        assert [contact.obstacle for contact in again] == ["box"]


def test_a_contact_within_the_release_time_is_the_same_bump():
    world = load_world("bump")
    with KinematicSimulator(RobotConfig(), SimConfig(), world) as sim:
        assert len(drive(sim, 3.0, 3.0, 1500)) == 1
        assert drive(sim, -1.0, -1.0, 5) == []  # 5 ms away: less than sim.bump_release (50 ms)
        assert drive(sim, 3.0, 3.0, 200) == []


def test_robots_of_a_fleet_bump_into_each_other_once_each_and_never_overlap():
    fleet = (
        Placement("rh0", RobotConfig(name="rh0"), InitialPose()),
        Placement("rh1", RobotConfig(name="rh1"), InitialPose(x=2.0, theta=math.pi)),
    )
    with KinematicSimulator(RobotConfig(), SimConfig(), load_world(None), fleet=fleet) as sim:
        began: list[Contact] = []
        for _ in range(3000):
            for robot in sim.robots:
                robot.set_torques([2.0, 2.0])
            began.extend(sim.step())
            gap = math.dist(sim.robots[0].body_pose()[:2], sim.robots[1].body_pose()[:2])
            assert gap >= 2 * sim.robots[0].reach
        assert sorted((c.robot, c.obstacle) for c in began) == [(0, "rh1"), (1, "rh0")]
        assert all(c.x == pytest.approx(1.0, abs=0.01) for c in began), "where they meet"


def test_cylinders_stop_the_robot_as_circles():
    world = parse_world('[[cylinders]]\nname = "post"\nx = 1.0\ny = 0.1\nradius = 0.1\nheight = 0.5\n')
    with KinematicSimulator(RobotConfig(), SimConfig(), world) as sim:
        began = drive(sim, 3.0, 3.0, 2000)
        assert [c.obstacle for c in began] == ["post"]
        x, y, _ = planar(sim.body_pose())
        assert math.hypot(1.0 - x, 0.1 - y) == pytest.approx(0.1 + sim.robots[0].reach, abs=0.002)


def test_shapes_measure_their_distance_and_nearest_point():
    box = Rectangle("box", 1.0, 0.0, math.pi / 2, 0.1, 0.5, 0.5)  # turned: 1.0 along x, 0.2 along y
    distance, point = box.nearest(1.0, 2.0)
    assert distance == pytest.approx(1.9) and point == pytest.approx((1.0, 0.1))
    assert box.nearest(2.0, 0.0)[0] == pytest.approx(0.5)
    assert box.nearest(1.0, 0.05)[0] == pytest.approx(-0.05), "inside: negative"
    post = Circle("post", 0.0, 0.0, 0.5, 1.0)
    distance, point = post.nearest(2.0, 0.0)
    assert distance == pytest.approx(1.5) and point == pytest.approx((0.5, 0.0))


@pytest.mark.parametrize("world_name", ["bump", "room"])
def test_the_lidar_sees_what_pybullet_s_sees(world_name: str):
    world = load_world(world_name)
    config = {"lidar": LidarConfig(), "imu": ImuConfig()}
    with (
        Simulator(RobotConfig(), SimConfig(), world, **config) as physics,
        KinematicSimulator(RobotConfig(), SimConfig(), world, **config) as model,
    ):
        expected, got = physics.robots[0].scan(Time(0, 0)), model.robots[0].scan(Time(0, 0))
        assert got.bodies == expected.bodies
        # a ray grazing a post's side may hit it in one engine and pass it in the other
        grazing = [ray for ray in range(len(got.hits)) if got.hits[ray] != expected.hits[ray]]
        assert len(grazing) <= 2, grazing
        for ray, (mine, theirs) in enumerate(zip(got.ranges, expected.ranges, strict=True)):
            if ray not in grazing:
                assert (mine is None) == (theirs is None)
                assert mine is None or mine == pytest.approx(theirs, abs=1e-4)
    if world_name == "bump":
        assert got.ranges[AHEAD] == pytest.approx(BOX_FACE_X)


def test_the_lidar_sees_cylinders_and_the_other_robots_where_they_are_now():
    lidar = LidarConfig()
    fleet = (
        Placement("rh0", RobotConfig(name="rh0"), InitialPose(), lidar),
        Placement("rh1", RobotConfig(name="rh1"), InitialPose(x=2.0, theta=math.pi), lidar),
    )
    with KinematicSimulator(RobotConfig(), SimConfig(), parse_world(POST_WORLD), fleet=fleet) as sim:
        first, second = (robot.scan(Time(0, 0)) for robot in sim.robots)
        assert first.bodies[first.hits[AHEAD + 90]] == "post" and first.ranges[AHEAD + 90] == pytest.approx(1.4)
        assert first.bodies[first.hits[AHEAD]] == "rh1" and first.ranges[AHEAD] == pytest.approx(1.55)
        assert second.bodies[second.hits[AHEAD]] == "rh0" and "rh1" not in second.bodies
        for _ in range(500):
            sim.robots[1].set_torques([5.0, 5.0])
            sim.step()
        moved = sim.robots[0].scan(Time(0, 0)).ranges[AHEAD]
        assert moved is not None and moved < 1.5


def test_the_imu_reads_the_plant_s_turn_and_gravity_level():
    with KinematicSimulator(RobotConfig(), SimConfig(), load_world(None), imu=ImuConfig()) as sim:
        drive(sim, -2.0, 2.0, 500)
        sample = sim.robots[0].imu_sample(Time(0, 500_000_000))
        assert sample.angular_velocity[2] == pytest.approx(sim.robots[0].plant.angular_velocity[2])
        assert sample.linear_acceleration[2] == pytest.approx(9.81)
        _, _, qz, qw = sample.orientation
        assert 2 * math.atan2(qz, qw) == pytest.approx(planar(sim.body_pose())[2])


def test_the_brakes_stop_the_wheels():
    with KinematicSimulator(RobotConfig(), SimConfig(), load_world(None)) as sim:
        drive(sim, 3.0, 3.0, 300)
        for _ in range(200):
            sim.robots[0].brake()
            sim.step()
        assert sim.robots[0].braking and sim.robots[0].plant.wheel_velocities == (0.0, 0.0)


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_the_kinematic_engine_s_modules_import_no_pybullet_even_indirectly():
    seen: set[str] = set()
    todo = ["sim_bridge.kinematic"]
    while todo:
        module = todo.pop()
        if module in seen:
            continue
        seen.add(module)
        path = REPO / (module.replace(".", "/") + ".py")
        if not path.is_file():
            path = REPO / module.replace(".", "/") / "__init__.py"
        if path.is_file():
            todo.extend(name for name in _imports(path) if name.split(".")[0] in ("schemas", "services", "sim_bridge"))
            assert not any(name.split(".")[0] == "pybullet" for name in _imports(path)), module
    assert "sim_bridge.kinematic_model" in seen and "sim_bridge.simulator" not in seen


def test_invent_sim_runs_the_kinematic_engine_where_pybullet_cannot_be_imported():
    code = (
        "import sys; sys.modules['pybullet'] = None\nfrom services.cli.main import main\nsys.exit(main(sys.argv[1:]))\n"
    )
    flags = ["sim", "--engine", "kinematic", "--world", "bump", "--duration", "0.2"]
    listen = ["--listen", f"tcp/127.0.0.1:{free_port()}"]
    result = subprocess.run(
        [sys.executable, "-c", code, *flags, *listen], check=False, cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "on the kinematic engine" in result.stderr and "200 steps" in result.stderr, result.stderr[-3000:]


@pytest.mark.parametrize("command", ["sim", "control", "up"])
def test_gui_with_the_kinematic_engine_exits_2_naming_the_flag_before_anything_starts(
    capsys: pytest.CaptureFixture[str], command: str
):
    code, _out, err = refused(capsys, command, "--engine", "kinematic", "--gui")
    assert code == ExitStatus.CONFIG == 2, err
    assert "--gui" in err and "kinematic" in err, err


def test_the_engine_flag_sets_sim_engine_and_set_does_too():
    from services.cli.main import build_parser
    from services.cli.sim import overrides

    args = build_parser().parse_args(["sim", "--engine", "kinematic"])
    assert overrides(args)["sim.engine"] == "kinematic"
    assert load_config(None, {"sim.engine": "kinematic"}).sim.engine == SimEngine.KINEMATIC
    assert SimConfig().engine == SimEngine.PYBULLET


def follow(sim: KinematicSimulator | Simulator, left: float, right: float, steps: int) -> None:
    for _ in range(steps):
        sim.robots[0].set_wheel_velocities([left, right])
        sim.step()


@pytest.mark.parametrize(("left", "right"), [(3.0, 3.0), (-2.0, 2.0), (4.0, 2.0)])
def test_both_engines_follow_wheel_speed_targets_alike(left: float, right: float):
    """The velocity seam (``motor.output = "velocity"``): PyBullet's velocity motors and the kinematic
    plant's loop bring the wheels to the targets, within the torque limit, and move the robot alike."""
    world = load_world(None)
    with (
        Simulator(RobotConfig(), SimConfig(), world) as physics,
        KinematicSimulator(RobotConfig(), SimConfig(), world) as model,
    ):
        follow(physics, left, right, 1000)
        follow(model, left, right, 1000)
        assert model.robots[0].plant.wheel_velocities == (left, right), "the plant reaches its targets exactly"
        x, y, theta = planar(physics.body_pose())
        mx, my, mtheta = planar(model.body_pose())
        assert math.hypot(mx - x, my - y) < 0.01, "within 1 cm after 1 s"
        assert mtheta == pytest.approx(theta, abs=0.02), "PyBullet's wheels slip a little on the turn"
        for sim in (physics, model):
            robot = sim.robots[0]
            assert all(abs(torque) <= SimConfig().max_wheel_torque for torque in robot.applied_torques)


def test_pybullets_velocity_motors_report_the_torque_they_applied_at_most_the_limit():
    with Simulator(RobotConfig(), SimConfig(), load_world(None)) as sim:
        follow(sim, 50.0, -50.0, 1)
        sim.wheel_angles()  # read with the joints' state
        limit = SimConfig().max_wheel_torque
        assert sim.robots[0].applied_torques == pytest.approx([limit, -limit])


def test_a_target_beyond_the_torque_limit_is_approached_at_the_limit_and_torques_take_over_again():
    with KinematicSimulator(RobotConfig(), SimConfig(), load_world(None)) as sim:
        robot = sim.robots[0]
        follow(sim, 50.0, 50.0, 1)
        limit = SimConfig().max_wheel_torque
        assert robot.applied_torques == [limit, limit] and 0.0 < robot.plant.wheel_velocities[0] < 50.0
        speed = robot.plant.wheel_velocities[0]
        drive(sim, 0.0, 0.0, 10)
        assert robot.velocity_targets is None and robot.plant.wheel_velocities[0] == pytest.approx(speed), "coasting"


def test_wheel_speed_targets_of_the_wrong_length_are_bad_input():
    with KinematicSimulator(RobotConfig(), SimConfig(), load_world(None)) as sim, pytest.raises(BadInput):
        sim.robots[0].set_wheel_velocities([1.0, 1.0, 1.0])
