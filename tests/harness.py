"""Test harness: real zenoh sessions on free ports and real ``invent`` processes.

Nothing here mocks zenoh: every test gets its own router on a free loopback port, and waits
on conditions with timeouts (matching, liveliness, replies), never on bare sleeps.
"""

from __future__ import annotations

import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any, Self, TypeVar

import msgspec
import pytest
import zenoh

from schemas.codec import decode
from schemas.keys import Keys, ServiceName
from schemas.status_kinds import status_type
from services.runtime.session import free_port, open_session, session_config

REPO = Path(__file__).resolve().parent.parent
T = TypeVar("T")
MessageT = TypeVar("MessageT", bound=msgspec.Struct)


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def wait_until(predicate: Callable[[], T], timeout: float = 10.0, what: str = "condition") -> T:
    """Poll ``predicate`` until it returns a truthy value; fail the test after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.005)


PoseT = TypeVar("PoseT", bound=Sequence[float])


def at_rest(pose: Callable[[], PoseT], within_m: float = 0.001, window_s: float = 0.1) -> PoseT | None:
    """The pose ``pose()`` gives (x, y first), once it moved less than ``within_m`` in ``window_s``
    of wall time; None while it moves (for :func:`wait_until`)."""
    before = pose()
    time.sleep(window_s)  # a window of stillness, measured over wall time
    after = pose()
    return after if math.hypot(after[0] - before[0], after[1] - before[1]) < within_m else None


def open_router(endpoint: str) -> zenoh.Session:
    return zenoh.open(session_config(listen=[endpoint], mode="router"))


def open_peer(endpoint: str) -> zenoh.Session:
    return zenoh.open(session_config(connect=[endpoint]))


@contextmanager
def running_router() -> Iterator[str]:
    """A zenoh router on a free loopback port, closed at the end; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(session_config(listen=[endpoint], mode="router")):
        yield endpoint


def peer_session(endpoint: str) -> AbstractContextManager[zenoh.Session]:
    """A peer session connected to ``endpoint``, as a context manager that closes it."""
    return open_session(session_config(connect=[endpoint]))


class Collector:
    """Subscribes to a key and queues its decoded samples for the test thread."""

    def __init__(self, session: zenoh.Session, key: str, message_type: type[MessageT] | None = None) -> None:
        self.key = key
        self.samples: queue.Queue[Any] = queue.Queue()
        self._type = message_type
        self._subscriber = session.declare_subscriber(key, lambda s: self.samples.put(s.payload.to_bytes()))

    def get(self, timeout: float = 5.0) -> Any:
        try:
            payload = self.samples.get(timeout=timeout)
        except queue.Empty:
            raise AssertionError(f"no sample on {self.key} within {timeout} s") from None
        return decode(self._type, payload) if self._type else payload

    def drain(self) -> list[Any]:
        items = []
        while True:
            try:
                payload = self.samples.get_nowait()
            except queue.Empty:
                return items
            items.append(decode(self._type, payload) if self._type else payload)

    def close(self) -> None:
        self._subscriber.undeclare()


def noting_replier(calls: list[tuple[str, str]], who: str, reply: bytes = b"{}") -> Callable[[zenoh.Query], None]:
    """A queryable's handler for rights tests: notes ``(who, key)`` of each query it is routed, in
    ``calls``, and replies ``reply``."""

    def answer(query: zenoh.Query) -> None:
        calls.append((who, str(query.key_expr)))
        query.reply(query.key_expr, reply)

    return answer


def call(
    session: zenoh.Session, key: str, payload: bytes | str | None = None, timeout: float = 5.0
) -> tuple[bool, Any]:
    """Query ``key`` once something answers it; return (ok, JSON value) of the single reply."""
    querier = session.declare_querier(key, timeout=timeout)
    try:
        wait_until(lambda: querier.matching_status.matching, timeout, f"a queryable on {key}")
        replies = list(querier.get(payload=payload))
    finally:
        querier.undeclare()
    assert len(replies) == 1, f"expected one reply from {key}, got {len(replies)}"
    reply = replies[0]
    sample = reply.ok if reply.ok is not None else reply.err
    return reply.ok is not None, json.loads(sample.payload.to_bytes())


def status_reply(session: zenoh.Session, keys: Keys, service: ServiceName, timeout: float = 5.0) -> dict[str, Any]:
    """``service``'s status reply as JSON, for a test that asserts on the wire, once it is checked
    that the reply decodes (strictly) as its kind's Struct (schemas/status_kinds.py)."""
    ok, reply = call(session, keys.status(service), timeout=timeout)
    assert ok, reply
    msgspec.json.decode(json.dumps(reply), type=status_type(service))
    return reply


