"""What ``--ros2`` adds to a run of ``invent up`` (one robot, services/launch/one_robot.py, or a fleet,
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

import logging
import shutil
from collections.abc import Mapping
from pathlib import Path
from threading import Event, Thread
from typing import Any

import zenoh

from services.config import Config, ConfigError, RecordConfig, SimMode
from services.errors import refuse_given
from services.exits import ExitStatus
from services.fleet.description import Fleet, bridge_configs
from services.launch.children import say
from services.launch.plan import UpPlan
from services.recording.rosbag import write_bag_from_journals
from services.ros2.graph import BridgeGraph, bridge_graph
from services.ros2.service import Ros2Options
from services.runtime.node import Node
from services.service import RunningService, ServicePlan, start_service

log = logging.getLogger("invent.ros2")

BAG_DIRECTORY = "rosbag2"
"""The run's bag, beside its ``run.mcap``: ``<report dir>/rosbag2/`` (``metadata.yaml``, ``rosbag2_0.mcap``, ...)."""
BAG_JOURNALS_DIRECTORY = "bag-journals"
"""Where the bridges keep what they publish while the run lasts (made into the bag at its end)."""


def check_ros2_flags(plan: UpPlan) -> None:
    """ConfigError (exit 2) for ``--teleop`` or ``--record-ros2`` where they cannot work, before anything starts."""
    if plan.teleop:
        given = {"--ros2": not plan.ros2, "--mode lockstep": plan.mode == SimMode.LOCKSTEP, "--loop": plan.loop}
        refuse_given(
            given,
            lambda named: (
                f"--teleop ({named}): it runs the loop in realtime with no scenario, the robots following "
                "ROS 2's /cmd_vel through the bridge, so it needs --ros2 and takes neither --mode lockstep nor --loop"
            ),
        )
    if plan.record_ros2:
        given = {
            "without --ros2": not plan.ros2,
            "with --no-record": plan.no_record,
            "with --teleop": plan.teleop,
        }
        refuse_given(
            given,
            lambda named: (
                f"--record-ros2 {named}: the bag of the bridges' topics is written with run.mcap at the "
                "end of a recorded run with --ros2 (beside a --teleop run, record it with `invent record --ros2`)"
            ),
        )


def fleet_bridges(fleet: Fleet, config_path: str | None, overrides: dict[str, Any]) -> dict[str, Config]:
    """Each robot's description as its bridge runs with it (its namespace, ``/clock`` from the
    first; ``overrides``, the command line's, over the rest), checked (ConfigError names the
    robot and field; ``$ROS_DOMAIN_ID`` too)."""
    configs = bridge_configs(fleet, config_path, overrides)
    for config in configs.values():
        bridge_graph(config)
    return configs


def fleet_bridge_graphs(fleet: Fleet, config_path: str | None, overrides: dict[str, Any]) -> dict[str, BridgeGraph]:
    """What each robot's bridge is in the ROS graph: what its credentials grant (``--secure``)."""
    return {name: bridge_graph(config) for name, config in fleet_bridges(fleet, config_path, overrides).items()}


def serve_bridges(session: zenoh.Session, plans: Mapping[str, ServicePlan], stop: Event) -> int:
    """``invent ros2 --fleet FILE``: a bridge per robot (``plans``, each robot's description from
    :func:`fleet_bridges`) on one session, each on its own thread (a node and executor of its own),
    until ``stop``; 1 if one failed."""
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
        for name, plan in plans.items():
            node, service = start_service(plan, session)
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
    ``<report dir>/bag-journals/`` (:attr:`options`), sharing ``record``'s bounds; :meth:`finish`
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
        self.options = Ros2Options(self.directory, bridges)
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
