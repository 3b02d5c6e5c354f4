"""The loop's sections of the robot description: the robot, its motor control, odometry, sim,
localization, drive and the bounds of plausible input.

Defaults are the seeds' (docs/protocol.md section 3); every default lives here or in
:mod:`services.config.run_sections` and nowhere else. Each field's unit is in its type and its
meaning in the docstring under it: both are rendered into docs/configuration.md.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Annotated, Literal, NamedTuple

import msgspec

from schemas.keys import DEFAULT_ROBOT, validate_robot_name
from schemas.messages import NANOSECONDS_PER_SECOND
from services.config.fields import (
    D_GAIN,
    KILOGRAMS,
    METRES,
    METRES_PER_SECOND,
    METRES_PER_SECOND_CUBED,
    METRES_PER_SECOND_SQUARED,
    NEWTON_METRES,
    P_GAIN,
    PER_SIMULATED_SECOND,
    RADIANS,
    RADIANS_PER_SECOND,
    RADIANS_PER_SECOND_CUBED,
    RADIANS_PER_SECOND_SQUARED,
    SIMULATED_SECONDS,
    STEPS,
    WALL_SECONDS,
    NonNegative,
    Positive,
    Section,
    WheelId,
)


class RobotConfig(Section, frozen=True):
    """The robot's name and geometry, shared by every service (the seeds repeated them in each ``.conf``)."""

    name: str = DEFAULT_ROBOT
    """The robot's name (by default the seed's ``bridge.sh`` name), one key chunk: every key is under
    ``invent/<name>/``; ``--robot NAME`` overrides it."""
    left_wheel_id: WheelId = 0
    """Index of the left wheel in the wheel-angle and torque vectors."""
    right_wheel_id: WheelId = 1
    """Index of the right wheel in the wheel-angle and torque vectors; differs from the left's."""
    radius_of_left_wheel: Annotated[Positive, METRES] = 0.1
    """Radius of the left drive wheel."""
    radius_of_right_wheel: Annotated[Positive, METRES] = 0.1
    """Radius of the right drive wheel."""
    length_of_axle: Annotated[Positive, METRES] = 0.441
    """Distance between the two drive wheels' contact points."""
    radius_of_body_area: Annotated[Positive, METRES] = 0.45
    """Radius of the robot's round body, as simulated and drawn."""

    def __post_init__(self) -> None:
        super().__post_init__()
        validate_robot_name(self.name)
        if self.left_wheel_id == self.right_wheel_id:
            raise ValueError("`right_wheel_id` must differ from `left_wheel_id`")

    @property
    def half_axle(self) -> float:
        return self.length_of_axle / 2.0


class TargetAngleMode(StrEnum):
    """How the motor control forms its target wheel angle (``motor.target_angle``)."""

    SEED = "seed"
    INTEGRATED = "integrated"


MotorOutput = Literal["torque", "velocity"]
"""What the motor sends the plant (``motor.output``): wheel torques or wheel speed targets."""


