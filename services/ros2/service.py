"""``invent ros2``: the robot as a ROS 2 citizen on the same zenoh network, speaking rmw_zenoh's
wire format (services/ros2/wire.py) with no ROS installation. docs/ros2.md is the walkthrough.

One node in the ROS graph (``ros2.node_name``, in ``--namespace``) with:

- publishers: ``/clock`` (the simulation time, at ``ros2.clock_rate`` per simulated second; unless
  ``ros2.publish_clock`` is off: one bridge of a fleet publishes it), ``odom`` and ``tf``
  (``map -> odom -> base_link`` and the wheels, each unless its ``ros2.enable_*_tf`` switch leaves it
  to a node of ROS's own) and ``joint_states`` (at ``ros2.publish_rate``),
  and, latched (transient-local, zenoh-ext advanced publishers with a cache), ``tf_static`` (the
  casters) and ``robot_description`` (the URDF); ``tf`` and ``tf_static`` in the namespace, or on
  the shared ``/tf`` and ``/tf_static`` with prefixed frames (``ros2.tf``, services/ros2/graph.py);
  ``scan`` and ``imu`` (sensor_msgs LaserScan and Imu, best-effort sensor QoS), one for each
  ``sim/scan`` and ``sim/imu`` of a robot that has the sensor; the drive's map, costmap and plan
  as Nav2 names and offers them, ``map`` and ``global_costmap/costmap`` (nav_msgs/OccupancyGrid,
  latched) and ``plan`` (nav_msgs/Path), one for each ``drive/map``, ``drive/costmap`` and
  ``drive/plan``, each declared when the drive first publishes its key;
- subscriptions: ``cmd_vel`` as geometry_msgs/Twist and as TwistStamped (diff_drive_controller's
  since Jazzy), each forwarded as ``drive/target_velocity`` stamped with the newest simulation time
  (at most ``ros2.cmd_vel_rate`` per simulated second, the newest kept between two), so the motor's
  command timeout works as diff_drive_controller's ``cmd_vel_timeout``;
- services ``motor/stop``, ``motor/clear``, ``motor/start``, ``motor/finish`` (std_srvs/Trigger),
  each calling the Motor method of that name (``motor/gui/<method>``, as an operator would;
  services/ros2/motor_services.py);
- the action ``navigate_to_pose`` (nav2_msgs/NavigateToPose: its three services and two topics)
  and the subscription ``goal_pose`` (RViz's 2D Goal Pose), each goal sent to the drive's
  ``drive/goal/send`` (services/ros2/action_server.py), unless ``ros2.navigate_to_pose`` is off;
- with the particle filter (``localization.mode = "amcl"``), as nav2_amcl: ``amcl_pose``
  (geometry_msgs/PoseWithCovarianceStamped, latched) from each ``localization/pose`` with a
  covariance, ``particle_cloud`` (geometry_msgs/PoseArray, sensor QoS) from each
  ``localization/particles``, and the subscription ``initialpose`` (RViz's 2D Pose Estimate), each
  pose estimate sent, from the service thread, as a query of ``localization/initial_pose``; the
  localization's refusal is logged and counted (``initial_pose`` in the status).

Its inputs from the loop: every sample of ``sim/clock`` (the clock, the wheels, and the continuous
odometry: each observed step, so no tick is skipped), the newest of ``odometry/pose`` (``map``) and
of ``motor/torque`` (the wheels' efforts), every ``sim/scan`` and ``sim/imu``, every ``drive/map``
and ``drive/plan`` (latched: the last one published before the bridge started too) and the newest
``drive/costmap``; what they become is the pure :class:`~services.ros2.outputs.RosOutputs`,
which ``invent export --ros2`` replays a recording through. ``sim/clock`` comes at the simulator's
observed steps: the bridge holds an observer token for each of its rates (docs/protocol.md section
2.7), so each of its ticks is one of them. Bad input (a sample without rmw_zenoh's attachment,
malformed CDR, a twist not finite or implausible) is counted under its ROS key and dropped, a
scan, IMU sample, map, costmap or plan malformed, not finite or out of order under its key;
nothing from ROS reaches the motor unchecked. Several bridges may share one session (a composed
fleet): their nodes' and entities' ids come from one counter per session, as in one ROS context
(services/ros2/node_entities.py).
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import zenoh
from msgspec import UNSET

from schemas.codec import BadInput, encode
from schemas.drive_status import InitialPoseStatus, Ros2Status
from schemas.keys import Service
from schemas.messages import (
    NANOSECONDS_PER_SECOND,
    ImuSample,
    LaserScan,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)
from schemas.navigation import GoalPlan, LocalizationReply, OccupancyGrid, ParticleCloud
from schemas.status import PlanarPose
from services.clock.sim_watch import SimulatorWatch
from services.config import Config, ConfigError
from services.ros2 import core, graph, interfaces, navigate, wire
from services.ros2.action_calls import localization_reply
from services.ros2.action_server import NavigateServer
from services.ros2.motor_services import MotorServices
from services.ros2.node_entities import GraphTokens, RosPublisher
from services.ros2.odometry_services import OdometryServices
from services.ros2.outputs import Outgoing, RosOutputs
from services.runtime.inputs import Delivery
from services.runtime.journal import Journal, journal_path
from services.runtime.logs import RateLimitedLog
from services.runtime.node import Node, Wait
from services.service import ServiceCommand, journal_limits

INITIAL_POSE_TIMEOUT_S = 2.0
"""How long an ``initialpose`` waits for the localization's reply."""
PENDING_INITIAL_POSES = 4
"""``initialpose`` samples waiting for the localization at once; beyond, one is bad input."""
MAX_INITIAL_POSE_PAYLOAD = 4096
"""Bytes: an ``initialpose`` larger than this is bad input, refused before it is decoded (one is 344
bytes of CDR with a frame id of a few characters)."""


