"""A run's report from its recording (``invent up``'s ``run.mcap``, ``invent record``'s): the series
and the run's summary (``up/run``) read from its messages, ``report.json`` and the plots written
(services/recording/report.py computes them). No zenoh here.

Any recording is reported, cut short or not: a file cut mid-chunk is read up to its last whole
chunk, and a run with no summary (it did not end cleanly: ``up`` itself killed, or a recording
of ``invent record``) has its health from the last status replies recorded; the report's
``missing`` says what it lacks.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from schemas.codec import BadInput, decode
from schemas.keys import Keys, Service, UserServiceName, parse_data_key
from schemas.messages import (
    PlannedPath,
    RunSummary,
    ScenarioOutcome,
    ServiceRestart,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)
from schemas.navigation import GoalFeedback, GoalTarget
from schemas.status import ServiceStatus, SimStatus
from schemas.topics import Topic
from services.config import Config, ConfigError, InputConfig, RobotConfig
from services.drive.scenarios import planned_path_for
from services.planar import Pose, check_coordinates
from services.recording.goal_report import goal_results
from services.recording.mcap_files import (
    RECORDING_ROTATED_TOPIC,
    RECORDING_STOPPED_TOPIC,
    ReadResult,
    RecordedMessage,
    read_run,
)
from services.recording.report import (
    Point,
    Recording,
    build_report,
    early_outcome,
    missing_parts,
    pose_from_body_pose,
    readable_status,
    recorded_health,
    restart_degradation,
    write_plots,
    write_report,
)


def run_summary(messages: list[RecordedMessage], keys: Keys) -> RunSummary | None:
    """The last ``up/run`` summary of ``keys.robot`` in a recording, if it has one."""
    summaries = decoded(messages, keys.run_summary, RunSummary)
    return summaries[-1] if summaries else None


def recording_from(
    messages: list[RecordedMessage], keys: Keys, robot: RobotConfig, limits: InputConfig, until_s: float | None
) -> Recording:
    """The series a report is built from, sorted by time, cut at ``until_s`` simulated seconds when given.
    A message that does not decode, or an implausible pose (someone's bad input on a recorded key,
    which the services refuse too), is not part of the run."""

    def series(topic: Topic, message_type: type[Any], convert: Any) -> list[Any]:
        key = keys.topic(topic)
        items = []
        for recorded in messages:
            if recorded.topic != key:
                continue
            try:
                message = decode(message_type, recorded.data)
                item = (message.tm.to_seconds(), convert(message))
            except (BadInput, IndexError):
                continue
            if until_s is None or item[0] <= until_s:
                items.append(item)
        items.sort(key=lambda item: item[0])
        return items

    def position(message: TimedPosition) -> Pose:
        check_coordinates(message.x, message.y, limits.max_coordinate)
        return Pose(message.x, message.y, message.theta)

    def wheels(message: TimedDoubleSeq) -> tuple[float, float]:
        return message.data[robot.left_wheel_id], message.data[robot.right_wheel_id]

    def command(message: TimedVelocity) -> tuple[float, float]:
        return message.vx, message.w

    return Recording(
        ground_truth=series(Topic.SIM_BODY_POSE, TimedDoubleSeq, lambda m: pose_from_body_pose(m.data)),
        odometry=series(Topic.ODOMETRY_POSE, TimedPosition, position),
        localization=series(Topic.LOCALIZATION_POSE, TimedPosition, position),
        commands=[(t, *c) for t, c in series(Topic.DRIVE_TARGET_VELOCITY, TimedVelocity, command)],
        wheel_angles=[(t, *w) for t, w in series(Topic.MOTOR_WHEEL_ANGLES, TimedDoubleSeq, wheels)],
    )


def _planned_path(
    summary: RunSummary | None, messages: list[RecordedMessage], keys: Keys, recording: Recording
) -> list[Point] | None:
    """The scenario's path from the ground truth's start (as the drive planned it from its own
    pose), or, for a scenario file no longer there or a run with no summary, the path the drive published."""
    if summary is not None:
        try:
            return planned_path_for(summary.scenario, recording.ground_truth[0][1] if recording.ground_truth else None)
        except ConfigError:
            pass  # the scenario's file is no longer there
    paths = decoded(messages, keys.drive_path, PlannedPath)
    return paths[-1].points if paths else None


def write_run_report(path: Path, report_dir: Path, config: Config) -> tuple[dict[str, Any], Path, list[Path]]:
    """``report.json`` and the plots of the run recorded in ``path`` (``invent up`` writes that
    file; ``invent report`` reads any, cut short or without its summary: the report says what it
    lacks): (report, its path, the plots' paths). ConfigError when the file is not a recording."""
    report, recording = robot_report(path, read_run(path), config)
    report_path = write_report(report, report_dir)
    plots = write_plots(recording, report.get("planned_path"), config.geometry, report_dir, report["goals"])
    return report, report_path, plots


def robot_report(path: Path, read: ReadResult, config: Config) -> tuple[dict[str, Any], Recording]:
    """The report of robot ``config.robot.name`` in the run recorded in ``path`` (``read``), and the
    series it is built from. Without the run's summary (``up/run``: a run that did not end
    cleanly, or ``invent record``'s) the loop's health is taken from the last status replies
    recorded; ``missing`` says what the report lacks. ConfigError when the file holds other
    robots' keys but none of this one's (``--robot`` names another)."""
    messages, keys = read.messages, Keys(config.robot.name)
    _check_robot_recorded(path, messages, keys)
    summary = run_summary(messages, keys)
    statuses = {} if summary else recorded_statuses(messages, keys)
    sim = statuses.get(str(Service.SIM))
    sim_status = sim[0] if sim is not None and isinstance(sim[0], SimStatus) else None
    until_s = summary.tm.to_seconds() if summary else None
    recording = recording_from(messages, keys, config.robot, config.input, until_s)
    targets = decoded(messages, keys.drive_goal, GoalTarget)
    report = build_report(
        recording,
        scenario=summary.scenario if summary else None,
        mode=summary.mode if summary else None if sim_status is None else sim_status.mode,
        # goal mode: no one planned path (each goal's is the straight line to it: its path_error_max_m)
        planned_path=None if targets else _planned_path(summary, messages, keys, recording),
        wall_time_s=summary.wall_time_s if summary else None,
        steps=summary.steps if summary else None if sim_status is None else sim_status.steps,
        health=summary.health if summary else recorded_health(statuses),
    )
    report["composed"] = summary.composed if summary else None
    report["restarts"] = restart_entries(summary.restarts if summary else ())
    report["degraded"] += [restart_degradation(restart) for restart in report["restarts"]]
    report["outcome"] = (
        early_outcome(summary.ended_early, summary.service, summary.exit_code, summary.tm.to_seconds())
        if summary and summary.ended_early
        else scenario_outcome(messages, keys)
    )
    report["goals"] = goal_results(
        targets,
        decoded(messages, keys.drive_goal_feedback, GoalFeedback),
        decoded(messages, keys.drive_outcome, ScenarioOutcome),
        recording.ground_truth,
    )
    report["recording"] = recording_bounds(messages)
    report["rotated"] = recording_rotation(messages)
    report["missing"] = missing_parts(
        complete=read.complete,
        summary=summary is not None,
        outcome=report["outcome"] is not None,
        statuses=bool(statuses),
        ground_truth=bool(recording.ground_truth),
    )
    return report, recording


def restart_entries(restarts: Sequence[ServiceRestart]) -> list[dict[str, Any]]:
    """``report.json``'s ``restarts``: each service the restart policy started again, how it had
    ended (as a service that died is named) and when."""
    entries = []
    for restart in restarts:
        died = early_outcome("service_died", restart.service, restart.exit_code, 0.0)
        how = {key: died[key] for key in ("service", "reason", "exit_code", "signal")}
        entries.append({**how, "wall_s": restart.wall_s, "delay_s": restart.delay_s})
    return entries


def _check_robot_recorded(path: Path, messages: list[RecordedMessage], keys: Keys) -> None:
    """ConfigError when the recording holds keys of other robots but none of ``keys.robot``'s."""
    robots = {parsed[0] for message in messages if (parsed := parse_data_key(message.topic)) is not None}
    if robots and keys.robot not in robots:
        found = ", ".join(sorted(robots))
        raise ConfigError(f"--robot {keys.robot}: {path} holds no keys of this robot; robots recorded: {found}")


def recorded_statuses(messages: list[RecordedMessage], keys: Keys) -> dict[str, tuple[ServiceStatus, dict[str, Any]]]:
    """Each service's last readable status reply recorded on ``<service>/status`` (the view's left
    out; :func:`readable_status`), by name: what a recording without its run's summary tells of the
    loop's health."""
    statuses: dict[str, tuple[ServiceStatus, dict[str, Any]]] = {}
    prefix, suffix = f"{keys.prefix}/", "/status"
    for message in messages:
        name = message.topic.removeprefix(prefix).removesuffix(suffix)
        if "/" not in name and message.topic == keys.status(UserServiceName(name)) != keys.view_status:
            readable = readable_status(name, message.data)
            if readable is not None:
                statuses[name] = readable
    return statuses


def decoded(
    messages: list[RecordedMessage], key: str, message_type: type[Any], check: Callable[[Any], Any] = lambda m: m
) -> list[Any]:
    """Every message recorded on ``key`` that decodes as ``message_type`` and passes ``check``, in
    recorded order (one that does not is someone's bad input, not part of the run)."""
    found = []
    for message in messages:
        if message.topic == key:
            try:
                found.append(check(decode(message_type, message.data)))
            except BadInput:
                continue
    return found


def recording_bounds(messages: list[RecordedMessage]) -> dict[str, Any] | None:
    """Why the recording stopped before its run ended (None: it holds the whole run)."""
    stops = [m for m in messages if m.topic == RECORDING_STOPPED_TOPIC]
    return json.loads(stops[0].data) if stops else None


def recording_rotation(messages: list[RecordedMessage]) -> dict[str, Any] | None:
    """What a recording that kept the newest removed and the span it covers (None: nothing removed)."""
    rotations = [m for m in messages if m.topic == RECORDING_ROTATED_TOPIC]
    return json.loads(rotations[-1].data) if rotations else None


def scenario_outcome(messages: list[RecordedMessage], keys: Keys) -> dict[str, Any] | None:
    """How the robot's scenario ended, from the drive's last ``drive/outcome`` (None: the run was
    interrupted, or has no scenario: ``--teleop``); in goal mode, the last goal's outcome, with its
    ``goal_id`` (every goal's is in ``report.json``'s ``goals``)."""
    outcomes = [m for m in messages if m.topic == keys.drive_outcome]
    if not outcomes:
        return None
    try:
        outcome = decode(ScenarioOutcome, outcomes[-1].data)
    except BadInput:
        return None
    return {
        "outcome": outcome.outcome,
        "reason": outcome.reason,
        "t_s": outcome.tm.to_seconds(),
        "iteration": outcome.iteration,
        "elapsed_s": outcome.elapsed_s,
        **({"goal_id": outcome.goal_id} if outcome.goal_id else {}),
    }