class MotorConfig(Section, frozen=True):
    """The motor control: its output, PD gains, the simulated model's offsets, the command timeout and limits."""

    output: MotorOutput = "torque"
    """What answers each wheel-angle sample: ``torque``, the PD law's wheel torques on
    ``motor/torque``; ``velocity``, wheel speed targets (rad/s) on ``motor/wheel_velocity`` that the
    plant's own velocity loop follows (ODrive's velocity mode, RoboClaw speed commands; docs/plant.md)."""
    velocity_rate: Annotated[Positive, PER_SIMULATED_SECOND] = 100.0
    """With ``output = "velocity"``: how often the wheel speed targets change, on the wheel-angle
    time (a plant's velocity loop takes new targets at 50 to 100 Hz); between two, the last is sent
    again. A stop or a finish sends zero at once; a command timeout brakes through the limits, as with
    torques."""

    p_gain_l: Annotated[NonNegative, P_GAIN] = 5.0
    """P gain of the left wheel; changeable at run time with set_pd_gain."""
    p_gain_r: Annotated[NonNegative, P_GAIN] = 5.0
    """P gain of the right wheel."""
    d_gain_l: Annotated[NonNegative, D_GAIN] = 2.0
    """D gain of the left wheel."""
    d_gain_r: Annotated[NonNegative, D_GAIN] = 2.0
    """D gain of the right wheel."""
    simulated_offset_x: Annotated[float, METRES] = 0.0
    """Model origin -> axle centre along the model's x; locked at start."""
    simulated_offset_y: Annotated[float, METRES] = 0.0
    """Model origin -> axle centre along the model's y (RH0: 0.045795)."""
    simulated_offset_angle: Annotated[float, RADIANS] = 0.0
    """Heading of the model's zero direction from +x (RH0: 1.5708)."""
    command_timeout: Annotated[NonNegative, SIMULATED_SECONDS] = 0.5
    """Wheel-angle time without a target velocity before braking to zero; 0 disables."""
    target_angle: TargetAngleMode = TargetAngleMode.SEED
    """How the target wheel angle is formed: ``seed``, q_ref restarts from the measured angle each
    cycle (docs/protocol.md section 4 step 3); ``integrated``, q_ref accumulates from the previous
    target angle, so the P term corrects drift (docs/motor.md)."""
    max_vx: Annotated[Positive, METRES_PER_SECOND] | None = 1.0
    """Limit on |vx| (as ros2's diff_drive_controller users expect; its ``linear.x.max_velocity``),
    backward too unless ``max_vx_reverse`` says otherwise; None (``"none"`` in a file or ``--set``)
    = no velocity limit, the seed's behaviour. The defaults fit the default robot and sit above
    what the drive commands. Every limit is a magnitude (docs/motor.md maps them to
    diff_drive_controller's signed parameters)."""
    max_vx_reverse: Annotated[Positive, METRES_PER_SECOND] | None = None
    """Limit on backward speed (−vx; ``linear.x.min_velocity``); None = ``max_vx``. Needs ``max_vx``."""
    max_ax: Annotated[Positive, METRES_PER_SECOND_SQUARED] | None = 2.0
    """Limit on how fast vx rises from rest or while forward (``linear.x.max_acceleration``; a step
    in wheel speed slips: docs/motor.md), and every rate of change of vx not set apart below; None
    = no acceleration limit."""
    max_ax_reverse: Annotated[Positive, METRES_PER_SECOND_SQUARED] | None = None
    """Limit on how fast vx falls from rest or while backward: speeding up backward
    (``linear.x.max_acceleration_reverse``); None = ``max_ax``. Needs ``max_ax``."""
    max_decel_x: Annotated[Positive, METRES_PER_SECOND_SQUARED] | None = None
    """Limit on how fast vx falls while forward: slowing down forward (``linear.x.max_deceleration``);
    None = ``max_ax_reverse`` (as upstream's RateLimiter resolves it). Needs ``max_ax``."""
    max_decel_x_reverse: Annotated[Positive, METRES_PER_SECOND_SQUARED] | None = None
    """Limit on how fast vx rises while backward: slowing down backward
    (``linear.x.max_deceleration_reverse``); None = ``max_ax``. Needs ``max_ax``."""
    max_jerk_x: Annotated[Positive, METRES_PER_SECOND_CUBED] | None = None
    """Limit on how fast vx's rate of rise grows while vx rises (``linear.x.max_jerk``), applied only
    while that rate grows, as upstream; None = no jerk limit."""
    max_jerk_x_falling: Annotated[Positive, METRES_PER_SECOND_CUBED] | None = None
    """Limit on how fast vx's rate of fall grows while vx falls (``linear.x.min_jerk``); None =
    ``max_jerk_x``. Needs ``max_jerk_x``."""
    max_w: Annotated[Positive, RADIANS_PER_SECOND] | None = 3.0
    """Limit on |w| (``angular.z.max_velocity``), clockwise too unless ``max_w_reverse`` says otherwise."""
    max_w_reverse: Annotated[Positive, RADIANS_PER_SECOND] | None = None
    """Limit on clockwise turning (−w; ``angular.z.min_velocity``); None = ``max_w``. Needs ``max_w``."""
    max_aw: Annotated[Positive, RADIANS_PER_SECOND_SQUARED] | None = 8.0
    """Limit on how fast w rises from rest or while counter-clockwise (``angular.z.max_acceleration``),
    and every rate of change of w not set apart below; None = no angular acceleration limit."""
    max_aw_reverse: Annotated[Positive, RADIANS_PER_SECOND_SQUARED] | None = None
    """Limit on how fast w falls from rest or while clockwise (``angular.z.max_acceleration_reverse``);
    None = ``max_aw``. Needs ``max_aw``."""
    max_decel_w: Annotated[Positive, RADIANS_PER_SECOND_SQUARED] | None = None
    """Limit on how fast w falls while counter-clockwise (``angular.z.max_deceleration``); None =
    ``max_aw_reverse``. Needs ``max_aw``."""
    max_decel_w_reverse: Annotated[Positive, RADIANS_PER_SECOND_SQUARED] | None = None
    """Limit on how fast w rises while clockwise (``angular.z.max_deceleration_reverse``); None =
    ``max_aw``. Needs ``max_aw``."""
    max_jerk_w: Annotated[Positive, RADIANS_PER_SECOND_CUBED] | None = None
    """Limit on how fast w's rate of rise grows while w rises (``angular.z.max_jerk``); None = no
    angular jerk limit."""
    max_jerk_w_falling: Annotated[Positive, RADIANS_PER_SECOND_CUBED] | None = None
    """Limit on how fast w's rate of fall grows while w falls (``angular.z.min_jerk``); None =
    ``max_jerk_w``. Needs ``max_jerk_w``."""

    def __post_init__(self) -> None:
        super().__post_init__()
        # Upstream ignores a limit set beside a base left NaN; a setting that does nothing is refused here.
        for base, dependents in LIMIT_BASES.items():
            if getattr(self, base) is None:
                for name in dependents:
                    if getattr(self, name) is not None:
                        raise ValueError(f"`{name}` needs `{base}`, which is none")