@dataclass(frozen=True)
class Ros2Options:
    """``invent ros2``'s own options beside the robot description: with ``invent up --record-ros2``,
    where the bridge keeps what it publishes for the run's bag, and how many bridges of the run
    share ``record.max_size``."""

    bag_journal: Path | None = None
    bag_journal_share: int = 1


class Ros2Bridge:
    finished = False
    """It serves until stopped."""
    exit_code = 0

    def __init__(self, node: Node, config: Config, options: Ros2Options) -> None:
        self.node = node
        self.config = config
        self.settings = settings = config.ros2
        self.graph = bridge = graph.bridge_graph(config)
        self.outputs = outputs = RosOutputs(config, bridge)
        self.tokens = tokens = GraphTokens(node.session, bridge)
        self.bag_journal = _bag_journal(options, config)
        self.entities = bridge.publications
        self.publishers = {
            name: RosPublisher(tokens, entity, self.bag_journal)
            for name, entity in self.entities.items()
            if name not in graph.NAVIGATION_TOPICS
        }
        """By topic; the navigation topics' once the drive published their first message."""
        self.target = node.publisher(node.keys.drive_target_velocity)
        self.clock = outputs.clock
        self.sim = sim = SimulatorWatch(node, self.clock.restart)
        self._min_forward_ns = round(NANOSECONDS_PER_SECOND / settings.cmd_vel_rate)
        self._pending_twist: tuple[float, float] | None = None
        self._last_forward_ns: int | None = None
        self.cmd_vel = {"received": 0, "forwarded": 0, "coalesced": 0}
        self._call_ids = itertools.count(1)

        # Every sample, not the newest: sim/clock comes only at the observed steps, and one taken
        # late is a /clock tick skipped and an /odom off its grid (and missing from the bag).
        self._clock_input = node.subscribe(
            node.keys.sim_clock, TimedDoubleSeq, sim.clock(self._on_wheels), Delivery.EVERY
        )
        rates = {settings.publish_rate, *((settings.clock_rate,) if bridge.publishes_clock else ())}
        for rate_hz in sorted(rates):
            node.observe(rate_hz)
        # The newest of each, taken when the clock wakes the thread: sampled inputs would have the
        # thread poll them every millisecond while it waits in the clock's channel.
        node.subscribe(
            node.keys.odometry_pose,
            TimedPosition,
            sim.stamped(node.keys.odometry_pose, outputs.take_localized, awaited=lambda: False),
            Delivery.NEWEST,
        )
        node.subscribe(
            node.keys.motor_torque,
            TimedDoubleSeq,
            sim.stamped(node.keys.motor_torque, outputs.take_torque, awaited=lambda: False),
            Delivery.NEWEST,
        )
        # Every sample: each is a message of its own. Taken when the clock wakes the thread (the
        # scan comes just before its step's clock), or, after a new simulator, once it decided.
        for topic, key, message_type, take in (
            ("scan", node.keys.sim_scan, LaserScan, outputs.take_scan),
            ("imu", node.keys.sim_imu, ImuSample, outputs.take_imu),
        ):
            if topic in bridge.publications:
                handler = partial(self._on_message, take)
                node.subscribe(key, message_type, sim.stamped(key, handler, awaited=lambda: False), Delivery.EVERY)

        # The drive's map and plan are latched: every one, and the last one published before this
        # bridge started (asked of the drive's queryable). The costmap comes about once a simulated
        # second and only its newest matters (taken when the clock wakes the thread, as the pose).
        def each(key: str, take: Callable[[Any], list[Outgoing]]) -> Callable[..., None]:
            return sim.stamped(key, partial(self._on_message, take), awaited=lambda: False)

        keys = node.keys
        node.subscribe_latched(keys.drive_map, OccupancyGrid, each(keys.drive_map, outputs.take_map))
        node.subscribe_latched(keys.drive_plan, GoalPlan, each(keys.drive_plan, outputs.take_plan))
        node.subscribe(
            keys.drive_costmap, OccupancyGrid, each(keys.drive_costmap, outputs.take_costmap), Delivery.NEWEST
        )
        # The particle filter's: every estimate (each one /amcl_pose), the newest particles.
        self.initial_pose = {"received": 0, "accepted": 0, "refused": 0, "unanswered": 0}
        self.last_initial_pose_refusal = ""
        self._pending_initial_poses: dict[int, str] = {}
        self._refusals = RateLimitedLog(node.log)
        self.initial_pose_key: str | None = None
        self._localization: Any = None
        if bridge.localization:
            pose = keys.localization_pose
            node.subscribe(pose, TimedPosition, each(pose, outputs.take_amcl_pose), Delivery.EVERY)
            particles = keys.localization_particles
            node.subscribe(particles, ParticleCloud, each(particles, outputs.take_particles), Delivery.NEWEST)
            self.initial_pose_key = bridge.key(graph.INITIAL_POSE)
            tokens.declare(wire.EntityKind.SUBSCRIPTION, graph.INITIAL_POSE)
            node.subscribe_bytes(self.initial_pose_key, self._on_initial_pose, Delivery.QUEUED)
            self._localization = node.querier(keys.localization_initial_pose, timeout=INITIAL_POSE_TIMEOUT_S)
        self.cmd_vel_keys: dict[str, str] = {}
        for entity in graph.CMD_VEL_SUBSCRIPTIONS:
            key = self.cmd_vel_keys[entity.interface] = bridge.key(entity)
            tokens.declare(wire.EntityKind.SUBSCRIPTION, entity)
            node.subscribe_bytes(key, partial(self._on_cmd_vel, entity.interface), Delivery.EVERY)
        self.motor_services = MotorServices(node, tokens)
        self.odometry_services = OdometryServices(node, tokens, outputs.odometry)
        self.frames = navigate.GoalFrames(settings.map_frame, outputs.prefix + settings.odom_frame)
        """The frames an ``initialpose`` may be given in."""
        self.navigate = (
            NavigateServer(node, config, tokens, outputs, partial(RosPublisher, tokens))
            if bridge.navigate_to_pose
            else None
        )
        self._publish(outputs.latched())
        node.wait_with(lambda: Wait(self._clock_input))
        node.set_status(self.status)
        node.log.info(
            "ROS 2 node %s in domain %d (zid %s): %s; %s once the drive publishes them",
            wire.full_name(bridge.namespace, settings.node_name),
            bridge.domain,
            tokens.identity.zid,
            ", ".join(publisher.name for publisher in self.publishers.values()),
            ", ".join(bridge.name(self.entities[topic]) for topic in graph.NAVIGATION_TOPICS),
        )

    def _publish(self, outgoing: list[Outgoing]) -> None:
        for message in outgoing:
            self._publisher(message.topic).put(message.message, message.stamp_ns)

    def _publisher(self, topic: str) -> RosPublisher:
        """The topic's publisher; a navigation topic's is declared (publisher and token) with its
        first message."""
        publisher = self.publishers.get(topic)
        if publisher is None:
            publisher = self.publishers[topic] = RosPublisher(self.tokens, self.entities[topic], self.bag_journal)
            self.node.log.info("publishing %s", publisher.name)
        return publisher

    # -- the loop's side ------------------------------------------------------------------------

    def _on_wheels(self, message: TimedDoubleSeq) -> None:
        taken = self.outputs.take_wheels(message)
        if taken.restarted:
            self._last_forward_ns = None
            self.node.log.info(
                "simulation time went back to %.3f s (a new simulator): odom starts again",
                message.tm.to_nanoseconds() / NANOSECONDS_PER_SECOND,
            )
        self._publish(taken.outgoing)
        if self.navigate is not None:
            self.navigate.tick(message.tm.to_nanoseconds(), taken.restarted)
        self._forward_twist()

    def _on_message(self, take: Callable[[Any], list[Outgoing]], message: Any) -> None:
        """A sample that is a ROS message of its own: a ``sim/scan`` or ``sim/imu``, a
        ``drive/map``, ``drive/costmap`` or ``drive/plan``."""
        self._publish(take(message))

    # -- ROS's side -----------------------------------------------------------------------------

    def _on_cmd_vel(self, interface_name: str, payload: bytes, attachment: bytes | None) -> None:
        wire.Attachment.decode(attachment)
        if len(payload) > core.MAX_TWIST_PAYLOAD:
            raise BadInput(f"{len(payload)} bytes, more than a twist's {core.MAX_TWIST_PAYLOAD}")
        target = core.target_from_twist(interfaces.deserialize(payload, interface_name), self.config)
        self.cmd_vel["received"] += 1
        if self._pending_twist is not None:
            self.cmd_vel["coalesced"] += 1
        self._pending_twist = target
        self._forward_twist()

    def _forward_twist(self) -> None:
        """Send the newest twist as a target stamped with the newest simulation time, unless one was
        sent less than 1/``cmd_vel_rate`` of simulation time ago (it waits for the clock then)."""
        now_ns = self.clock.last_ns
        if self._pending_twist is None or now_ns is None:
            return
        if self._last_forward_ns is not None and now_ns - self._last_forward_ns < self._min_forward_ns:
            return
        vx, w = self._pending_twist
        self.target.put(TimedVelocity(tm=Time.from_nanoseconds(now_ns), id=[], vx=vx, vy=0.0, w=w, error=[]))
        self._pending_twist = None
        self._last_forward_ns = now_ns
        self.cmd_vel["forwarded"] += 1

    def _on_initial_pose(self, payload: bytes, attachment: bytes | None) -> None:
        """An ``initialpose`` (the service thread: a queued input): checked, turned into ``map``
        and sent to the localization's ``localization/initial_pose``, its reply posted back to this
        thread. BadInput for a sample without rmw_zenoh's attachment, malformed or oversized, a
        pose estimate refused (navigate.py) or too many waiting for the localization."""
        wire.Attachment.decode(attachment)
        if len(payload) > MAX_INITIAL_POSE_PAYLOAD:
            raise BadInput(f"{len(payload)} bytes, more than a pose estimate's {MAX_INITIAL_POSE_PAYLOAD}")
        message = interfaces.deserialize(payload, interfaces.POSE_WITH_COVARIANCE_STAMPED)
        correction = self.outputs.map_to_odom
        request = navigate.initial_pose_request(
            message,
            self.frames,
            None if correction is None else correction[1],
            self.config.input.max_coordinate,
        )
        if len(self._pending_initial_poses) >= PENDING_INITIAL_POSES:
            raise BadInput(f"{PENDING_INITIAL_POSES} pose estimates already wait for the localization's reply")
        self.initial_pose["received"] += 1
        call_id = next(self._call_ids)
        self._pending_initial_poses[call_id] = f"({request.x:g}, {request.y:g}, {request.theta:g})"
        key = self.node.keys.localization_initial_pose
        post, guard = self.node.executor.post, self.node.guard
        self._localization.get(
            zenoh.handlers.Callback(
                lambda reply: post(
                    partial(guard, key, self._localization_replied), (call_id, localization_reply(reply))
                ),
                lambda: post(partial(guard, key, self._localization_done), call_id),
            ),
            payload=encode(request),
        )

    def _localization_replied(self, answer: tuple[int, LocalizationReply]) -> None:
        call_id, reply = answer
        pose = self._pending_initial_poses.pop(call_id, None)
        if pose is None:
            return
        if reply.accepted:
            self.initial_pose["accepted"] += 1
            self.node.log.info("initial pose %s taken by the localization", pose)
            return
        self.initial_pose["refused"] += 1
        self.last_initial_pose_refusal = reply.reason
        self._refusals(
            "refused", logging.WARNING, "the localization refused the initial pose %s: %s", pose, reply.reason
        )

    def _localization_done(self, call_id: int) -> None:
        """The query ended: a pose estimate still pending got no reply (no particle filter serves it)."""
        pose = self._pending_initial_poses.pop(call_id, None)
        if pose is not None:
            self.initial_pose["unanswered"] += 1
            self._refusals(
                "unanswered",
                logging.WARNING,
                "no localization answered the initial pose %s (is `invent localization` running with "
                'localization.mode = "amcl"?)',
                pose,
            )

    def status(self) -> Ros2Status:
        identity = self.tokens.identity
        return Ros2Status(
            state="waiting_for_clock" if self.clock.last_ns is None else "running",
            domain=identity.domain,
            namespace=identity.namespace,
            node=wire.full_name(identity.namespace, identity.name),
            zid=identity.zid,
            sim_alive=self.sim.alive,
            sim_time_s=None if self.clock.last_ns is None else self.clock.last_ns / NANOSECONDS_PER_SECOND,
            time_base_restarts=self.clock.restart.restarts,
            published={publisher.name: publisher.published for publisher in self.publishers.values()},
            cmd_vel=dict(self.cmd_vel),
            service_calls=self.motor_services.status(),
            odometry_services=self.odometry_services.status(),
            navigate=UNSET if self.navigate is None else self.navigate.status(),
            initial_pose=UNSET
            if self._localization is None
            else InitialPoseStatus(
                **self.initial_pose,
                waiting=len(self._pending_initial_poses),
                last_refusal=self.last_initial_pose_refusal,
            ),
            odom=PlanarPose(*self.outputs.odometry.pose),
        )

    def close(self) -> None:
        if self.navigate is not None:
            self.navigate.close()
        self.odometry_services.close()
        self.motor_services.close()
        if self._localization is not None:
            self._localization.undeclare()
        for publisher in self.publishers.values():
            publisher.undeclare()
        self.tokens.close()
        if self.bag_journal is not None:
            self.bag_journal.close()


def _bag_journal(options: Ros2Options, config: Config) -> Journal | None:
    """``--bag-journal DIR`` (``invent up --record-ros2``): where the bridge keeps what it publishes,
    ``<DIR>/<robot>.journal``, within its share of ``[record]``'s bounds, for the run's bag."""
    directory = options.bag_journal
    if directory is None:
        return None
    try:
        return Journal(
            journal_path(directory, config.robot.name), journal_limits(config.record, options.bag_journal_share)
        )
    except OSError as error:
        raise ConfigError(f"--bag-journal {directory}: {error.strerror}") from None


COMMAND = ServiceCommand(service=Service.ROS2, factory=Ros2Bridge, timestamped=True)
