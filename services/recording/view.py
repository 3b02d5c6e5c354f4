"""``invent view``: the running robot, live in Foxglove, over a Foxglove WebSocket server.

What it serves is what ``invent record`` writes (services/recording/mcap_files.py), live: the loop of
:class:`services.recording.record.Observer` takes every sample of ``invent/<robot>/**`` and the services'
status replies every 0.5 s, and hands them, with the robot's Foxglove scene
(:mod:`services.recording.scene`), to :class:`FoxgloveChannels`:

- one channel per zenoh key, named by the key, JSON messages as published, with the JSON schema
  of the key's message type (named ``TimedDoubleSeq``, ``TimedPosition``, ..., the schema a
  recording holds; a status reply's: its service's status Struct, ``MotorStatus``, ...); other
  keys (a user service's own) schemaless JSON;
- ``/tf``, ``/odometry/pose``, ``/localization/pose``, ``/scene``, ``/scan`` in Foxglove's
  well-known (protobuf) schemas, and ``/plot/wheel_speeds`` as JSON of ``WHEEL_SPEEDS_SCHEMA``.

A sample of a project key that does not decode as its type, or that the scene refuses, is bad
input: dropped (neither on its key's channel nor in the scene), logged once a second per key and
counted in the view's status (``bad_input``), as a service does.

A channel is advertised when its first message comes. ``log_time`` is when the sample was
received, as in a recording (what Foxglove's live timeline shows); a message's own stamp is
simulation time.

The server is foxglove-sdk's: it speaks the Foxglove WebSocket protocol under its current
subprotocol name, ``foxglove.sdk.v1``, which Foxglove and Lichtblick (since v1.22.1) offer; a
client that offers only the old name, ``foxglove.websocket.v1`` (older Lichtblick, old Foxglove
Studio, the ``@foxglove/ws-protocol`` client library 0.8.0), is refused (HTTP 400). Each
view has its own :class:`foxglove.Context`, so its channels and server share nothing with any
other view or Foxglove sink in the same process. ``docs/foxglove/layout.json`` is a layout for it.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Sequence
from typing import Any

import foxglove
import msgspec
import zenoh

from schemas.codec import ENCODING
from schemas.keys import VIEW, Keys
from schemas.status import ViewStatus
from services.config import Config
from services.exits import ExitStatus
from services.recording.mcap_files import JSON, JSON_SCHEMA, key_json_schema
from services.recording.record import TAKE_PERIOD_S, Observer, writer_sink
from services.runtime.logs import BadInputCounter

log = logging.getLogger("invent.view")

DEFAULT_HOST = "127.0.0.1"
"""Loopback, where every service listens unless told: ``--host 0.0.0.0`` serves other machines (a container)."""
DEFAULT_PORT = 8765
"""Foxglove's default port for a Foxglove WebSocket connection."""
"""``run_view``'s exit code when the server cannot listen (the port is taken, no such address)."""


def _foxglove_schema(name: str, encoding: str, data: bytes) -> foxglove.Schema:
    return foxglove.Schema(name=name, encoding=encoding, data=data)