LIMIT_BASES = {
    "max_vx": ("max_vx_reverse",),
    "max_ax": ("max_ax_reverse", "max_decel_x", "max_decel_x_reverse"),
    "max_jerk_x": ("max_jerk_x_falling",),
    "max_w": ("max_w_reverse",),
    "max_aw": ("max_aw_reverse", "max_decel_w", "max_decel_w_reverse"),
    "max_jerk_w": ("max_jerk_w_falling",),
}
"""``[motor]``'s limits that take effect only beside another (their base)."""


class StartPose(Section, frozen=True):
    """The pose a service takes the robot to be at before its first fix (the odometry's and the
    localization's are set together: a fleet sets both to each robot's start)."""

    initial_x: Annotated[float, METRES] = 0.0
    """x of the pose the service starts from, before its first fix (a fleet sets it to the robot's start)."""
    initial_y: Annotated[float, METRES] = 0.0
    """y of the starting pose."""
    initial_theta: Annotated[float, RADIANS] = 0.0
    """Heading of the starting pose."""


StraightStep = Literal["exact", "seed"]
"""How the odometry's straight and rho_border branches take ΔL (``odometry.straight_step``)."""


class OdometryConfig(StartPose, frozen=True):
    """Odometry: the starting pose, the integration's borders and the calibration multipliers."""

    rotation_angle_border: Annotated[Positive, RADIANS] = math.pi / 180.0
    """|dphi| below which a step takes arc length for chord (π/180)."""
    rho_border: Annotated[Positive, METRES] = 10000.0
    """|rho| above which a step integrates as straight, rho clamped."""
    left_radius_scale: Positive = 1.0
    """Calibration multiplier on the left wheel radius (docs/protocol.md section 9.6: 1.0 = no calibration)."""
    right_radius_scale: Positive = 1.0
    """Calibration multiplier on the right wheel radius (1.0 = no calibration)."""
    axle_scale: Positive = 1.0
    """Calibration multiplier on the axle length (1.0 = no calibration)."""
    straight_step: StraightStep = "exact"
    """ΔL of the straight and rho_border branches: ``exact``, the step's own mean wheel travel
    (r_L·Δq_L + r_R·Δq_R)/2; ``seed``, the seed's trapezoid (V + V_old)/2·Δt (docs/odometry.md)."""


