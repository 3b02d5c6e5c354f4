"""``invent goto X Y [THETA]``: send the drive a goal (``drive/goal/send``), show its progress as it
goes (``drive/goal/feedback``) and exit with its outcome's code (``drive/outcome``); Ctrl-C (or
SIGTERM) cancels it (``drive/goal/cancel``) before exiting. What it prints and when, and the exit
statuses, are services/goto/core.py's; this module is its zenoh session (docs/protocol.md section 7.3).

One subscriber takes the goal's samples (``drive/goal``, ``drive/goal/feedback``, ``drive/outcome``),
so they come in the order the drive published them: zenoh runs two subscribers' callbacks in no set
order (seen here: an outcome queued before the feedback published before it). It is declared before
the goal is sent, but declarations propagate asynchronously and a subscriber cannot see whether the
drive's publishers match it: so whenever :data:`LATCHED_LOOK_S` of wall time pass with no sample of
the goal, the tool asks the latched ``drive/outcome`` for the last outcome, which is the goal's if it
ended meanwhile unseen. A drive whose liveliness token goes while the goal runs ends the tool (exit 1)."""

from __future__ import annotations

import argparse
import contextlib
import queue
import sys
import threading
import time
from typing import get_args

import zenoh

from schemas.codec import ENCODING, BadMessage, decode, encode
from schemas.keys import DEFAULT_ROBOT, Keys, Service
from schemas.messages import ScenarioOutcome
from schemas.navigation import CancelReply, CancelRequest, GoalFeedback, GoalFrame, GoalReply, GoalRequest, GoalTarget
from services.cli.flags import finite_number, positive_seconds, robot_name, session_from_args
from services.cli.tools import ask
from services.config import GoalsConfig
from services.exits import ExitStatus
from services.goto.core import Progress, accepted_line, cancel_line, goal_request, rejected_line
from services.runtime.session import open_session, stop_on_signals

