"""Test harness: a zenoh session in another process (:class:`RemoteSession`), driven by JSON lines:
opened as every service opens its own (``services.runtime.session``), in a network namespace of
tests/netns.py (:meth:`~tests.netns.Network.session`; one process cannot hold sessions in two
namespaces, for zenoh's runtime threads are shared). Each declaration returns the :class:`Stream` of
what it receives, each event stamped with its arrival.

``python -m tests.remote_session --connect EP`` is the process of a :class:`RemoteSession`.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tests.netns import HostProcess


STOP_TIMEOUT_S = 10.0
"""How long a process (a session's, or one tests/netns.py started) is given to stop before it is killed."""

Event = dict[str, Any]


class Stream:
    """The events of one thing a :class:`RemoteSession` declared (samples, liveliness changes,
    replies), each stamped with ``t``, this process's ``time.monotonic()`` at its arrival."""

    def __init__(self, what: str) -> None:
        self.what = what
        self.events: list[Event] = []
        self._changed = threading.Condition()

    def _add(self, event: Event) -> None:
        with self._changed:
            self.events.append(event)
            self._changed.notify_all()

    def snapshot(self) -> list[Event]:
        with self._changed:
            return list(self.events)

    def wait_for(
        self, predicate: Callable[[Event], bool], timeout: float = 10.0, what: str = "", since: float = -1.0
    ) -> Event:
        """The first event (arrived after ``since``, a monotonic time) for which ``predicate`` holds;
        fails after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                for event in self.events:
                    if event["t"] > since and predicate(event):
                        return event
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"timed out after {timeout} s waiting for {what or 'an event'} on {self.what}")
                self._changed.wait(min(left, 0.2))


class RemoteSession:
    """A zenoh session in another process (in a namespace), opened by
    ``services.runtime.session.session_config``/``open_session`` as every service opens its own,
    and driven by JSON lines: each method sends one command. Its declarations return the
    :class:`Stream` of what they receive."""

    def __init__(self, start: Callable[[Callable[[str], None]], HostProcess], timeout: float = 20.0) -> None:
        """``start(on_line)`` starts the session's process, its stdout lines going to ``on_line``."""
        self._streams: dict[int, Stream] = {}
        self._ids = iter(range(1, 1 << 30))
        self._lock = threading.Lock()
        self._control = Stream("control")
        self._streams[0] = self._control
        self.process = start(self._dispatch)
        ready = self._wait_control(lambda e: e.get("event") in ("ready", "failed"), timeout, "the session to open")
        if ready["event"] == "failed":
            raise AssertionError(f"the remote session did not open: {ready['error']}")
        self.zid: str = ready["zid"]

    def _wait_control(self, predicate: Callable[[Event], bool], timeout: float, what: str) -> Event:
        try:
            return self._control.wait_for(predicate, timeout, what)
        except AssertionError as error:
            raise AssertionError(f"{error}; the session's stderr:\n{self.process.stderr}") from None

    def _dispatch(self, line: str) -> None:
        try:
            event = json.loads(line)
        except ValueError:
            return
        event["t"] = time.monotonic()
        stream = self._streams.get(event.get("id", 0), self._control)
        stream._add(event)

    def _send(self, command: dict[str, Any], what: str) -> tuple[int, Stream]:
        with self._lock:
            ident = next(self._ids)
            stream = Stream(what)
            self._streams[ident] = stream
            assert self.process.process.stdin is not None
            self.process.process.stdin.write(json.dumps({**command, "id": ident}) + "\n")
            self.process.process.stdin.flush()
        return ident, stream

    def _declared(self, command: dict[str, Any], what: str, timeout: float = 10.0) -> Stream:
        ident, stream = self._send(command, what)
        self._wait_control(lambda e: e.get("done") == ident, timeout, f"{what} to be declared")
        return stream

    def publish_every(self, key: str, period_s: float) -> Stream:
        """Put ``{"seq": n}`` on ``key`` every ``period_s`` (n = 0, 1, ...) until the session ends."""
        return self._declared({"op": "publish_every", "key": key, "period_s": period_s}, f"publisher {key}")

    def subscribe(self, key: str) -> Stream:
        """Events ``{"event": "sample", "key", "value"}`` (``value`` decoded as JSON)."""
        return self._declared({"op": "subscribe", "key": key}, f"subscriber {key}")

    def queryable(self, key: str, reply: Any) -> Stream:
        """Answer every query on ``key`` with the JSON ``reply``; its events say each query."""
        return self._declared({"op": "queryable", "key": key, "reply": reply}, f"queryable {key}")

    def token(self, key: str) -> Stream:
        """A liveliness token on ``key``."""
        return self._declared({"op": "token", "key": key}, f"token {key}")

    def liveliness(self, key: str) -> Stream:
        """Events ``{"event": "alive", "key", "kind": "put"|"delete"}`` for the tokens on ``key``
        (with history: the tokens alive now come first)."""
        return self._declared({"op": "liveliness", "key": key}, f"liveliness {key}")

    def get(self, key: str, timeout: float = 5.0) -> list[Any]:
        """A query on ``key``: the JSON value of each ok reply (errors as ``{"error": text}``)."""
        _ident, stream = self._send({"op": "get", "key": key, "timeout": timeout}, f"get {key}")
        return stream.wait_for(lambda e: e.get("event") == "replies", timeout + 10, f"replies to {key}")["replies"]

    def info(self) -> dict[str, Any]:
        """``{"zid", "routers": [zid...], "peers": [zid...]}``: whom the session is connected to."""
        _ident, stream = self._send({"op": "info"}, "info")
        return stream.wait_for(lambda e: e.get("event") == "info", 10, "info")

    def close(self) -> int:
        """Close the session (its process ends); return the exit code."""
        if self.process.process.poll() is None and self.process.process.stdin:
            try:
                self.process.process.stdin.close()
            except OSError:
                pass
            try:
                return self.process.process.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                pass
        return self.process.stop()


# ---- the process of a RemoteSession: python -m tests.remote_session ... ----


def _session_main(args: argparse.Namespace) -> int:
    import zenoh

    from services.errors import SessionFailed
    from services.runtime.session import open_session, session_config

    # The JSON lines keep the real stdout; zenoh's own log (which goes to fd 1) goes to stderr.
    protocol = os.fdopen(os.dup(sys.stdout.fileno()), "w", buffering=1)
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    out_lock = threading.Lock()

    def emit(event: Event) -> None:
        with out_lock:
            protocol.write(json.dumps(event) + "\n")
            protocol.flush()

    if os.environ.get("RUST_LOG"):
        zenoh.init_log_from_env_or("error")  # zenoh's own log on stderr, for a test that asks
    config = session_config(connect=args.connect, listen=args.listen, mode=args.mode)
    stop = threading.Event()
    try:
        with open_session(config) as session:
            emit({"event": "ready", "zid": str(session.zid())})
            keep: list[Any] = []
            threads: list[threading.Thread] = []
            for line in sys.stdin:
                command = json.loads(line)
                op, ident = command["op"], command["id"]
                if op == "publish_every":
                    publisher = session.declare_publisher(command["key"])
                    keep.append(publisher)

                    def publish(publisher: Any = publisher, period: float = command["period_s"]) -> None:
                        seq = 0
                        while not stop.wait(period):
                            publisher.put(json.dumps({"seq": seq}))
                            seq += 1

                    threads.append(threading.Thread(target=publish, daemon=True))
                    threads[-1].start()
                elif op == "subscribe":

                    def on_sample(sample: zenoh.Sample, ident: int = ident) -> None:
                        emit(
                            {
                                "id": ident,
                                "event": "sample",
                                "key": str(sample.key_expr),
                                "value": json.loads(sample.payload.to_bytes()),
                            }
                        )

                    keep.append(session.declare_subscriber(command["key"], on_sample))
                elif op == "queryable":

                    def on_query(query: zenoh.Query, ident: int = ident, reply: Any = command["reply"]) -> None:
                        query.reply(query.key_expr, json.dumps(reply))
                        emit({"id": ident, "event": "query", "key": str(query.key_expr)})

                    keep.append(session.declare_queryable(command["key"], on_query))
                elif op == "token":
                    keep.append(session.liveliness().declare_token(command["key"]))
                elif op == "liveliness":

                    def on_token(sample: zenoh.Sample, ident: int = ident) -> None:
                        kind = "put" if sample.kind == zenoh.SampleKind.PUT else "delete"
                        emit({"id": ident, "event": "alive", "key": str(sample.key_expr), "kind": kind})

                    keep.append(session.liveliness().declare_subscriber(command["key"], on_token, history=True))
                elif op == "get":

                    def query(
                        key: str = command["key"], timeout: float = command["timeout"], ident: int = ident
                    ) -> None:
                        replies = []
                        for reply in session.get(key, timeout=timeout):
                            if reply.ok is not None:
                                replies.append(json.loads(reply.ok.payload.to_bytes()))
                            elif reply.err is not None:
                                replies.append({"error": reply.err.payload.to_string()})
                        emit({"id": ident, "event": "replies", "replies": replies})

                    threads.append(threading.Thread(target=query, daemon=True))
                    threads[-1].start()
                    continue
                elif op == "info":
                    emit(
                        {
                            "id": ident,
                            "event": "info",
                            "zid": str(session.zid()),
                            "routers": sorted(str(z) for z in session.info.routers_zid()),
                            "peers": sorted(str(z) for z in session.info.peers_zid()),
                        }
                    )
                    continue
                else:
                    emit({"event": "error", "error": f"unknown op {op!r}"})
                    continue
                emit({"done": ident})
            stop.set()
            for thread in threads:
                thread.join(5)
    except SessionFailed as error:
        emit({"event": "failed", "error": str(error)})
        return 1
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tests.remote_session", description="a zenoh session driven by JSON lines on stdin"
    )
    parser.add_argument("--connect", action="append", default=[])
    parser.add_argument("--listen", action="append", default=[])
    parser.add_argument("--mode", default="peer")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    return _session_main(args)


if __name__ == "__main__":
    sys.exit(main())