class CalibratedGeometry(NamedTuple):
    """The lengths the odometry integrates with and the motor turns body velocities into wheel
    speeds with: the robot's, times the calibration multipliers of ``[odometry]`` (as ROS 2's
    diff_drive_controller applies its multipliers to both; docs/odometry.md, Calibration)."""

    left_radius: float
    """r_L: the configured radius times its calibration multiplier."""
    right_radius: float
    half_axle: float
    """b = calibrated axle length / 2."""

    @classmethod
    def of(cls, robot: RobotConfig, odometry: OdometryConfig) -> CalibratedGeometry:
        return cls(
            robot.radius_of_left_wheel * odometry.left_radius_scale,
            robot.radius_of_right_wheel * odometry.right_radius_scale,
            robot.length_of_axle * odometry.axle_scale / 2.0,
        )


class SimMode(StrEnum):
    """How the simulator steps (``sim.mode``)."""

    LOCKSTEP = "lockstep"
    REALTIME = "realtime"


class SimEngine(StrEnum):
    """What computes the simulated robot's motion (``sim.engine``)."""

    PYBULLET = "pybullet"
    KINEMATIC = "kinematic"


class SimConfig(Section, frozen=True):
    """The simulator: how it steps, the world, the robot's body and its motor driver."""

    engine: SimEngine = SimEngine.PYBULLET
    """``pybullet``: rigid-body physics (contacts, friction, slip); ``kinematic``: each wheel a motor
    turning the robot's inertia, ideal rolling, bumps by geometry, no PyBullet needed (docs/sim.md,
    "Engines")."""
    mode: SimMode = SimMode.LOCKSTEP
    """``lockstep``: every step waits for its torque; ``realtime``: steps paced to the wall clock
    (docs/protocol.md section 6). Every service reads it: in lockstep its publishers wait for room
    rather than drop a sample (protocol section 2.6); ``invent up`` gives every child its run's."""
    step: Annotated[Positive, SIMULATED_SECONDS] = 0.001
    """Simulation time of one physics step."""
    observe_every: Annotated[int, msgspec.Meta(ge=1), STEPS] = 20
    """Steps between two observed steps, beside every lockstep participant's tick: the steps at
    which what is observed rather than controlled goes out (``sim/clock``, ``sim/body_pose``,
    the motor's simulated poses, ``odometry/pose``; docs/protocol.md section 2.7). 1 = every
    step, the seeds' every-cycle behaviour. A recorded run records every step all the same."""
    lockstep_timeout: Annotated[Positive, WALL_SECONDS] = 0.5
    """Lockstep: every how long a step that still waits for its torque, or for a participant's
    output at its tick, says so (``long_waits``): it waits on for as long as the motor control's or
    the participant's liveliness token lives (the drive waits so for a tick's pose). How long the
    particle filter waits for a tick's scan, and the drive for a pose from an odometry that came
    back mid-run, at most."""
    realtime_factor: Positive = 1.0
    """Realtime mode: simulated seconds per wall second."""
    torque_max_age: Annotated[Positive, SIMULATED_SECONDS] = 0.01
    """Realtime mode: the age after which the newest torque is stale (zero is applied)."""
    brake_after: Annotated[Positive, SIMULATED_SECONDS] | None = 0.5
    """How long without a torque from the robot's motor control (gone, silent, or cut off by a link
    down) before the simulated motor driver brakes the wheels (to rest, at most
    ``max_wheel_torque``) until a torque comes again, as a driver's watchdog does; the default is
    the motor's own ``command_timeout``. None (``"none"``): the wheels run free on zero torque."""
    world: str | None = None
    """World file (TOML) or built-in world name (sim_bridge/worlds/); None (``"none"``) = an empty floor."""
    body_mass: Annotated[Positive, KILOGRAMS] = 20.0
    """The body's mass; its centre of mass sits on the axle centre."""
    body_height: Annotated[Positive, METRES] = 0.15
    """The body is a cylinder of radius robot.radius_of_body_area whose bottom is at axle height."""
    wheel_mass: Annotated[Positive, KILOGRAMS] = 1.0
    """Mass of each drive wheel."""
    wheel_width: Annotated[Positive, METRES] = 0.04
    """Width of each drive wheel."""
    caster_mass: Annotated[Positive, KILOGRAMS] = 0.5
    """Mass of each of the two frictionless casters (front and rear)."""
    max_wheel_torque: Annotated[Positive, NEWTON_METRES] = 20.0
    """Motor torque limit; commanded torques are saturated to ±this."""
    wheel_friction: Positive = 1.0
    """Lateral friction coefficient of the drive wheels."""
    bump_release: Annotated[Positive, SIMULATED_SECONDS] = 0.05
    """How long without contact before touching the same obstacle again is a new bump."""


