"""The services of a run as child processes: starting them, their prefixed output, how they ended,
and their orderly stop (:class:`Supervisor`); :class:`Launcher` is what a run needs of them, which
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
from services.errors import ChildDied
from services.runtime.intraprocess import LocalBus

STOP_TIMEOUT_S = 10.0
"""How long a child has to stop after SIGINT before it is killed."""
_PR_SET_PDEATHSIG = 1
NAME_WIDTH = max(len(str(service)) for service in Service)


def say(text: str) -> None:
    """A line of ``invent up`` itself, prefixed as its children's are."""
    print(f"[{'up':<{NAME_WIDTH}}] {text}", flush=True)


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
        return self.process.poll()

    def check_running(self, unless_exit_code: int | None = None) -> None:
        """Raise ChildDied if it has ended (with any exit code other than ``unless_exit_code``)."""
        code = self.finished()
        if code is not None and code != unless_exit_code:
            raise ChildDied(f"{self.name} exited unexpectedly ({describe_exit(code)})")


class Supervisor:
    """The children of one ``invent up`` run, their prefixed output, and their orderly stop."""

    bus: LocalBus | None = None

    def __init__(self) -> None:
        self.children: list[Child] = []

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
        True for one it took (not printed); ``stdin``: the child's standard input is a pipe."""
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
        said: list[str] = []
        ready = threading.Event()
        if ready_line is None:
            ready.set()
        pump = threading.Thread(target=self._pump, args=(name, process, said, ready, ready_line, on_line), daemon=True)
        child = Child(name, process, pump, said, ready)
        pump.start()
        self.children.append(child)
        say(f"started {name} (pid {process.pid}): invent {' '.join(argv)}")
        return child

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
            code = child.process.poll()
            if child.name != exclude and code is not None:
                return child.name, code, describe_exit(code)
        return None

    def exits(self) -> dict[str, tuple[int, str]]:
        """Every child that has exited: its (exit code, how it ended), by name."""
        return {
            child.name: (code, describe_exit(code))
            for child in self.children
            if (code := child.process.poll()) is not None
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

    def start(self, name: str, argv: Sequence[str]) -> Any: ...

    def exited(self, exclude: str | None = None) -> tuple[str, int, str] | None: ...

    def exits(self) -> dict[str, tuple[int, str]]: ...

    def stop(self) -> dict[str, int]: ...

    def idle(self) -> None:
        """Called while a run waits for its services to start: let them handle their events."""