class FoxgloveChannels:
    """The channels of one view, on its own ``context``, created on their first message; written
    as an MCAP file is (:class:`services.recording.record.SceneWriter`), for every client of the server."""

    def __init__(self, context: foxglove.Context) -> None:
        self._context = context
        self._channels: dict[str, foxglove.Channel] = {}
        self.messages = 0

    def write_sample(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """A zenoh sample, as published, on the channel of its key."""
        channel = self._channels.get(key)
        if channel is None:
            schema = key_json_schema(key)
            channel = self._channel(key, None if schema is None else _foxglove_schema(*schema), JSON)
        self._log(channel, payload, log_time_ns)

    def write_json(self, topic: str, value: Any, schema: dict[str, Any], stamp_ns: int, log_time_ns: int) -> None:
        """A JSON message of ``schema`` (a JSON schema with a ``title``) on ``topic``."""
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channel(
                topic, _foxglove_schema(schema["title"], JSON_SCHEMA, json.dumps(schema).encode()), JSON
            )
        self._log(channel, json.dumps(value).encode(), log_time_ns)

    def write_foxglove(self, topic: str, message: Any, stamp_ns: int, log_time_ns: int) -> None:
        """A Foxglove well-known message (``foxglove.messages``), protobuf-encoded."""
        channel = self._channels.get(topic)
        if channel is None:
            schema = message.get_schema()
            channel = self._channel(topic, schema, schema.encoding)
        self._log(channel, message.encode(), log_time_ns)

    @property
    def count(self) -> int:
        return len(self._channels)

    def _channel(self, topic: str, schema: foxglove.Schema | None, encoding: str) -> foxglove.Channel:
        """A new channel (advertised to every client); no ``schema``: schemaless JSON."""
        channel = foxglove.Channel(topic, schema=schema, message_encoding=encoding, context=self._context)
        self._channels[topic] = channel
        return channel

    def _log(self, channel: foxglove.Channel, data: bytes, log_time_ns: int) -> None:
        channel.log(data, log_time=log_time_ns)
        self.messages += 1

    def close(self) -> None:
        """Unadvertise every channel."""
        for channel in self._channels.values():
            channel.close()
        self._channels.clear()


STATUS_QUERIES = 16
"""Status queries waiting for the view's loop; beyond, the oldest is dropped (its asker gets no
reply) and zenoh's thread never waits."""


def _answer_status(
    queries: zenoh.Queryable,
    keys: Keys,
    url: str,
    started: float,
    channels: FoxgloveChannels,
    bad_input: BadInputCounter,
) -> None:
    """Answer the status queries that wait, from the view's own loop (never in zenoh's callback):
    read-only, so a wildcard query (``invent/*/*/status``) gets it too."""
    while (query := queries.try_recv()) is not None:
        try:
            status = ViewStatus(
                service=VIEW,
                robot=keys.robot,
                uptime_s=round(time.monotonic() - started, 3),
                url=url,
                channels=channels.count,
                messages=channels.messages,
                bad_input=bad_input.status(),
            )
            query.reply(keys.view_status, msgspec.json.encode(status), encoding=zenoh.Encoding(ENCODING))
        finally:
            query.drop()


def run_view(
    session: zenoh.Session,
    keys: Keys,
    config: Config,
    stop: threading.Event,
    host: str,
    port: int,
    fleet: Sequence[Config] = (),
) -> int:
    """Serve the robot of ``keys`` (or every robot of ``fleet``: their descriptions) on
    ws://``host``:``port`` (port 0: any free port) until ``stop``; ``ExitStatus.FAILURE`` when the
    server cannot listen there."""
    context = foxglove.Context()
    channels = FoxgloveChannels(context)
    try:
        server = foxglove.start_server(name=f"invent {keys.robot}", host=host, port=port, context=context)
    except RuntimeError as error:  # foxglove-sdk's FoxgloveError: the address is taken, or no such host
        log.error("cannot serve on %s:%d: %s", host, port, error)
        return ExitStatus.FAILURE
    url = f"ws://{host}:{server.port}"
    started = time.monotonic()
    observer: Observer | None = None
    bad_input = BadInputCounter(VIEW)
    status_queries = session.declare_queryable(keys.view_status, zenoh.handlers.RingChannel(STATUS_QUERIES))
    try:
        watched = [Keys(robot.robot.name).everything for robot in fleet] or [keys.everything]
        observer = Observer(session, keys, watched, config, writer_sink(channels), fleet, bad_input)
        log.info("Foxglove live view on %s (open Foxglove → Open connection → Foxglove WebSocket)", url)
        while not stop.is_set():
            _answer_status(status_queries, keys, url, started, channels, bad_input)
            if observer.spin_once():
                stop.wait(TAKE_PERIOD_S)
    finally:
        status_queries.undeclare()
        server.stop()
        if observer is not None:
            observer.close()
        channels.close()
    log.info("served %d messages of %s", channels.messages, ", ".join(watched))
    return 0