LocalizationMode = Literal["stub", "amcl", "none"]
"""``localization.mode``: the seeds' stub (the simulator's pose, plus noise), a particle filter on the
map from the lidar and the wheels (``[amcl]``), or no fixes after the start (odometry alone)."""


class LocalizationConfig(StartPose, frozen=True):
    """The localization (docs/localization.md): where the robot starts, how it is localized, how
    often a fix is published and, for the stub, its noise."""

    mode: LocalizationMode = "stub"
    """``stub``: the simulator's ground truth plus noise (the seeds'); ``amcl``: a particle filter on
    the map of ``navigation.map`` from the lidar's scans and the wheel angles, reading no ground
    truth (``[amcl]``); ``none``: the initial pose once, then no fix (the odometry alone, drifting)."""
    rate: Annotated[Positive, PER_SIMULATED_SECOND] = 1.0
    """Fixes per second of simulation time."""
    noise_x: Annotated[NonNegative, METRES] = 0.0
    """Standard deviation of the Gaussian noise added to a fix's x (0 = exact)."""
    noise_y: Annotated[NonNegative, METRES] = 0.0
    """Standard deviation of the noise on y."""
    noise_theta: Annotated[NonNegative, RADIANS] = 0.0
    """Standard deviation of the noise on theta."""
    seed: Annotated[int, msgspec.Meta(ge=0)] | None = None
    """Random seed for the noise (the stub's) or the particles (amcl's); None (``"none"``) draws one
    from the OS (shown in status)."""
    particles_rate: Annotated[NonNegative, PER_SIMULATED_SECOND] = 1.0
    """How often ``amcl`` publishes its particles (``localization/particles``), per simulated second;
    0: never."""

    @property
    def participates(self) -> bool:
        """Whether it takes part in lockstep (a fix at every tick): every mode but ``none``."""
        return self.mode != "none"


