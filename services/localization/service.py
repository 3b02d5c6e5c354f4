"""``invent localization``: the localization in its three modes (``localization.mode``,
docs/localization.md): the stub (here), the particle filter (:mod:`services.localization.amcl_shell`),
and none (here: the initial pose once, then nothing).

The stub (the seed's LocalizationRTC, docs/protocol.md section 7) subscribes
``motor/sim_pose/localization`` ([x, y, z, θ] stamped with simulation time) and publishes
``localization/pose``: first the configured initial pose, stamped with the first simulation time
seen once someone (odometry) subscribes, then every 1/rate seconds of simulation time the latest simulated pose plus optional Gaussian noise
(:mod:`services.localization.core`). Odometry resets its pose on every fix. When the
simulator's liveliness token appears and the next stamp is not after the last one (a restarted
simulator's clock starts again at 0), that sample starts a new time base and takes a fix at once.

The simulated pose is sampled (:attr:`~services.runtime.inputs.Delivery.SAMPLED`): a fix is always the
newest pose, never one from a backlog, which odometry would take for the present. The motor puts
it at the simulator's observed steps only (docs/protocol.md section 2.7), each of the
localization's ticks among them (its ticks token asks for them); the thread waits in its receive,
never polls.
"""

from __future__ import annotations

from schemas.keys import Service
from schemas.messages import NANOSECONDS_PER_SECOND, Time, TimedDoubleSeq, TimedPosition
from schemas.status import LocalizationFix, LocalizationStatus, PlanarPose
from services.clock.sim_watch import SimulatorWatch
from services.config import Config
from services.localization.amcl_shell import AmclLocalization
from services.localization.core import Fix, Localizer, resolve_seed
from services.planar import Pose
from services.runtime.inputs import Delivery
from services.runtime.node import Node, Wait
from services.service import NoOptions, ServiceCommand


def _fix_status(fix: Fix | None) -> LocalizationFix | None:
    if fix is None:
        return None
    return LocalizationFix(fix.stamp_ns / NANOSECONDS_PER_SECOND, *fix.pose, initial=fix.initial)


class StubLocalization:
    finished = False
    """It serves until stopped."""
    exit_code = 0

    def __init__(self, node: Node, config: Config, _options: NoOptions) -> None:
        self.node = node
        self.config = config.localization
        self.seed = resolve_seed(self.config.seed)
        self.localizer = Localizer.from_config(config, self.seed)
        self.publisher = node.publisher(node.keys.localization_pose)
        node.participate(self.publisher, self.config.rate)
        sim_pose = node.subscribe(
            node.keys.motor_sim_pose_localization, TimedDoubleSeq, self._on_sim_pose, Delivery.SAMPLED
        )
        node.wait_with(lambda: Wait(sim_pose))
        self.sim = SimulatorWatch(node, self.localizer.restart)
        node.set_status(self.status)
        node.log.info(
            "fixes at %g Hz of simulation time, noise σ = (%g m, %g m, %g rad), seed %d",
            self.config.rate,
            self.config.noise_x,
            self.config.noise_y,
            self.config.noise_theta,
            self.seed,
        )

    def _on_sim_pose(self, message: TimedDoubleSeq) -> None:
        localizer = self.localizer
        restarts = localizer.time_base_restarts
        # The initial pose must reach odometry: the schedule starts once someone listens.
        fix = localizer.on_sim_pose(
            message.tm.to_nanoseconds(), message.data, may_start=localizer.started or self.publisher.matched
        )
        if localizer.time_base_restarts != restarts:
            self.node.log.info("simulation time went back (a new simulator): a new time base, a fix at once")
        if fix is not None:
            if localizer.fixes == 1 and localizer.first_fix_from_sim_pose:
                self.node.log.info(
                    "simulation time is already %.3f s: the first fix is the simulated pose, not the initial pose",
                    fix.stamp_ns / NANOSECONDS_PER_SECOND,
                )
            x, y, theta = fix.pose
            stamp = Time.from_nanoseconds(fix.stamp_ns)
            self.publisher.put(TimedPosition(tm=stamp, id=[], x=x, y=y, theta=theta, error=[]))

    def status(self) -> LocalizationStatus:
        if self.localizer.started:
            state = "running"
        else:
            state = "waiting_for_sim_pose" if self.localizer.last_sim_pose is None else "waiting_for_subscriber"
        return LocalizationStatus(
            state=state,
            mode="stub",
            fixes_published=self.localizer.fixes,
            time_base_restarts=self.localizer.time_base_restarts,
            sim_alive=self.sim.alive,
            last_fix=_fix_status(self.localizer.last_fix),
            rate_hz=self.config.rate,
            noise={"x": self.config.noise_x, "y": self.config.noise_y, "theta": self.config.noise_theta},
            seed=self.seed,
            seed_from_config=self.config.seed is not None,
            initial_pose=PlanarPose(*self.localizer.initial),
            first_fix_from_sim_pose=self.localizer.first_fix_from_sim_pose,
            lockstep_participant=self.node.participating,
        )

    def close(self) -> None:
        """Nothing beyond the node to release."""


