"""The services of a run as child processes: starting them, their prefixed output, how they ended,
starting again those that failed as the run's restart policy says (:class:`Restarting`), and their
orderly stop (:class:`Supervisor`); :class:`Launcher` is what a run needs of them, which
``services/launch/composition.py`` provides too, for services composed in one process."""

from __future__ import annotations

import ctypes
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from schemas.keys import Service
from schemas.messages import ServiceRestart
from services.errors import ChildDied
from services.launch.restart import History, RestartPlan, RestartPolicy, RestartRule
from services.launch.service_plans import ChildPlan, ControlPlan, service_argv
from services.runtime.intraprocess import LocalBus

STOP_TIMEOUT_S = 10.0
"""How long a child has to stop after SIGINT before it is killed."""
_PR_SET_PDEATHSIG = 1
NAME_WIDTH = max(len(str(service)) for service in Service)


def say(text: str) -> None:
    """A line of ``invent up`` itself, prefixed as its children's are: one write, so that another
    thread's line (a child's, relayed) is never put inside it, as between print's text and its newline."""
    sys.stdout.write(f"[{'up':<{NAME_WIDTH}}] {text}\n")
    sys.stdout.flush()


def _die_with_parent() -> None:
    """Runs in the child before exec: SIGTERM it if ``invent up`` itself dies (Linux)."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


LINES_KEPT = 5


def describe_exit(code: int) -> str:
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit code {code}"


class ServiceDied(ChildDied):
    """A service of the run ended before the run did: which (its child's name) and how (its exit
    code, or minus the signal that killed it), for the run's summary and report."""

    def __init__(self, service: str, exit_code: int, how: str) -> None:
        super().__init__(f"{service} exited unexpectedly ({how})")
        self.service = service
        self.exit_code = exit_code


@dataclass
class Child:
    name: str
    process: subprocess.Popen[str]
    pump: threading.Thread
    said: list[str]
    """Its last lines of output (at most :data:`LINES_KEPT`): what it said before it died."""
    ready: threading.Event
    """Set once it has printed the line it was started to wait for (:meth:`Supervisor.start`)."""
    restarts: Restarting | None = None
    """How it is started again when it fails (``invent up --restart``); None: never."""

    def wait_ready(self, timeout: float) -> None:
        """Until it has said it is ready; ChildDied, with its last line, if it exits first or is
        not ready within ``timeout``."""
        deadline = time.monotonic() + timeout
        while not self.ready.wait(0.02):
            code = self.finished()
            if code is not None:
                self.pump.join(1.0)
                last = self.said[-1].strip() if self.said else ""
                raise ChildDied(f"{self.name} exited at start ({describe_exit(code)}){': ' + last if last else ''}")
            if time.monotonic() > deadline:
                raise ChildDied(f"{self.name} not ready within {timeout} s")

    def finished(self) -> int | None:
        """Its exit code once it has ended for good; None while it runs, or waits to be started
        again (its restart policy then starts it once its delay is over)."""
        code = self.process.poll()
        if code is None or self.restarts is None:
            return code
        return None if self.restarts.restarting(self, code) else code

    def check_running(self, unless_exit_code: int | None = None) -> None:
        """Raise ChildDied if it has ended (with any exit code other than ``unless_exit_code``)."""
        code = self.finished()
        if code is not None and code != unless_exit_code:
            raise ChildDied(f"{self.name} exited unexpectedly ({describe_exit(code)})")


class Restarting:
    """One child's restart policy at work (services/launch/restart.py): once it has failed, it is
    started again when its delay is over, each restart said and appended to ``done``."""

    def __init__(
        self,
        rule: RestartRule,
        launch: Callable[[], tuple[subprocess.Popen[str], threading.Thread]],
        done: list[ServiceRestart],
        began: float,
    ) -> None:
        self.rule = rule
        self._launch = launch
        self._done = done
        self._began = began
        self._history = History()
        self._started = time.monotonic()
        self._due: float | None = None
        """When it is started again, once it has failed; None while it runs (or has ended for good)."""
        self._exit_code = 0
        self._given_up = False

    def restarting(self, child: Child, exit_code: int) -> bool:
        """Whether ``child``, ended with ``exit_code``, is (or is about to be) started again: when
        its delay is over, it is, here."""
        now = time.monotonic()
        if self._due is None:
            following = self.rule.next_restart(self._history, exit_code, now - self._started)
            if following is None:
                if self.rule.is_failure(exit_code) and self._history.restarts and not self._given_up:
                    self._given_up = True
                    say(f"{child.name} {describe_exit(exit_code)}: not started again (the limit, {self.rule.limit})")
                return False
            self._history, self._due, self._exit_code = following, now + following.delay_s, exit_code
            say(
                f"{child.name} {describe_exit(exit_code)}: starting it again in {following.delay_s:g} s "
                f"(restart {following.restarts} of at most {self.rule.limit}, --restart {self.rule.policy})"
            )
        if now < self._due:
            return True
        child.pump.join(timeout=1.0)
        child.process, child.pump = self._launch()
        self._due, self._started = None, time.monotonic()
        restarted = ServiceRestart(child.name, self._exit_code, self._started - self._began, self._history.delay_s)
        self._done.append(restarted)
        return True