def wait_alive(session: zenoh.Session, token_key: str, timeout: float = 20.0) -> None:
    """Block until a liveliness token on ``token_key`` exists."""
    seen = threading.Event()
    with session.liveliness().declare_subscriber(token_key, lambda _s: seen.set(), history=True):
        if not seen.wait(timeout):
            raise AssertionError(f"{token_key} not alive within {timeout} s")


def invent_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "services.cli", *args]


ABORT_TIMEOUT_S = 5.0


class InventProcess:
    """An ``invent`` subcommand in its own process, stopped with SIGINT at the end.

    Its output waits in pipes the test reads when it wants to. A process that runs long and logs
    much needs ``drain=True``: threads then read both pipes as the lines come (a full pipe blocks
    the service in its next log line) and :meth:`stop` returns what they read. ``wrapper``: a
    command the process runs under (``setpriv ...`` to take rights away from it).
    """

    def __init__(
        self, *args: str, env: dict[str, str] | None = None, drain: bool = False, wrapper: Sequence[str] = ()
    ) -> None:
        self.args = args
        self.process = subprocess.Popen(
            [*wrapper, *invent_command(*args)],
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONFAULTHANDLER": "1", **(env or {})},
        )
        self._drained: tuple[list[str], list[str]] | None = None
        self._pumps: list[threading.Thread] = []
        if drain:
            self._drained = ([], [])
            for stream, lines in zip((self.process.stdout, self.process.stderr), self._drained, strict=True):
                pump = threading.Thread(target=lambda s=stream, sink=lines: sink.extend(s), daemon=True)
                pump.start()
                self._pumps.append(pump)

    def stderr_so_far(self) -> str:
        """What a ``drain=True`` process wrote on stderr so far (its log lines)."""
        assert self._drained is not None, "drain=True"
        return "".join(self._drained[1])

    def _communicate(self, timeout: float | None = None) -> tuple[str, str]:
        if self._drained is None:
            return self.process.communicate(timeout=timeout)
        self.process.wait(timeout)
        for pump in self._pumps:
            pump.join(5)
        return "".join(self._drained[0]), "".join(self._drained[1])

    def stop(self, timeout: float = 15.0) -> tuple[int, str, str]:
        """SIGINT, wait, and return (exit code, stdout, stderr)."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            out, err = self._communicate(timeout)
        except subprocess.TimeoutExpired:
            out, err = self._abort()
            raise AssertionError(f"invent {' '.join(self.args)} did not stop on SIGINT; stderr:\n{err}") from None
        return self.process.returncode, out, err

    def _abort(self) -> tuple[str, str]:
        """SIGABRT: with PYTHONFAULTHANDLER set, the process prints every thread's Python stack on
        stderr before it dies, so a hang says where it hangs."""
        self.process.send_signal(signal.SIGABRT)
        try:
            return self._communicate(ABORT_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return self._communicate()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: object) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self._communicate()


def start_up(*args: str) -> subprocess.Popen[str]:
    """``invent up ARGS`` in its own process, its output (stdout and stderr) on one text pipe."""
    return subprocess.Popen(
        invent_command("up", *args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def run_invent(*args: str, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(invent_command(*args), cwd=REPO, capture_output=True, text=True, timeout=timeout, check=False)


def refused(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """``invent ARGS`` run in this process, for arguments it refuses before anything starts (a
    process of its own costs a second of imports): its exit status, and what it wrote on stdout and stderr.

    Before anything starts means before the command takes over the signals or chooses its CPUs
    (``rt.partition``): both are checked unchanged in this process, which a late refusal would
    otherwise leave so for the rest of the suite. (An ignored SIGINT is the one change allowed:
    the entry point takes it back, as for a suite run as a background job.)"""
    from services.cli.main import main

    handler, cpus = signal.getsignal(signal.SIGINT), os.sched_getaffinity(0)
    if handler is signal.SIG_IGN:
        handler = signal.default_int_handler
    try:
        code = main(list(args))
    except SystemExit as exit_:
        code = exit_.code if isinstance(exit_.code, int) else 1
    captured = capsys.readouterr()
    assert signal.getsignal(signal.SIGINT) is handler, f"invent {' '.join(args)} took over the signals first"
    assert os.sched_getaffinity(0) == cpus, f"invent {' '.join(args)} chose its CPUs first"
    return code, captured.out, captured.err


def json_lines(text: str) -> list[Any]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def connect_flags(endpoint: str) -> Sequence[str]:
    return ("--connect", endpoint)
