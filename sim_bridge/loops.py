"""The sim bridge's two loops over every robot link (the mode's rules: :mod:`sim_bridge.bridge`):
lockstep, each step waiting for its torques and at the participants' ticks for their outputs,
for as long as their liveliness tokens say they live; realtime, steps paced to the wall clock. Their steps run at thousands a second: the per-step
code takes its attributes once and calls as little as it can (benchmarks/README.md)."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from schemas.messages import NANOSECONDS_PER_SECOND, Time
from services.config import SimConfig
from services.runtime.executor import STOP_POLL_S
from services.runtime.node import Node
from sim_bridge.link import RobotLink
from sim_bridge.liveness import Liveness
from sim_bridge.progress import RunProgress

if TYPE_CHECKING:
    from sim_bridge.engine import Engine

MAX_REALTIME_LAG_S = 0.1
"""Realtime mode: a loop this far behind the wall clock restarts its schedule instead of bursting."""


@dataclass(kw_only=True)
class Loop:
    """Steps the world: each step publishes every robot's state, sets its torques, and steps."""

    sim: Engine
    node: Node
    links: list[RobotLink]
    parameters: SimConfig
    progress: RunProgress
    end_step: float
    """The step of a finite run's last state (``--duration``); infinity for an endless run."""
    until_drive_ends: bool
    liveness: list[Liveness] = field(init=False)
    """Each link's, read at every step (``--until-drive-ends``) without going through the link."""

    def __post_init__(self) -> None:
        self.liveness = [link.liveness for link in self.links]

    def _publish_state(self, final: bool) -> int:
        sim = self.sim
        tm_ns = sim.time_ns
        tm = Time.from_nanoseconds(tm_ns)
        self.progress.published_ns = tm_ns
        every_step = self.node.recording_every_step
        for link in self.links:
            link.publish_state(sim.step_index, tm_ns, tm, every_step, final)
        return tm_ns

    def final(self) -> bool:
        """Whether the state about to be published is a finite run's last (``--duration``): it is
        published, observed, and answered as any step's, then the run ends without stepping."""
        return self.sim.step_index >= self.end_step

    def ended(self) -> bool:
        """``--until-drive-ends``: every robot's drive has ended its scenario."""
        if not self.until_drive_ends:
            return False
        for liveness in self.liveness:  # a loop, not all() over a generator: this runs at every step
            if not liveness.drive_ended:
                return False
        return True

    def _after_torques(self, tm_ns: int) -> None:
        for link in self.links:
            link.after_torque(tm_ns)

    def _step(self) -> bool:
        """Step the world; True if a bump began (its ``motor/bump/stop`` called)."""
        contacts = self.sim.step()
        if contacts:
            tm = Time.from_nanoseconds(self.sim.time_ns)
            for contact in contacts:
                self.links[contact.robot].bump(contact, tm)
        return bool(contacts)

    # --- lockstep ---

    def run_lockstep(self, stop: threading.Event) -> None:
        try:
            while not stop.is_set():
                final = self.final()
                tm_ns = self._publish_state(final)
                self._lockstep_torques(tm_ns, stop, final)
                self._after_torques(tm_ns)
                self._lockstep_ticks(tm_ns, stop)
                if final or self.ended():
                    return
                if self._step():
                    self._lockstep_bump_stops(stop)
        finally:
            for liveness in self.liveness:
                liveness.steps_over = True

    def _lockstep_torques(self, tm_ns: int, stop: threading.Event, final: bool) -> None:
        """Set this step's torque of every robot: its motor's answer for ``tm_ns``, or zero."""
        links = self.links
        for link in links:
            link.torque.begin_wait(tm_ns)
        for link in links:
            self._lockstep_torque(link, tm_ns, stop, final)
        step_index = self.sim.step_index
        for link in links:
            link.torque.end_wait(step_index, final)

    def _lockstep_torque(self, link: RobotLink, tm_ns: int, stop: threading.Event, final: bool) -> None:
        """Wait for ``link``'s torque for ``tm_ns`` while its motor control is alive, however long
        it takes (said at each ``sim.lockstep_timeout``); a silent one's for one real-time period."""
        torque = link.torque
        if not torque.motor_alive:
            self.node.drain()
            torque.not_awaited(final)
            return
        spin_until = self.node.executor.spin_until  # the step's messages in one call, not one each
        settled, torque_input = torque.settled, link.torque_input
        interval = self.parameters.lockstep_timeout
        began = time.monotonic()
        said = began + interval
        while not stop.is_set():
            silent = torque.silent  # a motor control that goes and comes back mid-wait is silent
            until = began + torque.silent_wait_s if silent else said
            if spin_until(settled, max(0.0, min(until - time.monotonic(), STOP_POLL_S)), torque_input):
                return
            now = time.monotonic()
            if now < until:
                continue
            if silent:
                torque.silent_wait_ran_out(final)
                return
            torque.still_waiting(tm_ns, now - began)
            said += interval

    def _lockstep_bump_stops(self, stop: threading.Event) -> None:
        """Wait until the step's ``motor/bump/stop`` calls have finished (answered, or past their
        own timeout) before the next step's wheel angles: the motor latches at the contact's step,
        the same in every run, not when the call happens to reach it."""
        links = self.links

        def finished() -> bool:
            return not any(link.bump_stops_open for link in links)

        while not finished() and not stop.is_set():
            self.node.executor.spin_until(finished, STOP_POLL_S)

    def _lockstep_ticks(self, tm_ns: int, stop: threading.Event) -> None:
        """Wait for the outputs of the participants with a tick at ``tm_ns``, each for as long as its
        token lives (said at each ``sim.lockstep_timeout``): one whose token goes is dropped, and a
        robot whose motor control has gone waits for none."""
        due = []
        for link in self.links:  # a loop, not a comprehension: this runs at every step
            if link.barrier.ticks(tm_ns):
                due.append(link)
        if not due:
            return
        node = self.node
        interval = self.parameters.lockstep_timeout
        began = time.monotonic()
        said = began + interval
        for link in due:
            barrier, liveness = link.barrier, link.liveness
            while (missing := barrier.missing()) and not stop.is_set():
                if liveness.motor_lost:
                    for service in missing:
                        barrier.gave_up(service)
                    break
                now = time.monotonic()
                if now >= said:
                    liveness.still_waiting(missing, tm_ns, now - began)
                    said += interval
                    continue
                node.spin_once(min(said - now, STOP_POLL_S), link.outputs[missing[0]])

    # --- realtime ---

    def run_realtime(self, stop: threading.Event) -> None:
        sim, node, links = self.sim, self.node, self.links
        period = sim.step_ns / NANOSECONDS_PER_SECOND / self.parameters.realtime_factor
        origin, origin_step = time.monotonic(), sim.step_index
        while not stop.is_set():
            final = self.final()
            tm_ns = self._publish_state(final)
            deadline = origin + (sim.step_index + 1 - origin_step) * period
            while (remaining := deadline - time.monotonic()) > 0.0:
                node.spin_once(min(remaining, STOP_POLL_S))
                for link in links:
                    if link.torque.newest_ns == tm_ns:
                        link.after_torque(tm_ns)
            self._after_torques(tm_ns)
            if final:
                return
            if -remaining > MAX_REALTIME_LAG_S:
                for link in links:
                    link.counters["realtime_resyncs"] += 1
                origin, origin_step = time.monotonic(), sim.step_index + 1
            node.drain()
            step_index = sim.step_index
            for link in links:
                link.torque.realtime(tm_ns, step_index)
            if self.ended():
                return
            self._step()
