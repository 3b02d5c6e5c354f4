"""The zenoh tools of the ``invent`` CLI: router, echo, call, status, secrets.

Each writes JSON lines to stdout (one per sample or reply) so that its output can be piped
to ``jq`` or read by tests, and errors as one line on stderr.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

import msgspec
import zenoh

from schemas.codec import ENCODING, BadMessage, decode, encode
from schemas.keys import Keys, all_robots_alive, schema_for_key
from services.config import ConfigError
from services.config.sections import LocalizationMode
from services.exits import ExitStatus
from services.ros2.graph import BridgeGraph
from services.runtime.discovery import payload_value, service_statuses
from services.runtime.session import ROUTER_LISTENING, has_match
from services.security import UserServiceGrant, write_fleet_profile, write_profile
from services.security.grants import DEFAULT_LOCALIZATION

MessageT = TypeVar("MessageT", bound=msgspec.Struct)


def _print_json(value: Any, stream=sys.stdout) -> None:
    stream.write(json.dumps(value, separators=(", ", ": ")) + "\n")
    stream.flush()


def describe_sample(key: str, payload: bytes) -> dict[str, Any]:
    """A sample as ``{"key", "value"}``: decoded with the key's schema, raw text for unknown keys.

    A payload that does not decode with its key's schema is shown as text with the reason.
    """
    schema = schema_for_key(key)
    if schema is None:
        return {"key": key, "value": payload.decode("utf-8", errors="replace")}
    try:
        return {"key": key, "value": msgspec.to_builtins(decode(schema, payload))}
    except BadMessage as error:
        return {"key": key, "value": payload.decode("utf-8", errors="replace"), "error": str(error)}


def run_router(session: zenoh.Session, listen: list[str], stop: threading.Event) -> int:
    """Serve as the zenoh router until SIGINT/SIGTERM."""
    print(
        f"invent router {session.zid()} {ROUTER_LISTENING} {', '.join(listen)}; Ctrl-C stops it",
        file=sys.stderr,
        flush=True,
    )
    while not stop.wait(0.2):
        pass
    return ExitStatus.OK


def run_secrets(
    directory: Path,
    keys: Keys,
    *,
    endpoint: str,
    router_listen: Sequence[str],
    tls: bool,
    tls_names: Sequence[str],
    seen_as: Path | None,
    router_base: str | None,
    ros: BridgeGraph,
    robots: Sequence[str] = (),
    user_services: Sequence[UserServiceGrant] = (),
    localization: LocalizationMode = DEFAULT_LOCALIZATION,
) -> int:
    """Write a secure deployment's profile (:func:`services.security.write_profile`) and say what is where;
    ``user_services`` (``--with``) get credentials of their own (one robot's profile only).

    With ``robots`` (``--robots``), a fleet's profile (:func:`services.security.write_fleet_profile`)
    for those robots in place of ``keys``'s one; ``ros`` then places each robot's bridge in the
    namespace ``<ros.namespace>/<robot>``. ``localization`` (``--localization-mode``): the mode the
    localization role (each robot's) is granted for."""
    try:
        base = _router_plugins(router_base) if router_base else None
        options: dict[str, Any] = {
            "endpoint": endpoint,
            "router_listen": router_listen,
            "tls": tls,
            "tls_names": tls_names,
            "seen_as": seen_as,
            "router_base": base,
            "ros": ros,
        }
        if robots:
            if user_services:
                raise ConfigError("--with with --robots: a fleet's profile has no user services yet")
            modes = dict.fromkeys(robots, localization)
            profile = write_fleet_profile(directory, robots, localization=modes, **options)
        else:
            profile = write_profile(directory, keys, user_services=user_services, localization=localization, **options)
    except ValueError as error:
        raise ConfigError(str(error)) from None
    fleet = f" for the fleet {', '.join(profile.robots)}" if profile.robots else ""
    print(f"invent secrets: wrote {profile.directory}{fleet} (clients connect to {profile.endpoint})", file=sys.stderr)
    print(f"  router:   invent router --config {profile.router_config}", file=sys.stderr)
    width = max(13, *(len(identity.user) + 1 for identity in profile.identities))
    for identity in profile.identities:
        path = profile.client_config(identity.role, identity.robot)
        print(f"  {identity.user + ':':<{width}} --zenoh-config {path}", file=sys.stderr)
    for name in profile.user_services:
        print(f"  {name + ':':<{width}} --zenoh-config {profile.user_service_config(name)}", file=sys.stderr)
    return ExitStatus.OK


def _router_plugins(path: str) -> dict[str, Any]:
    """The plugin sections of a zenoh router configuration file (JSON5, read by zenoh itself)."""
    try:
        config = zenoh.Config.from_file(path)
    except zenoh.ZError as error:
        raise ConfigError(f"--router-base {path}: {error}") from None
    loading = json.loads(config.get_json("plugins_loading"))
    return {"plugins_loading": {"enabled": loading["enabled"]}, "plugins": json.loads(config.get_json("plugins"))}


ECHO_CAPACITY = 1024
"""Samples ``invent echo`` holds before printing them: a full channel holds zenoh's receive back, so
a lockstep run waits for the printing (docs/protocol.md 2.6) and a realtime one drops at its publishers."""
ECHO_POLL_S = 0.01


def run_echo(session: zenoh.Session, key_expr: str, count: int | None, stop: threading.Event) -> int:
    """Print one JSON line per sample on ``key_expr``; stop after ``count`` samples if given."""
    with session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(ECHO_CAPACITY)) as samples:
        printed = 0
        while not stop.is_set() and (count is None or printed < count):
            sample = samples.try_recv()
            if sample is None:
                stop.wait(ECHO_POLL_S)
                continue
            _print_json(describe_sample(str(sample.key_expr), sample.payload.to_bytes()))
            printed += 1
    return ExitStatus.OK


def wait_for_match(querier: zenoh.Querier, timeout: float, stop: threading.Event | None = None) -> bool:
    """Whether something serves the querier's key within ``timeout`` s (False at once once ``stop`` is set)."""
    deadline = time.monotonic() + timeout
    while not has_match(querier):
        if time.monotonic() > deadline or (stop is not None and stop.is_set()):
            return False
        time.sleep(0.005)
    return True


def ask(
    session: zenoh.Session,
    key: str,
    request: msgspec.Struct,
    reply_type: type[MessageT],
    timeout: float,
    error: Callable[[str], None],
    hint: Callable[[bool], str],
    stop: threading.Event | None = None,
) -> MessageT | ExitStatus:
    """The reply to ``request`` on ``key`` as a ``reply_type``, or the exit status when there is
    none, said through ``error``: an error reply or one that does not decode (FAILURE); nothing
    answered within ``timeout`` s (FAILURE; why, then ``hint(matched)``: what may be wrong, knowing
    whether anything served the key); ``stop`` set before the request was sent (INTERRUPTED)."""
    querier = session.declare_querier(key, timeout=timeout)
    try:
        matched = wait_for_match(querier, timeout, stop)
        if stop is not None and stop.is_set():
            error(f"interrupted before the request on {key} was sent")
            return ExitStatus.INTERRUPTED
        replies = list(querier.get(payload=encode(request), encoding=zenoh.Encoding(ENCODING)))
    finally:
        querier.undeclare()
    answer = typed_reply(replies, key, reply_type, error)
    if answer is not None:
        return answer
    error(no_answer(session, key, matched, timeout) + hint(matched))
    return ExitStatus.FAILURE


def typed_reply(
    replies: Sequence[zenoh.Reply], key: str, message_type: type[MessageT], error: Callable[[str], None]
) -> MessageT | ExitStatus | None:
    """The first of ``replies`` to a method's query on ``key`` as a ``message_type``; FAILURE (said
    through ``error``) for an error reply or one that does not decode; None when nothing replied."""
    for reply in replies:
        result = reply.result
        if not isinstance(result, zenoh.Sample):
            error(f"{key} replied with an error: {result.payload.to_string()}")
            return ExitStatus.FAILURE
        try:
            return decode(message_type, result.payload.to_bytes())
        except BadMessage as bad:
            error(f"{key} replied with what is not a {message_type.__name__} ({bad})")
            return ExitStatus.FAILURE
    return None


def no_answer(session: zenoh.Session, key: str, matched: bool, timeout: float) -> str:
    """Why nothing answered: no connection at all, nothing serving ``key``, or no reply in time."""
    if not list(session.info.routers_zid()) and not list(session.info.peers_zid()):
        return (
            "this session reached no router and no peer: is a router listening where --connect points "
            "(and are the credentials right)?"
        )
    if not matched:
        return f"nothing answers on {key} (is the service running?)"
    return f"no reply from {key} within {timeout} s"


def run_call(session: zenoh.Session, key: str, payload: str | None, timeout: float) -> int:
    """Query ``key`` and print each reply; non-zero exit on ``reply_err`` or when nothing answers."""
    querier = session.declare_querier(key, timeout=timeout)
    try:
        # Matching says the declarations reached this session. It is never seen for a wildcard key
        # whose queryables are not complete (every `status`), so the query goes out anyway.
        matched = wait_for_match(querier, timeout)
        replies = 0
        failed = False
        for reply in querier.get(payload=payload, encoding=zenoh.Encoding(ENCODING) if payload else None):
            result = reply.result
            if isinstance(result, zenoh.Sample):
                _print_json({"key": str(result.key_expr), "value": payload_value(result.payload.to_bytes())})
                replies += 1
            else:
                error = payload_value(result.payload.to_bytes())
                print(f"invent call: {key} replied with an error: {json.dumps(error)}", file=sys.stderr)
                failed = True
        if not replies and not failed:
            print(f"invent call: {no_answer(session, key, matched, timeout)}", file=sys.stderr)
            return ExitStatus.FAILURE
        return ExitStatus.FAILURE if failed else ExitStatus.OK
    finally:
        querier.undeclare()


def run_status(session: zenoh.Session, robot: str | None, timeout: float) -> int:
    """Print the services alive and each one's status reply; non-zero exit when none is alive."""
    key_expr = Keys(robot).every_alive if robot else all_robots_alive()
    statuses = service_statuses(session, key_expr, timeout)
    if not statuses:
        print(f"invent status: no service alive on {key_expr}", file=sys.stderr)
        return ExitStatus.FAILURE
    for robot_name, service, _status, reply in statuses:
        _print_json({"robot": robot_name, "service": str(service), "alive": True, "status": reply})
    return ExitStatus.OK