DEFAULT_WAIT_S = 5.0
"""Wall seconds the tool waits for the drive to answer a goal or a cancel (``--wait``)."""
CANCEL_WAIT_S = 10.0
"""Wall seconds the tool waits, once it canceled the goal, for the goal's outcome."""
LATCHED_LOOK_S = 1.0
"""Wall seconds with no sample of the goal after which the tool asks the latched ``drive/outcome``."""
GONE_GRACE_S = 0.5
"""Wall seconds the tool still takes samples once the drive's token is gone (its last ones may come after)."""
GOALS = GoalsConfig()
"""The ``[goals]`` defaults, for the help (the drive applies its own description's)."""
ARRIVED_MAX = 1024
"""Samples the callbacks may queue ahead of the printing thread (feedback comes at 5 Hz)."""
_GONE = "gone"
"""What the liveliness subscriber queues when the drive's token is withdrawn."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("x", type=finite_number, metavar="X", help="the goal's x in --frame (m)")
    parser.add_argument("y", type=finite_number, metavar="Y", help="the goal's y in --frame (m)")
    parser.add_argument(
        "theta",
        type=finite_number,
        nargs="?",
        metavar="THETA",
        help="the heading to end at in --frame (rad; default: any heading, the goal ends where it arrives)",
    )
    parser.add_argument(
        "--robot", type=robot_name, default=DEFAULT_ROBOT, metavar="NAME", help=f"the robot (default {DEFAULT_ROBOT})"
    )
    parser.add_argument(
        "--frame",
        choices=get_args(GoalFrame),
        default="map",
        help="map (default): the world frame of odometry/pose; odom: the frame the robot started in, at its "
        "origin facing +x",
    )
    parser.add_argument(
        "--timeout",
        type=finite_number,
        metavar="S",
        help="the goal's time limit in simulated seconds (default: the drive's rule, drive.time_limit_factor x "
        "its planned duration + drive.time_limit_margin); past it the goal ends timed_out (exit 4)",
    )
    parser.add_argument(
        "--position-tolerance",
        type=finite_number,
        metavar="M",
        help=f"how close to (X, Y) the goal completes (m; default the drive's goals.position_tolerance, "
        f"{GOALS.position_tolerance:g})",
    )
    parser.add_argument(
        "--heading-tolerance",
        type=finite_number,
        metavar="RAD",
        help=f"how close to THETA the goal completes (rad; default the drive's goals.heading_tolerance, "
        f"{GOALS.heading_tolerance:g})",
    )
    parser.add_argument(
        "--wait",
        type=positive_seconds,
        default=DEFAULT_WAIT_S,
        metavar="S",
        help=f"wall seconds to wait for the drive to answer (default {DEFAULT_WAIT_S:g}); then exit 1 naming the key",
    )


def run(args: argparse.Namespace) -> int:
    stop = stop_on_signals()
    request = goal_request(
        args.x,
        args.y,
        args.theta,
        frame=args.frame,
        time_limit=args.timeout,
        position_tolerance=args.position_tolerance,
        heading_tolerance=args.heading_tolerance,
    )
    # Client mode, as the one-shot tools (docs/protocol.md section 11.4): everything through the
    # router, no route to set up with each peer as it is found (a --zenoh-config file says its own).
    with open_session(session_from_args(args, mode="client")) as session:
        return Goto(session, Keys(args.robot), args.wait, stop).run(request)


def _say(line: str) -> None:
    print(line, flush=True)


def _error(line: str) -> None:
    print(f"invent goto: {line}", file=sys.stderr, flush=True)


class Goto:
    """One goal sent to ``keys.robot``'s drive and followed to its end, on ``session``. Zenoh's
    callbacks only queue what arrives; the calling thread decodes and prints it."""

    def __init__(self, session: zenoh.Session, keys: Keys, wait_s: float, stop: threading.Event) -> None:
        self.session = session
        self.keys = keys
        self.wait_s = wait_s
        self.stop = stop
        self.arrived: queue.Queue[tuple[str, bytes]] = queue.Queue(ARRIVED_MAX)
        self._taken = {keys.drive_goal, keys.drive_goal_feedback, keys.drive_outcome}

    def _queue(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        if key in self._taken:  # not the drive's other keys (its 50 Hz targets)
            self._put((key, sample.payload.to_bytes()))

    def _liveliness(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            self._put((_GONE, b""))

    def _put(self, item: tuple[str, bytes]) -> None:
        # Bounded: a flood is dropped; the goal's outcome is then still found on the latched key.
        with contextlib.suppress(queue.Full):
            self.arrived.put_nowait(item)

    def run(self, request: GoalRequest) -> int:
        keys = self.keys
        # Declared before the goal is sent, so that its first samples are not missed.
        watching = [
            self.session.declare_subscriber(keys.under(Service.DRIVE), self._queue),
            self.session.liveliness().declare_subscriber(keys.alive(Service.DRIVE), self._liveliness),
        ]
        try:
            reply = self._send(request)
            if not isinstance(reply, GoalReply):
                return reply
            if not reply.accepted:
                _error(rejected_line(reply))
                return ExitStatus.FAILURE
            _say(accepted_line(keys.robot, reply, request))
            return self._follow(Progress(reply.id))
        finally:
            for entity in watching:
                entity.undeclare()

    def _send(self, request: GoalRequest) -> GoalReply | int:
        """The drive's reply to the goal, or the exit status when there is none (said): nothing
        answered, the reply was not a GoalReply, or Ctrl-C came before the goal was sent."""
        return ask(self.session, self.keys.drive_goal_send, request, GoalReply, self.wait_s, _error, _hint, self.stop)

    def _follow(self, progress: Progress) -> int:
        """Print the goal's progress until its outcome; cancel it on Ctrl-C and wait (bounded) for that outcome."""
        keys = self.keys
        quiet_since = time.monotonic()
        cancel_deadline: float | None = None
        gone_at: float | None = None
        while True:
            if gone_at is not None and time.monotonic() - gone_at > GONE_GRACE_S:
                _error(f"{keys.robot}'s drive is gone (its token withdrawn) before goal {progress.goal_id} ended")
                return ExitStatus.FAILURE
            if self.stop.is_set() and cancel_deadline is None:
                self._cancel(progress.goal_id)
                cancel_deadline = time.monotonic() + CANCEL_WAIT_S
            if cancel_deadline is not None and time.monotonic() > cancel_deadline:
                _error(f"no outcome of goal {progress.goal_id} within {CANCEL_WAIT_S:g} s of the cancel")
                return ExitStatus.FAILURE
            try:
                key, payload = self.arrived.get(timeout=0.1)
            except queue.Empty:
                if time.monotonic() - quiet_since < LATCHED_LOOK_S:
                    continue
                quiet_since = time.monotonic()
                latched = self._latched(keys.drive_outcome)
                if not latched:
                    continue
                key, payload = keys.drive_outcome, latched[0]
            if key == _GONE:
                gone_at = gone_at or time.monotonic()
                continue
            try:
                line, ours = self._take(progress, key, payload)
            except BadMessage:
                continue  # not the drive's: nothing to say of it
            if ours:
                quiet_since = time.monotonic()
            if line:
                _say(line)
            if progress.ending is not None:
                return progress.ending.status

    def _take(self, progress: Progress, key: str, payload: bytes) -> tuple[str | None, bool]:
        """What to print of a sample on ``key``, and whether it was of our goal."""
        keys = self.keys
        if key == keys.drive_goal_feedback:
            feedback = decode(GoalFeedback, payload)
            return progress.on_feedback(feedback, time.monotonic()), feedback.id == progress.goal_id
        if key == keys.drive_goal:
            target = decode(GoalTarget, payload)
            return progress.on_target(target), target.id == progress.goal_id
        outcome = decode(ScenarioOutcome, payload)
        ending = progress.on_outcome(outcome)
        return (ending.line if ending else None), outcome.goal_id == progress.goal_id

    def _latched(self, key: str) -> list[bytes]:
        """What the latched ``key`` last published (none before its first)."""
        return [reply.ok.payload.to_bytes() for reply in self.session.get(key, timeout=1.0) if reply.ok is not None]

    def _cancel(self, goal_id: str) -> None:
        """Ask the drive to cancel ``goal_id`` and say what it answered."""
        key = self.keys.drive_goal_cancel
        payload = encode(CancelRequest(id=goal_id))
        replies = list(self.session.get(key, payload=payload, encoding=zenoh.Encoding(ENCODING), timeout=self.wait_s))
        for reply in replies:
            result = reply.result
            if not isinstance(result, zenoh.Sample):
                _error(f"{key} replied with an error: {result.payload.to_string()}")
                return
            try:
                _say(cancel_line(goal_id, decode(CancelReply, result.payload.to_bytes())))
            except BadMessage as error:
                _error(f"{key} replied with what is not a CancelReply ({error})")
            return
        _error(f"nothing answered the cancel on {key} within {self.wait_s:g} s")


HELP = "send the drive a goal, show its progress, exit with its outcome (Ctrl-C cancels it)"
DESCRIPTION = (
    "Send the robot's drive (`invent drive --goals`, `invent up --goals`) a goal: the position (X, Y) and, "
    "with THETA, the heading to end at. Prints the goal's id (or why the drive rejected it: exit 1), its "
    "progress about once a second (distance remaining, simulated time elapsed, an estimate of the time left), "
    "and its outcome; exits 0 completed, 3 aborted, 4 timed out, 5 canceled (a newer goal preempts it). "
    "Ctrl-C or SIGTERM cancels the goal, waits for its outcome and exits 5. Nothing answering within --wait: "
    "exit 1 naming the key. In a secure deployment, connect as the operator "
    "(--zenoh-config operator.json5): the observer may not send goals."
)
GROUPS: tuple[str, ...] = ("connection",)


def _hint(matched: bool) -> str:
    """Why no drive may have answered a goal: the ACL, or no drive in goal mode."""
    if matched:
        return (
            "; in a secure deployment only the operator and the ROS 2 bridge may send goals (the router drops "
            "the others' unanswered)"
        )
    return "; a drive takes goals in goal mode (`invent drive --goals`, `invent up --goals`)"
