"""What ``--ros2`` adds to a run of ``invent up`` (one robot, services/launch/up.py, or a fleet,
services/launch/fleet.py): the checks of its flags, each robot's bridge of a fleet (its namespace,
``/clock`` from one), and the run's ROS 2 bag (``--record-ros2``); and ``invent ros2 --fleet FILE``,
a bridge per robot of a fleet in one process (:func:`serve_bridges`).

One bridge per robot, not one for the fleet: each robot's bridge is a service of that robot like
its motor, with that robot's credentials in a secure fleet (it may touch only its robot's keys and
its namespace's topics), and a bridge that dies degrades only its robot. Its cost per robot is in
benchmarks/README.md ("The bridge of each robot of a fleet").

The bag is made as ``run.mcap`` is, where the samples already are: each bridge keeps what it
publishes (the CDR payload and the simulation time it carries) in a journal of its own, within its
share of ``[record]``'s bounds, and at the end of the run :class:`BagRecording` makes the bag of
them (services/recording/rosbag.py). A recorder subscribed to the bridges would cost the run
zenoh's delivery of every ROS message to it.
"""

from __future__ import annotations

import argparse
import logging
import shutil
from pathlib import Path
from threading import Event, Thread

import zenoh

from services.config import Config, ConfigError, RecordConfig, SimMode, TfLayout
from services.exits import ExitStatus
from services.fleet.description import Fleet, bridge_configs
from services.launch.children import say
from services.recording.rosbag import write_bag_from_journals
from services.ros2.graph import BridgeGraph, bridge_graph
from services.runtime.node import Node
from services.service import RunningService, ServiceCommand, overrides_from_args, start_service

log = logging.getLogger("invent.ros2")

BAG_DIRECTORY = "rosbag2"
"""The run's bag, beside its ``run.mcap``: ``<report dir>/rosbag2/`` (``metadata.yaml``, ``rosbag2_0.mcap``, ...)."""
BAG_JOURNALS_DIRECTORY = "bag-journals"
"""Where the bridges keep what they publish while the run lasts (made into the bag at its end)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``invent up``'s flags of the bridges' TF and of the run's bag."""
    parser.add_argument(
        "--tf",
        choices=list(TfLayout),
        help="with --ros2 and a namespace (every robot of a fleet has one): namespaced (default), each robot's "
        "TF on /<NS>/tf and /<NS>/tf_static, frames as named (Nav2's multi-robot bringup); prefixed, every robot "
        "on the shared /tf and /tf_static, frames <NS>/odom, <NS>/base_link, ... under map, for one RViz (the "
        "same as --set ros2.tf=...; docs/ros2.md, A fleet)",
    )
    parser.add_argument(
        "--record-ros2",
        action="store_true",
        help=f"with --ros2: also record what the ROS 2 bridges publish into a rosbag2 bag (MCAP storage) beside "
        f"run.mcap, <report dir>/{BAG_DIRECTORY}/, stamped in simulation time, /clock included, within the bounds "
        "of [record] (`ros2 bag info`, `ros2 bag play --clock`, Foxglove: docs/ros2.md, Bags)",
    )


def check_ros2_flags(args: argparse.Namespace) -> None:
    """ConfigError (exit 2) for ``--teleop`` or ``--record-ros2`` where they cannot work, before anything starts."""
    if args.teleop:
        given = {"--ros2": not args.ros2, "--mode lockstep": args.mode == SimMode.LOCKSTEP, "--loop": args.loop}
        wrong = [flag for flag, conflicting in given.items() if conflicting]
        if wrong:
            raise ConfigError(
                f"--teleop ({', '.join(wrong)}): it runs the loop in realtime with no scenario, the robots following "
                "ROS 2's /cmd_vel through the bridge, so it needs --ros2 and takes neither --mode lockstep nor --loop"
            )
    if args.record_ros2:
        given = {
            "without --ros2": not args.ros2,
            "with --no-record": args.no_record,
            "with --loop": args.loop,
            "with --teleop": args.teleop,
        }
        wrong = [flag for flag, conflicting in given.items() if conflicting]
        if wrong:
            raise ConfigError(
                f"--record-ros2 {', '.join(wrong)}: the bag of the bridges' topics is written with run.mcap at the end "
                "of a recorded run with --ros2 (beside a --teleop or --loop run, record it with `invent record --ros2`)"
            )


