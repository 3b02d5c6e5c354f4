"""The zenoh session of a service or tool: its configuration, opening it, and the signals that end it."""

from __future__ import annotations

import faulthandler
import json
import os
import random
import signal
import socket
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import zenoh

from services.config import ConfigError
from services.errors import SessionFailed

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where services connect and ``invent router`` listens by default (rmw_zenoh's convention)."""
LOOPBACK_LISTEN = "tcp/127.0.0.1:0"
"""Where a peer listens unless told otherwise: a free port on loopback, so peers on one host still
talk directly while nothing off the host can connect (zenoh's own default is every interface)."""

ZENOH_CONFIG_VARIABLE = "ZENOH_CONFIG"
LOW_LATENCY_VARIABLE = "INVENT_ZENOH_LOWLATENCY"
"""Set to 1 to use :data:`LOW_LATENCY` (opt-in: see its caveats)."""
LOW_LATENCY = {
    "transport/unicast/lowlatency": "true",
    "transport/unicast/qos/enabled": "false",
    "scouting/gossip/autoconnect_strategy": json.dumps({"peer": {"to_router": "always", "to_peer": "greater-zid"}}),
}
"""Zenoh's low-latency unicast transport: a put writes to the socket itself, no batching thread
(it needs QoS off). The separate-process lockstep loop gains about 15-20 % from it
(benchmarks/README.md), but it is not the default, for what else was measured here with
zenoh 1.10.2: no batching, so a loaded subscriber of a 1 kHz key falls further behind; no
fragmentation, so a publication that does not fit in one batch is dropped (48 kB pass, 56 kB do
not); with both peers of a pair connecting at once, declarations were lost at start-up (about
one start in six; hence peers connecting one way only, to the greater id, which cured it); and
once, the whole loop stalled in puts and a declaration for minutes. A peer or router without
these settings (zenohd's defaults) still talks to these, over the ordinary transport."""


def session_config(
    *,
    connect: Iterable[str] = (),
    listen: Iterable[str] = (),
    mode: str = "peer",
    file: str | None = None,
    timestamping: bool = False,
) -> zenoh.Config:
    """The zenoh configuration of a service or tool.

    Default: ``mode`` (peer), multicast scouting off, connect to :data:`DEFAULT_ENDPOINT`;
    with ``$INVENT_ZENOH_LOWLATENCY=1`` also the :data:`LOW_LATENCY` transport. A zenoh config
    ``file`` (``--zenoh-config``), else one named by ``$ZENOH_CONFIG``, replaces the default;
    ``connect`` endpoints override either's. A peer listens on :data:`LOOPBACK_LISTEN` plus any
    ``listen`` endpoints (unless its file names its own); a router on ``listen``, else its file's
    or :data:`DEFAULT_ENDPOINT`; a client listens on nothing unless told. A file that zenoh cannot
    read is a :class:`ConfigError`. ``timestamping`` turns on zenoh's timestamps on what the
    session publishes (a router's are on by zenoh's default).
    """
    connect, listen = list(connect), list(listen)
    path = file or os.environ.get(ZENOH_CONFIG_VARIABLE)
    if path:
        try:
            config = zenoh.Config.from_file(path)
        except zenoh.ZError as error:
            raise ConfigError(f"zenoh config {path}: {error}") from None
    else:
        config = zenoh.Config()
        config.insert_json5("mode", json.dumps(mode))
        config.insert_json5("scouting/multicast/enabled", "false")
        if mode == "router":
            listen = listen or [DEFAULT_ENDPOINT]
            # With multicast scouting off a router has nothing to scout: don't wait 0.5 s for it.
            config.insert_json5("scouting/delay", "0")
        else:
            connect = connect or [DEFAULT_ENDPOINT]
        if os.environ.get(LOW_LATENCY_VARIABLE) == "1":
            for path_in_config, value in LOW_LATENCY.items():
                config.insert_json5(path_in_config, value)
    if json.loads(config.get_json("mode")) == "peer" and not _listens_explicitly(config):
        listen = [LOOPBACK_LISTEN, *listen]
    if timestamping:
        config.insert_json5("timestamping/enabled", "true")
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    return config


def _listens_explicitly(config: zenoh.Config) -> bool:
    """False while ``listen/endpoints`` is zenoh's default, a table by mode whose peer entry is
    every interface (``tcp/[::]:0``)."""
    return isinstance(json.loads(config.get_json("listen/endpoints")), list)


def has_match(entity: zenoh.Publisher | zenoh.Querier) -> bool:
    """Whether ``entity`` has a subscriber (publisher) or queryable (querier) now."""
    # zenoh-python 1.10's stub types matching_status as bool; it returns a MatchingStatus.
    status: Any = entity.matching_status
    return bool(status.matching)


ROUTER_LISTENING = "listening on"
"""What ``invent router`` prints once its session is open, so listening (``invent up`` waits for it)."""


@contextmanager
def open_session(config: zenoh.Config) -> Iterator[zenoh.Session]:
    try:
        session = zenoh.open(config)
    except zenoh.ZError as error:
        endpoints = json.loads(config.get_json("connect/endpoints"))
        if "listener" in str(error):
            listen = json.loads(config.get_json("listen/endpoints"))
            raise SessionFailed(
                f"cannot listen on {', '.join(map(str, listen)) if isinstance(listen, list) else listen}: "
                f"{str(error).split(' at ')[0]} (another router or program has the port: --listen another)"
            ) from None
        raise SessionFailed(
            f"cannot open a zenoh session connecting to {', '.join(map(str, endpoints)) or 'nothing'}: "
            f"{str(error).split(' at ')[0]} (is the router running, and are the credentials right?)"
        ) from None
    try:
        yield session
    finally:
        session.close()


SHUTDOWN_WATCHDOG_S = 8.0
"""How long a service may take to shut down once signalled, under ``invent up``'s wait for its
children (``STOP_TIMEOUT_S``, 10 s) so that a hung one says where before it is killed."""


def stop_on_signals(shutdown_watchdog_s: float | None = None) -> threading.Event:
    """An event set by SIGINT or SIGTERM (the service then shuts down cleanly, exit 0).

    ``shutdown_watchdog_s``: a process still alive that long after the signal prints every thread's
    stack to stderr (``Timeout (0:00:08)!`` and the tracebacks) and exits 1. The watchdog is
    faulthandler's own thread, which needs neither the GIL nor the main thread: a shutdown stuck in
    native code (a session's close, a server's stop) ends too, and says where it was stuck.

    Only the first signal sets it. Python runs a signal's handler between two bytecodes of the
    main thread, so a second signal (SIGTERM, then SIGINT from an impatient supervisor) can run
    its handler inside the first one's ``Event.set``, which holds the event's lock: setting it
    again there would wait for that lock for ever (seen: a service hung on stop, its stack two
    handlers deep in ``Event.set``)."""
    stop = threading.Event()
    signalled = False

    def handle(_signum: int, _frame: object) -> None:
        nonlocal signalled
        if signalled:
            return
        signalled = True
        if shutdown_watchdog_s is not None:
            faulthandler.dump_traceback_later(shutdown_watchdog_s, exit=True)
        stop.set()

    signal.signal(signal.SIGINT, handle)
    signal.signal(signal.SIGTERM, handle)
    return stop


EPHEMERAL_PORTS = Path("/proc/sys/net/ipv4/ip_local_port_range")
LOWEST_CHOSEN_PORT = 10_000


def free_port() -> int:
    """A TCP port free on loopback now, for a router to listen on (the tests', the benchmarks'),
    taken below the kernel's ephemeral range: a port the kernel hands out itself (``bind`` to port
    0, as every zenoh peer's loopback listener does, or a connection's source port) can be taken by
    any session opened between this choice and the router's bind, which makes the router exit 1
    ("address already in use"). Above the range only where it leaves no room below."""
    try:
        low = int(EPHEMERAL_PORTS.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        low = LOWEST_CHOSEN_PORT
    for _ in range(100):
        port = random.randrange(LOWEST_CHOSEN_PORT, low) if low > LOWEST_CHOSEN_PORT + 1000 else 0
        with socket.socket() as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(probe.getsockname()[1])
    raise OSError("no free TCP port on 127.0.0.1")