class Supervisor:
    """The children of one ``invent up`` run, their prefixed output, their restarts (``restarts``:
    the run's policy; None: a child that ends stays ended), and their orderly stop."""

    bus: LocalBus | None = None

    def __init__(self, restarts: RestartPlan | None = None) -> None:
        self.children: list[Child] = []
        self._restarts = restarts
        self.restarted: list[ServiceRestart] = []
        """Every restart so far, in order."""
        self._began = time.monotonic()

    def start(
        self,
        name: str,
        argv: Sequence[str],
        ready_line: str | None = None,
        *,
        on_line: Callable[[str], bool] | None = None,
        stdin: bool = False,
    ) -> Child:
        """Start ``invent <argv>`` as ``name``; with ``ready_line``, its :attr:`Child.ready` is set
        once it prints a line containing it. ``on_line(line)`` sees each line first and returns
        True for one it took (not printed); ``stdin``: the child's standard input is a pipe. Its
        restarts (if its policy has any) run the same command again."""
        said: list[str] = []
        ready = threading.Event()

        def launch() -> tuple[subprocess.Popen[str], threading.Thread]:
            process = subprocess.Popen(
                [sys.executable, "-m", "services.cli", *argv],
                stdin=subprocess.PIPE if stdin else None,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                start_new_session=True,
                # prctl only, no Python objects: the hazard of preexec_fn with threads does not arise.
                preexec_fn=_die_with_parent if sys.platform == "linux" else None,  # noqa: PLW1509
            )
            if ready_line is None:
                ready.set()
            else:
                ready.clear()
            pump = threading.Thread(
                target=self._pump, args=(name, process, said, ready, ready_line, on_line), daemon=True
            )
            pump.start()
            say(f"started {name} (pid {process.pid}): invent {' '.join(argv)}")
            return process, pump

        process, pump = launch()
        child = Child(name, process, pump, said, ready)
        if self._restarts is not None and (rule := self._restarts.rule(name)).policy is not RestartPolicy.NEVER:
            child.restarts = Restarting(rule, launch, self.restarted, self._began)
        self.children.append(child)
        return child

    def start_service(self, child: ChildPlan[Any] | ControlPlan) -> Child:
        """Start the service ``child`` plans as a process of its own: its plan rendered as its command line."""
        return self.start(child.name, service_argv(child))

    def _pump(
        self,
        name: str,
        process: subprocess.Popen[str],
        said: list[str],
        ready: threading.Event,
        ready_line: str | None,
        on_line: Callable[[str], bool] | None,
    ) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            if on_line is not None and on_line(line):
                continue
            sys.stdout.write(f"[{name:<{NAME_WIDTH}}] {line}")
            sys.stdout.flush()
            said.append(line)
            del said[:-LINES_KEPT]
            if ready_line is not None and ready_line in line:
                ready.set()

    def exited(self, exclude: str | None = None) -> tuple[str, int, str] | None:
        """(name, exit code, how it ended) of a child other than ``exclude`` that has exited, or None."""
        for child in self.children:
            code = child.finished()
            if child.name != exclude and code is not None:
                return child.name, code, describe_exit(code)
        return None

    def exits(self) -> dict[str, tuple[int, str]]:
        """Every child that has exited: its (exit code, how it ended), by name."""
        return {
            child.name: (code, describe_exit(code)) for child in self.children if (code := child.finished()) is not None
        }

    def stop(self) -> dict[str, int]:
        """SIGINT every child, newest first; kill what does not stop in time. Returns exit codes."""
        for child in reversed(self.children):
            if child.process.poll() is None:
                child.process.send_signal(signal.SIGINT)
                try:
                    child.process.wait(STOP_TIMEOUT_S)
                except subprocess.TimeoutExpired:
                    say(f"{child.name} did not stop within {STOP_TIMEOUT_S} s; killing it")
                    child.process.kill()
                    child.process.wait()
            child.pump.join(timeout=2.0)
        return {child.name: child.process.returncode for child in self.children}

    def idle(self) -> None:
        """Each child has its own thread."""


class Launcher(Protocol):
    """How a run starts its services: as processes (:class:`Supervisor`) or composed in this process."""

    bus: LocalBus | None
    """The intra-process delivery of the services composed in this process, if any: what watches
    their keys here taps it (services/runtime/intraprocess.py)."""

    def start_service(self, child: ChildPlan[Any]) -> Any:
        """Start the service ``child`` plans; what its end is watched by (its ``name``, ``finished()``)."""
        ...

    def exited(self, exclude: str | None = None) -> tuple[str, int, str] | None: ...

    def exits(self) -> dict[str, tuple[int, str]]: ...

    def stop(self) -> dict[str, int]: ...

    def idle(self) -> None:
        """Called while a run waits for its services to start: let them handle their events."""