def fleet_bridges(fleet: Fleet, args: argparse.Namespace, command: ServiceCommand | None = None) -> dict[str, Config]:
    """Each robot's description as its bridge runs with it (its namespace, ``/clock`` from the
    first; ``command``'s flags, ``invent ros2``'s, over the rest), checked (ConfigError names the
    robot and field; ``$ROS_DOMAIN_ID`` too)."""
    configs = bridge_configs(fleet, args.config, overrides_from_args(command, args))
    for config in configs.values():
        bridge_graph(config)
    return configs


def fleet_bridge_graphs(fleet: Fleet, args: argparse.Namespace) -> dict[str, BridgeGraph]:
    """What each robot's bridge is in the ROS graph: what its credentials grant (``--secure``)."""
    return {name: bridge_graph(config) for name, config in fleet_bridges(fleet, args).items()}


def serve_bridges(
    command: ServiceCommand, session: zenoh.Session, configs: dict[str, Config], args: argparse.Namespace, stop: Event
) -> int:
    """``invent ros2 --fleet FILE``: a bridge per robot (``configs``, :func:`fleet_bridges`) on one
    session, each on its own thread (a node and executor of its own), until ``stop``; 1 if one failed."""
    running: list[tuple[Node, RunningService]] = []
    failed: list[str] = []

    def serve(name: str, node: Node, service: RunningService) -> None:
        try:
            node.serve(stop, lambda: service.finished)
        except Exception:
            log.exception("the bridge of %s failed", name)
            failed.append(name)
            stop.set()

    threads = []
    try:
        for name, config in configs.items():
            node, service = start_service(command, session, config, args)
            running.append((node, service))
            threads.append(Thread(target=serve, args=(name, node, service), name=f"ros2-{name}", daemon=True))
        for thread in threads:
            thread.start()
        stop.wait()
        for thread in threads:
            thread.join()
    finally:
        for node, service in reversed(running):
            service.close()
            node.close()
    return ExitStatus.FAILURE if failed else ExitStatus.OK


class BagRecording:
    """``--record-ros2``: the ``bridges`` bridges of the run keep what they publish in journals in
    ``<report dir>/bag-journals/`` (:attr:`flags`), sharing ``record``'s bounds; :meth:`finish`
    makes ``<report dir>/rosbag2/`` of them."""

    def __init__(self, report_dir: Path, record: RecordConfig, bridges: int, distro: str) -> None:
        self.record = record
        self.distro = distro
        self.path = report_dir / BAG_DIRECTORY
        self.directory = report_dir / BAG_JOURNALS_DIRECTORY
        if self.path.exists():
            raise ConfigError(f"--record-ros2: {self.path} exists (a bag is written into a new directory)")
        self._made = [
            directory for directory in (self.directory, report_dir, *report_dir.parents) if not directory.exists()
        ]
        """The directories this makes, deepest first: a run that never starts removes them again."""
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise ConfigError(f"--report {report_dir}: {error.strerror}") from None
        self.flags = ["--bag-journal", str(self.directory), "--bag-journal-share", str(bridges)]
        """What a bridge needs to keep its journal here."""

    def finish(self, started: bool) -> None:
        """At the run's end, however it ended: the bag (once every bridge has stopped), or, for a
        run that never started, nothing (and no directory it made, unless something else is in it);
        the journals are removed either way."""
        try:
            if not started:
                shutil.rmtree(self.directory, ignore_errors=True)
                for directory in self._made[1:]:
                    try:
                        directory.rmdir()
                    except OSError:  # not empty: the run's secrets, its run.mcap, or someone else's files
                        break
                return
            say(f"writing the ROS 2 bag {self.path} from what the bridges published")
            result = write_bag_from_journals(self.directory, self.path, self.record, self.distro)
            if result.stopped is not None:
                say(f"the ROS 2 bag stopped before the run did ({result.stopped['reason']}); the robot went on")
            counts = ", ".join(f"{topic} {count}" for topic, count in sorted(result.counts.items()))
            say(f"ROS 2 bag: {self.path} ({result.messages} messages in {len(result.files)} file(s): {counts})")
        finally:
            shutil.rmtree(self.directory, ignore_errors=True)
