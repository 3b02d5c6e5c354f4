"""The sim bridge's start-up handshakes: before its first step, the services a run waits for
(``--wait-for``), the motor controls' subscriptions to the wheel angles, and (lockstep) each
participant's word that it sees this simulator, so that a run starts the same way every time."""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from schemas.keys import Service, ServiceName
from schemas.status import decode_status
from schemas.status_kinds import status_type
from services.runtime.executor import STOP_POLL_S
from services.runtime.node import Node
from sim_bridge.link import RobotLink

START_HANDSHAKE_TIMEOUT_S = 5.0
"""Lockstep: how long the first step waits for the participants to see this simulator."""


def await_motor_subscriptions(node: Node, links: Sequence[RobotLink], timeout_s: float) -> None:
    """Give the first wheel angles a subscriber to reach, so the first step does not time out."""
    deadline = time.monotonic() + timeout_s
    waiting = [link for link in links if link.torque.motor_alive]
    while any(not link.angles_publisher.matched for link in waiting) and time.monotonic() < deadline:
        node.spin_once(STOP_POLL_S / 10.0)


def await_services(
    node: Node, links: Sequence[RobotLink], wait_for: Sequence[ServiceName], stop: threading.Event
) -> None:
    """``--wait-for``: before the first step, until each named service of every robot is alive
    (a lockstep participant: holds its ticks token), so that the run starts the same way every time."""
    if not wait_for:
        return

    def missing() -> list[str]:
        return [
            f"{link.prefix}{service}"
            for link in links
            for service in wait_for
            if not (link.torque.motor_alive if service is Service.MOTOR else link.barrier.announced(service))
        ]

    deadline = time.monotonic() + START_HANDSHAKE_TIMEOUT_S * len(links)
    while missing() and time.monotonic() < deadline and not stop.is_set():
        node.spin_once(STOP_POLL_S)
    if missing():
        node.log.warning(
            "starting without %s: not there within %g s",
            ", ".join(missing()),
            START_HANDSHAKE_TIMEOUT_S * len(links),
        )


def await_participants(node: Node, links: Sequence[RobotLink]) -> None:
    """Before the first step, until each participant there from the start says it sees this
    simulator: a session this new has routes to a peer only once their declarations have
    crossed, and a participant that missed the first step's sample would miss its first tick.
    The thread keeps handling events meanwhile (composed, it serves those participants too)."""
    deadline = time.monotonic() + START_HANDSHAKE_TIMEOUT_S
    waiting = {
        (index, service)
        for index, link in enumerate(links)
        for service in (*link.barrier.waited_for(), *((Service.MOTOR,) if link.torque.motor_alive else ()))
    }
    asked: dict[tuple[int, ServiceName], Any] = {}
    while waiting and time.monotonic() < deadline:
        for index, service in waiting - set(asked):
            status = links[index].node.keys.status(service)
            links[index].node.declared.query(status)
            asked[index, service] = node.session.get(status, timeout=STOP_POLL_S)
        node.spin_once(STOP_POLL_S / 10.0)
        for participant, replies in list(asked.items()):
            try:
                reply = replies.try_recv()
            except zenoh.ZError:  # unanswered within its timeout: asked again
                del asked[participant]
                continue
            if reply is None:
                continue
            del asked[participant]  # answered: asked again unless it sees this simulator
            kind = status_type(participant[1])
            answered = None if reply.ok is None else decode_status(kind, reply.ok.payload.to_bytes())
            # every participant's kind says sim_alive; a bad reply is no answer: asked again
            if getattr(answered, "sim_alive", False) is True:
                waiting.discard(participant)
    if waiting:
        names = sorted(f"{links[index].prefix}{service}" for index, service in waiting)
        node.log.warning("%s did not see this simulator before its first step", ", ".join(names))
