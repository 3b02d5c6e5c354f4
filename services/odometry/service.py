"""``invent odometry``: the OdometryRTC port (docs/protocol.md section 5), a thin shell around services/odometry/core.py.

Subscribes ``motor/wheel_angles`` and ``localization/pose``; integrates every accepted sample and
publishes ``odometry/pose`` (with the ``tm`` of the wheel-angle sample) for those of observed
steps (their mark says so, docs/protocol.md section 2.7), for every sample without a mark (a
replayed or hand-made stream), and for every sample in a recorded run. A localized pose overwrites the pose the next step starts from,
and so does a pose set at runtime on the queryable ``odometry/set_pose`` (diff_drive_controller's
``set_odometry``, applied at its stamp as a fix is). ``--trace FILE`` writes one JSON
line per accepted wheel-angle sample (docs/odometry.md describes the fields). When the
simulator's liveliness token appears and the next wheel-angle sample is not after the last one,
that sample starts a new time base (the stamps are the simulator's, and a restarted simulator's
clock starts again at 0; a reconnected one's goes on, and costs nothing): services/clock/sim_watch.py.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import msgspec

from schemas.codec import BadInput, BadMessage, decode
from schemas.keys import Service
from schemas.messages import SetOdometry, SetOdometryReply, Time, TimedDoubleSeq, TimedPosition
from schemas.status import LockstepHolds, OdometryCounters, OdometryStatus, OdometryVelocity, PlanarPose, PoseSet
from schemas.topics import Topic
from services.clock.lockstep import Hold, observed
from services.clock.sim_time import ClockRestart
from services.clock.sim_watch import HeldSample, SimulatorWatch
from services.config import Config
from services.odometry.core import FIX_HISTORY_STEPS, Branch, Odometry
from services.planar import Pose
from services.runtime.inputs import Delivery
from services.runtime.node import Node
from services.service import ServiceCommand, TraceFile

STATE_IDLE = "idle"
"""No wheel angles seen yet: the pose is the starting (or localized) pose."""
STATE_RUNNING = "running"


@dataclass(frozen=True)
class OdometryOptions:
    """``invent odometry``'s own options beside the robot description."""

    trace: str | None = None
    """``--trace FILE``: one JSON line per accepted wheel-angle sample (docs/odometry.md)."""


class OdometryService:
    finished = False
    """It serves until stopped."""
    exit_code = 0

    def __init__(self, node: Node, config: Config, options: OdometryOptions) -> None:
        self.node = node
        odometry = config.odometry
        start = Pose(odometry.initial_x, odometry.initial_y, odometry.initial_theta)
        self.odometry = Odometry(config.robot, odometry, start=start, limits=config.input)
        self.samples = 0
        self.localization_resets = 0
        self.pose_sets = 0
        self.last_pose_set: PoseSet | None = None
        self.sim = SimulatorWatch(node, ClockRestart(config.input.stamp_horizon_ns))
        self.branches = dict.fromkeys(Branch, 0)
        self.last_tm: Time | None = None
        # Lockstep: a wheel-angle sample waits for the localization's fix it is owed (the sim took it).
        self.fix_hold: Hold[HeldSample] = Hold(
            Topic.LOCALIZATION_POSE,
            self._integrate,
            capacity=FIX_HISTORY_STEPS,
            guard=partial(node.guard, node.keys.motor_wheel_angles),
        )
        self._trace = TraceFile.from_flag(options.trace)
        self._pose = node.publisher(node.keys.odometry_pose)
        node.subscribe(
            node.keys.motor_wheel_angles,
            TimedDoubleSeq,
            self.sim.held_clock(self.fix_hold, self.odometry, "pose kept"),
            Delivery.EVERY,
            wakes=True,
            with_attachment=True,
        )
        node.subscribe(
            node.keys.localization_pose,
            TimedPosition,
            self.sim.stamped(
                node.keys.localization_pose, self._on_localized_pose, awaited=lambda: self.fix_hold.holding
            ),
            Delivery.QUEUED,
        )
        node.queryable(node.keys.odometry_set_pose, self._on_set_pose, mutates=True)
        node.set_status(self.status)

    def _integrate(self, held: HeldSample) -> None:
        sample, _attachment, mark, stamp_ns = held
        step = self.odometry.step(stamp_ns, sample.data)
        self.samples += 1
        self.branches[step.branch] += 1
        self.last_tm = sample.tm
        if self._trace is not None:
            self._trace.write({"tm": sample.tm, **step._asdict(), "localization_resets": self.localization_resets})
        if self.node.recording_every_step or observed(mark):
            self._pose.put(TimedPosition(tm=sample.tm, id=[], x=step.x, y=step.y, theta=step.theta, error=[]))

    def _on_localized_pose(self, pose: TimedPosition) -> None:
        stamp_ns = pose.tm.to_nanoseconds()
        self.odometry.reset_at(stamp_ns, pose.x, pose.y, pose.theta)
        self.localization_resets += 1
        self.fix_hold.took(stamp_ns)

    def _on_set_pose(self, payload: bytes) -> SetOdometryReply:
        """``odometry/set_pose``: the pose set at its stamp (or the last sample's), as a fix is."""
        try:
            request = decode(SetOdometry, payload)
            stamp_ns = None if request.tm is None else request.tm.to_nanoseconds()
            applied_ns = self.odometry.set_pose(request.x, request.y, request.theta, stamp_ns)
        except BadInput as error:
            self.node.bad_inputs.record(self.node.keys.odometry_set_pose, str(error))
            kind = "not a SetOdometry" if isinstance(error, BadMessage) else "refused"
            return SetOdometryReply(False, f"{kind}: {error}")
        self.pose_sets += 1
        tm = None if applied_ns is None else Time.from_nanoseconds(applied_ns)
        self.last_pose_set = PoseSet(request.x, request.y, request.theta, tm)
        when = "as the starting pose" if tm is None else f"at {tm.to_seconds():.3f} s"
        self.node.log.info("pose set to (%g, %g, %g) %s", request.x, request.y, request.theta, when)
        return SetOdometryReply(True, tm=tm)

    def status(self) -> OdometryStatus:
        pose = self.odometry.pose
        v, omega = self.odometry.velocity
        odometry = self.odometry
        return OdometryStatus(
            state=STATE_RUNNING if self.odometry.initialised else STATE_IDLE,
            sim_alive=self.sim.alive,
            pose=PlanarPose(pose.x, pose.y, pose.theta),
            velocity=OdometryVelocity(v, omega),
            last_wheel_angles_tm=self.last_tm,
            last_pose_set=self.last_pose_set,
            counters=OdometryCounters(
                wheel_angle_samples=self.samples,
                localization_resets=self.localization_resets,
                pose_sets=self.pose_sets,
                time_base_restarts=self.sim.restart.restarts,
                lockstep_holds=LockstepHolds(self.fix_hold.holds, self.fix_hold.overflows),
                branches={str(branch): count for branch, count in self.branches.items()},
            ),
            parameters={
                "left_wheel_id": odometry.robot.left_wheel_id,
                "right_wheel_id": odometry.robot.right_wheel_id,
                "radius_of_left_wheel": odometry.robot.radius_of_left_wheel,
                "radius_of_right_wheel": odometry.robot.radius_of_right_wheel,
                "length_of_axle": odometry.robot.length_of_axle,
                **msgspec.structs.asdict(odometry.config),
                **odometry.geometry._asdict(),
            },
        )

    def close(self) -> None:
        if self._trace is not None:
            self._trace.close()


COMMAND = ServiceCommand(service=Service.ODOMETRY, factory=OdometryService)
