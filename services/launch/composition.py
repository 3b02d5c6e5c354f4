"""Services composed in one process on one zenoh session, as ROS 2 component containers do.

The same service code and the same keys as separate processes, still visible to outside zenoh
tools, without the network hop: every service's node is on one :class:`Executor`, and the sim's
thread (its lockstep wait) handles all their events and inputs, so a step's exchange (wheel
angles → motor → torque → sim) involves no thread switch, and no other thread competes for the
GIL at every step (when one did, the loop ran at half the speed: benchmarks/README.md). The
services hand each other their messages as they are, through a :class:`LocalBus` (intra-process
delivery, as rclcpp's: no encoding, no zenoh), and zenoh carries a message only to a subscriber
outside the process (``intra_process=False``: every message through the session, as before). The
other services run no loop of their own; the drive's end shows in its ``finished``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import zenoh

from services.config import RtConfig
from services.exits import ExitStatus
from services.runtime.executor import STOP_POLL_S, Executor
from services.runtime.intraprocess import LocalBus
from services.runtime.node import Node
from services.runtime.realtime import pin_loop_thread, settle_garbage_collector
from services.service import ClockedService, RunningService, ServicePlan, start_service

if TYPE_CHECKING:
    from services.launch.service_plans import ChildPlan

log = logging.getLogger("invent.composed")


@dataclass
class ComposedService:
    name: str
    node: Node
    service: RunningService
    thread: threading.Thread | None
    exit_code: int | None = None
    error: BaseException | None = field(default=None, repr=False)

    def finished(self) -> int | None:
        """The exit code once the service's run loop has returned (1 if it raised), or its own once
        a service without a loop has finished by itself (the drive's outcome); else None."""
        if self.thread is None:
            return self.service.exit_code if self.service.finished else None
        if self.thread.is_alive():
            return None
        return self.exit_code if self.error is None else ExitStatus.FAILURE


class Composition:
    """Builds and runs services on one shared session; the in-process twin of
    :class:`services.launch.children.Supervisor`."""

    def __init__(self, session: zenoh.Session, *, intra_process: bool = True) -> None:
        self.session = session
        self._stop = threading.Event()
        self._shared = Executor()
        self.bus = LocalBus() if intra_process else None
        """The services hand each other their messages directly (services/runtime/intraprocess.py);
        None: through the one session, as separate processes do."""
        self.services: list[ComposedService] = []

    def start_service(self, child: ChildPlan[Any]) -> ComposedService:
        """Build the service ``child`` plans, here, and start its loop if it has one."""
        # Imported here: the plans import every service's module (and scipy with the navigation's),
        # which `invent control`, composing only the sim and the motor from its own plans, never needs.
        from services.launch.service_plans import service_argv

        return self.start_plan(child.name, child.service_plan(), " ".join(service_argv(child)))

    def start_plan(self, name: str, plan: ServicePlan, command_line: str = "") -> ComposedService:
        """Build the service ``plan`` says, here, under ``name``, and start its loop if it has one
        (``command_line``: the one that would run it alone, for the log)."""
        config = plan.config
        node, service = start_service(plan, self.session, self._shared, self.bus)
        composed = ComposedService(name, node, service, None)
        if isinstance(service, ClockedService):
            # The clocked service starts last: everything the composition needs is built.
            settle_garbage_collector(config.rt)
            composed.thread = threading.Thread(
                target=self._run, args=(composed, service, config.rt), name=name, daemon=True
            )
            composed.thread.start()
        self.services.append(composed)
        log.info("started %s in this process: invent %s", name, command_line or plan.command.service)
        return composed

    def post(self, handle: Callable[[Any], None], item: Any) -> None:
        """Run ``handle(item)`` on the thread that handles the services' events (thread-safe)."""
        self._shared.post(handle, item)

    def spin(self, timeout: float) -> None:
        """Handle the services' events and inputs on this thread for up to ``timeout`` seconds (a
        composition whose services have no loop of their own: a fleet's worker)."""
        deadline = time.monotonic() + timeout
        while (remaining := deadline - time.monotonic()) > 0 and self._shared.spin_once(remaining):
            pass

    def idle(self) -> None:
        """Until the sim's thread runs the shared executor, handle its events here: the services
        started before the sim (the drive's lockstep token waits on its matching event) need them."""
        if not any(composed.thread is not None for composed in self.services):
            while self._shared.spin_once(0):
                pass

    def _run(self, composed: ComposedService, service: ClockedService, rt: RtConfig) -> None:
        pin_loop_thread(rt, f"invent up --composed: {composed.name}")
        try:
            composed.exit_code = service.run(self._stop)
        except BaseException as error:  # reported by check(), like a child process that died
            composed.error = error
            log.exception("%s crashed", composed.name)

    def exited(self, exclude: str | None = None) -> tuple[str, int, str] | None:
        """(name, exit code, reason) of a service other than ``exclude`` whose loop ended, or None."""
        for composed in self.services:
            code = composed.finished()
            if composed.name != exclude and code is not None:
                reason = f"crashed: {composed.error!r}" if composed.error else f"returned {code}"
                return composed.name, code, reason
        return None

    def exits(self) -> dict[str, tuple[int, str]]:
        """Every service whose loop has ended (or that has finished by itself): (exit code, how), by name."""
        ended = {}
        for composed in self.services:
            code = composed.finished()
            if code is not None:
                ended[composed.name] = (code, f"crashed: {composed.error!r}" if composed.error else f"returned {code}")
        return ended

    def stop(self) -> dict[str, int]:
        """Stop every loop, then close services and nodes, newest first."""
        self._stop.set()
        for composed in self.services:
            if composed.thread is not None:
                composed.thread.join()
        for composed in reversed(self.services):
            composed.service.close()
            composed.node.close()
        codes = {c.name: (c.finished() or 0) for c in self.services}
        self.services.clear()
        return codes


def run_composed(
    session: zenoh.Session,
    plans: Sequence[tuple[str, ServicePlan]],
    stop: threading.Event,
    started: Callable[[Composition], None] | None = None,
) -> int:
    """Compose ``plans`` ((name, plan), started in this order: the clocked service last) on
    ``session``, call ``started`` with the composition, and run them until ``stop`` is set or one
    of them ends by itself, then stop them all (``invent control``). The exit status: the code of
    the first to end by itself (the sim's 0 after ``--duration``, 1 for a crash), else the highest
    of their codes."""
    composition = Composition(session)
    ended: dict[str, tuple[int, str]] = {}
    try:
        for name, plan in plans:
            composition.start_plan(name, plan)
        if started is not None:
            started(composition)
        while not stop.wait(STOP_POLL_S):
            ended = composition.exits()
            if ended:
                name, (_, how) = next(iter(ended.items()))
                log.warning("%s %s: stopping the others", name, how)
                break
    finally:
        codes = composition.stop()
    if ended:
        return next(iter(ended.values()))[0]
    return max(codes.values(), default=ExitStatus.OK)