class DriveConfig(Section, frozen=True):
    """The drive: its rate, the path follower's speeds and limits, and when it gives a scenario up."""

    rate: Annotated[Positive, PER_SIMULATED_SECOND] = 50.0
    """Target velocities per second of simulation time."""
    cruise_speed: Annotated[Positive, METRES_PER_SECOND] = 0.3
    """Path follower forward speed."""
    max_turn_rate: Annotated[Positive, RADIANS_PER_SECOND] = 1.0
    """Path follower turn rate limit."""
    lookahead: Annotated[Positive, METRES] = 0.25
    """Pure pursuit lookahead distance."""
    goal_tolerance: Annotated[Positive, METRES] = 0.02
    """Distance at which a waypoint counts as reached (passing it along the path counts too)."""
    turn_in_place_angle: Annotated[Positive, RADIANS] = math.radians(45.0)
    """Heading error above which the follower stops and turns in place (also: a corner sharper
    than this is a stop); 45°."""
    heading_tolerance: Annotated[Positive, RADIANS] = math.radians(2.0)
    """Heading error below which a turn in place ends and the follower drives on; 2°."""
    max_acceleration: Annotated[Positive, METRES_PER_SECOND_SQUARED] = 0.5
    """Path follower limit on the rate of change of vx (a step in wheel speed slips)."""
    max_angular_acceleration: Annotated[Positive, RADIANS_PER_SECOND_SQUARED] = 2.0
    """Path follower limit on the rate of change of w."""
    pose_timeout: Annotated[Positive, SIMULATED_SECONDS] = 0.5
    """Age after which an odometry pose is too old to follow a path on: the drive then commands
    zero until a fresh one arrives."""
    give_up_after_stop: Annotated[Positive, SIMULATED_SECONDS] | None = 2.0
    """How long the motor may stay latched stopped (a bump, an emergency stop), or held by its
    collision monitor (``motor/state``'s ``held_by``), before the drive gives its scenario up
    (``aborted``); None (``"none"``): it waits for a ``clear``, or a clear way, for ever."""
    time_limit_factor: Positive | None = 3.0
    """A pass of a scenario lasting longer than this many times its planned duration, plus
    ``time_limit_margin``, is given up (``timed_out``), unless the scenario sets its own
    ``time_limit``; None (``"none"``): only a scenario's own limit applies."""
    time_limit_margin: Annotated[NonNegative, SIMULATED_SECONDS] = 10.0
    """Added to the time limit a scenario gets from ``time_limit_factor``."""


class GoalsConfig(Section, frozen=True):
    """Goals sent to a running drive (``invent drive --goals``, ``invent goto``, ROS 2's
    NavigateToPose): what a goal that says nothing more is held to, and how often its progress goes out."""

    position_tolerance: Annotated[Positive, METRES] = 0.05
    """How close to the goal's position the robot must end (odometry's pose) for ``completed``."""
    heading_tolerance: Annotated[Positive, RADIANS] = 0.1
    """How close to the goal's heading the robot must end, when the goal gives one."""
    feedback_rate: Annotated[Positive, PER_SIMULATED_SECOND] = 5.0
    """``drive/goal/feedback`` messages per second of simulation time while a goal runs."""
    max_distance: Annotated[Positive, METRES] = 100.0
    """A goal further than this from the robot is rejected (an absurd pose, not a goal)."""


class InputConfig(Section, frozen=True):
    """What every service accepts as plausible input (docs/input.md). Outside these bounds a
    well-formed sample is bad input: dropped, counted, and its stamp never moves a time base."""

    stamp_horizon: Annotated[Positive, SIMULATED_SECONDS] = 1.0
    """How far a stamp may run ahead of the time base it is checked against (the previous sample
    of the same stream, or the wheel-angle time for targets and fixes)."""
    max_wheel_speed: Annotated[Positive, RADIANS_PER_SECOND] = 50.0
    """A wheel-angle step, or a target velocity, implying a faster wheel is implausible (the
    default robot's top speed, 1 m/s at the motor's default limits, is 10 rad/s)."""
    max_gain: Positive = 1000.0
    """Ceiling on each PD gain (in its own unit), from the configuration or set_pd_gain."""
    max_coordinate: Annotated[Positive, METRES] = 10_000.0
    """A pose (localization fix, odometry pose, simulated pose) further than this from the origin
    on either axis is implausible."""

    @property
    def stamp_horizon_ns(self) -> int:
        """``stamp_horizon`` in the integer nanoseconds stamps are compared in."""
        return round(self.stamp_horizon * NANOSECONDS_PER_SECOND)