class NoLocalization:
    """``localization.mode = "none"``: the odometry alone. The initial pose is published once, at
    the first wheel-angle sample after someone listens, if that is within one fix period of time 0
    (the pose at the start, as the stub's first fix); then nothing: the odometry's drift shows. It
    reads no ground truth and takes no part in lockstep (no fix is owed)."""

    finished = False
    exit_code = 0

    def __init__(self, node: Node, config: Config) -> None:
        self.node = node
        self.config = config.localization
        self.initial = Pose(self.config.initial_x, self.config.initial_y, self.config.initial_theta)
        self.initial_published_at: int | None = None
        self.skipped_initial = False
        self._until_ns = round(NANOSECONDS_PER_SECOND / self.config.rate)
        self.publisher = node.publisher(node.keys.localization_pose)
        node.subscribe(
            node.keys.motor_wheel_angles, TimedDoubleSeq, self._on_wheel_angles, Delivery.SAMPLED, wakes=True
        )
        node.set_status(self.status)
        node.log.info("no localization: the initial pose once, then the odometry alone")

    def _on_wheel_angles(self, sample: TimedDoubleSeq) -> None:
        if self.initial_published_at is not None or self.skipped_initial or not self.publisher.matched:
            return
        stamp_ns = sample.tm.to_nanoseconds()
        if stamp_ns > self._until_ns:
            self.skipped_initial = True
            self.node.log.info("simulation time is already %.3f s: no initial pose", stamp_ns / NANOSECONDS_PER_SECOND)
            return
        x, y, theta = self.initial
        self.publisher.put(TimedPosition(tm=sample.tm, id=[], x=x, y=y, theta=theta, error=[]))
        self.initial_published_at = stamp_ns

    def status(self) -> LocalizationStatus:
        return LocalizationStatus(
            state="running",
            mode="none",
            initial_pose=PlanarPose(*self.initial),
            initial_published_at=None
            if self.initial_published_at is None
            else self.initial_published_at / NANOSECONDS_PER_SECOND,
            initial_skipped=self.skipped_initial,
            lockstep_participant=False,
        )

    def close(self) -> None:
        """Nothing beyond the node to release."""


def localization_service(
    node: Node, config: Config, _options: NoOptions
) -> StubLocalization | AmclLocalization | NoLocalization:
    """The localization of ``localization.mode``."""
    mode = config.localization.mode
    if mode == "amcl":
        return AmclLocalization(node, config)
    if mode == "none":
        return NoLocalization(node, config)
    return StubLocalization(node, config, _options)


COMMAND = ServiceCommand(service=Service.LOCALIZATION, factory=localization_service)
