"""The run report of ``invent up``: metrics from a recording, plots, and a short summary.

Pure apart from writing files: :func:`build_report` turns recorded series into the
``report.json`` dictionary; :func:`write_plots` draws the trajectories and wheel speeds.
"""

from __future__ import annotations

import json
import math
import signal
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
from msgspec import UNSET, UnsetType

from schemas.drive_status import DriveNavigationStatus, DriveStatus
from schemas.keys import Service
from schemas.status import MotorStatus, ServiceStatus, SimCounters, SimStatus, decode_status
from schemas.status_kinds import status_type
from services.config import CalibratedGeometry
from services.drive.scenarios import distance_to_path
from services.motor.sim_pose import SimPoseConverter
from services.planar import Pose
from services.recording.goal_report import goal_lines

Point = tuple[float, float]


@dataclass
class Recording:
    """Time-stamped series of one run (time in simulated seconds)."""

    ground_truth: list[tuple[float, Pose]] = field(default_factory=list)
    odometry: list[tuple[float, Pose]] = field(default_factory=list)
    localization: list[tuple[float, Pose]] = field(default_factory=list)
    commands: list[tuple[float, float, float]] = field(default_factory=list)
    """(t, vx, w) target velocities."""
    wheel_angles: list[tuple[float, float, float]] = field(default_factory=list)
    """(t, left, right) wheel angles."""


_GROUND_TRUTH = SimPoseConverter()
"""The motor's conversion without offsets: the simulator's own frame is the axle centre."""


def pose_from_body_pose(data: list[float]) -> Pose:
    """x, y and heading of a ``sim/body_pose`` vector (x, y, z, rotation row-major)."""
    x, y, _z, theta = _GROUND_TRUTH(data)
    return Pose(x, y, theta)


def _pose_dict(pose: Pose | None) -> dict[str, float] | None:
    return None if pose is None else pose._asdict()


def odometry_errors(recording: Recording) -> list[float]:
    """Position error of each odometry pose against the ground truth at the same stamp."""
    truth = dict(recording.ground_truth)
    return [math.hypot(pose.x - truth[t].x, pose.y - truth[t].y) for t, pose in recording.odometry if t in truth]


def wheel_speeds(
    recording: Recording, geometry: CalibratedGeometry
) -> tuple[list[tuple[float, float, float]], list[tuple[float, float, float]]]:
    """(commanded, measured) wheel speeds in rad/s as (t, left, right) series; the commanded ones as
    the motor turns the commands into wheel speeds, with the calibrated ``geometry``."""
    left_radius, right_radius, b = geometry
    commanded = [(t, (vx - b * w) / left_radius, (vx + b * w) / right_radius) for t, vx, w in recording.commands]
    measured = [
        (t1, (l1 - l0) / (t1 - t0), (r1 - r0) / (t1 - t0))
        for (t0, l0, r0), (t1, l1, r1) in zip(recording.wheel_angles, recording.wheel_angles[1:])
        if t1 > t0
    ]
    return commanded, measured


def build_report(
    recording: Recording,
    *,
    scenario: str | None,
    mode: str | None,
    planned_path: list[Point] | None,
    wall_time_s: float | None,
    steps: int | None,
    health: dict[str, Any],
) -> dict[str, Any]:
    """``report.json``'s metrics; None for what the recording does not say (a run without its summary)."""
    sim_time_s = recording.ground_truth[-1][0] if recording.ground_truth else 0.0
    errors = odometry_errors(recording)
    report: dict[str, Any] = {
        "scenario": scenario,
        "mode": mode,
        "sim_time_s": sim_time_s,
        "wall_time_s": wall_time_s,
        "real_time_factor": sim_time_s / wall_time_s if wall_time_s else None,
        "steps": steps,
        "final": {
            name: _pose_dict(series[-1][1] if series else None)
            for name, series in (
                ("ground_truth", recording.ground_truth),
                ("odometry", recording.odometry),
                ("localization", recording.localization),
            )
        },
        "start": _pose_dict(recording.ground_truth[0][1] if recording.ground_truth else None),
        "odometry_error": {"max_m": max(errors, default=None), "final_m": errors[-1] if errors else None},
        "path_error": None,
        "bad_inputs": {name: counts["bad_inputs"] for name, counts in health["services"].items()},
        "health": health,
        "degraded": degradations(health),
    }
    if planned_path:
        deviations = [distance_to_path((pose.x, pose.y), planned_path) for _t, pose in recording.ground_truth]
        report["path_error"] = {
            "mean_m": sum(deviations) / len(deviations) if deviations else None,
            "max_m": max(deviations, default=None),
        }
        report["planned_path"] = [list(point) for point in planned_path]
    return report


DEGRADED_FRACTION = 0.01
"""A run whose late or missing torques exceed this fraction of its steps degraded."""


def loop_health(sim_status: SimStatus | None, statuses: Mapping[str, ServiceStatus | None]) -> dict[str, Any]:
    """What the loop actually did, from the services' last status replies: the sim's torque
    figures, the lockstep participants it dropped, the drive's ticks commanded from an older pose,
    and each service's bad-input, internal-error and dropped-event counts. A lockstep step is never
    late: it waits for its torque as long as the motor control lives (how long is the machine's, as
    the wall time, and not in the health)."""
    counters = SimCounters() if sim_status is None else sim_status.counters
    drive, motor = statuses.get(str(Service.DRIVE)), statuses.get(str(Service.MOTOR))
    steps = 0 if sim_status is None else sim_status.steps
    lockstep = sim_status is not None and sim_status.mode == "lockstep"
    late = 0 if lockstep else counters.realtime_late_steps
    missing = counters.missing_torques

    def fraction(count: int) -> float:
        return count / steps if steps else 0.0

    return {
        "torques": {
            "applied": counters.torques_applied,
            "late": late,
            "missing": missing,
            "stale": counters.stale_torques,
            "late_fraction": fraction(late),
            "missing_fraction": fraction(missing),
        },
        "lockstep": {
            "pose_wait_timeouts": _pose_wait_timeouts(drive) if lockstep else 0,
            "dropped_participants": msgspec.to_builtins(sim_status.dropped_participants)
            if sim_status is not None and lockstep
            else [],
        },
        "realtime": {"resyncs": counters.realtime_resyncs},
        "safety": {"bumps": counters.bumps, "collision_monitor_holds": _collision_monitor_holds(motor)},
        # not the scans taken: the drive's status is last read while it runs, a moment of the wall
        # clock; the late ones degrade a run, and are none in a lockstep run that did not
        "navigation": {"scans_late": _scans_late(drive) if lockstep else 0},
        "services": {
            name: {
                "bad_inputs": status.bad_input.total,
                "internal_errors": status.internal_errors,
                "dropped_events": status.dropped_events,
            }
            for name, status in statuses.items()
            if status is not None
        },
    }


def _pose_wait_timeouts(drive: ServiceStatus | None) -> int:
    """The drive's ticks commanded from an older pose (none from a user service that drives)."""
    timeouts = drive.pose_wait_timeouts if isinstance(drive, DriveStatus) else UNSET
    return 0 if isinstance(timeouts, UnsetType) else timeouts


def _scans_late(drive: ServiceStatus | None) -> int:
    """The scans that reached the drive after their tick (goal mode with navigation only)."""
    navigation = drive.navigation if isinstance(drive, DriveStatus) else None
    return navigation.scans_late if isinstance(navigation, DriveNavigationStatus) else 0


def _collision_monitor_holds(motor: ServiceStatus | None) -> int:
    counters = motor.collision_monitor.counters if isinstance(motor, MotorStatus) else UNSET
    return 0 if isinstance(counters, UnsetType) else counters.holds


def readable_status(name: str, payload: bytes) -> tuple[ServiceStatus, dict[str, Any]] | None:
    """A recorded status reply of service ``name`` as its kind's Struct and as a JSON object (a user
    service's own fields); None for one that does not decode (bad input on a status key)."""
    status = decode_status(status_type(name), payload)
    return None if status is None else (status, json.loads(payload))


def recorded_health(statuses: Mapping[str, tuple[ServiceStatus, dict[str, Any]]]) -> dict[str, Any]:
    """The loop's health as ``up`` takes it at a run's end, from the last readable status replies a
    recording holds (:func:`readable_status`): for a run without its summary. A service of one's
    own's status (not one of :class:`Service`) is also under ``user_services``, as ``up`` puts it."""
    typed = {name: status for name, (status, _reply) in statuses.items()}
    sim = typed.get(Service.SIM)
    health = loop_health(sim if isinstance(sim, SimStatus) else None, typed)
    users = {name: reply for name, (_status, reply) in statuses.items() if name not in Service._value2member_map_}
    if users:
        health["user_services"] = users
    return health


EARLY_ENDS = {
    "service_died": "a service died",
    "interrupted": "Ctrl-C or SIGTERM before the scenario ended",
}
"""The outcomes of a run that ended before its scenario did (``RunSummary.ended_early``), and what each means."""


def early_outcome(ended_early: str, service: str, exit_code: int | None, t_s: float) -> dict[str, Any]:
    """``report.json``'s ``outcome`` of a run that ended before its scenario did: which service
    died and how (its exit code, or the signal that killed it: negative ``exit_code``), or Ctrl-C."""
    if ended_early != "service_died":
        return {"outcome": ended_early, "reason": EARLY_ENDS.get(ended_early, ended_early), "t_s": t_s}
    killed_by = None
    if exit_code is not None and exit_code < 0:
        try:
            killed_by = signal.Signals(-exit_code).name
        except ValueError:  # no such signal here
            killed_by = f"signal {-exit_code}"
    how = f"killed by {killed_by}" if killed_by else f"exited with code {exit_code}"
    return {
        "outcome": ended_early,
        "reason": f"{service} {how}",
        "t_s": t_s,
        "service": service,
        "exit_code": None if killed_by else exit_code,
        "signal": killed_by,
    }


def missing_parts(*, complete: bool, summary: bool, outcome: bool, statuses: bool, ground_truth: bool) -> list[str]:
    """What a report lacks, one line each, from what its recording holds (empty: nothing)."""
    missing = []
    if not complete:
        missing.append("the file was cut short: its last, unfinished chunk of messages (and its index) is lost")
    if not summary:
        known = [
            "the outcome is the drive's last" if outcome else "outcome unknown",
            "wall time unknown",
            "the loop's health from the last status replies recorded" if statuses else "the loop's health unknown",
        ]
        missing.append(f"no run summary: the run did not end cleanly; {', '.join(known)}")
    if not ground_truth:
        missing.append("no ground truth (sim/body_pose): no final pose, no odometry or path error")
    return missing


def degradations(health: dict[str, Any]) -> list[str]:
    """Why a run degraded, one reason each (empty for a clean run)."""
    torques, reasons = health["torques"], []
    for kind in ("late", "missing"):
        if torques[f"{kind}_fraction"] > DEGRADED_FRACTION:
            reasons.append(
                f"{kind} torques on {torques[f'{kind}_fraction']:.1%} of the steps ({torques[kind]}; "
                f"more than {DEGRADED_FRACTION:.0%})"
            )
    for dropped in health["lockstep"].get("dropped_participants", []):  # .get: absent from older recordings
        reasons.append(f"{dropped['service']} dropped at t = {dropped['sim_time_s']:.3f} s (its token went first)")
    if pose_waits := health["lockstep"].get("pose_wait_timeouts", 0):  # .get: absent from older recordings
        reasons.append(
            f"{pose_waits} drive ticks commanded from an older pose (odometry's pose "
            "of the tick did not come within sim.lockstep_timeout)"
        )
    # .get: recordings made before the navigation have no such field.
    if late_scans := health.get("navigation", {}).get("scans_late", 0):
        reasons.append(
            f"{late_scans} scans reached the drive after the tick that should have taken them into its costmap"
        )
    for name, counts in health["services"].items():
        for counter in ("internal_errors", "dropped_events"):
            if counts[counter]:
                reasons.append(f"{name}: {counts[counter]} {counter.replace('_', ' ')}")
    return reasons


def restart_degradation(restart: dict[str, Any]) -> str:
    """A restart (``report.json``'s ``restarts``) as a reason the run degraded: a service failed."""
    return f"{restart['service']} was started again ({restart['reason']}, {restart['wall_s']:.1f} s into the run)"


def restarts_line(restarts: Sequence[dict[str, Any]]) -> str:
    """``restarts: 2 (motor, motor)``: how many, and which service each started again."""
    return f"restarts: {len(restarts)} ({', '.join(restart['service'] for restart in restarts)})"


def degradation_line(reason: str) -> str:
    return f"WARNING: the run degraded: {reason}"


def health_lines(health: dict[str, Any]) -> list[str]:
    torques = health["torques"]
    services = health["services"]
    return [
        (
            f"torques: late {torques['late']} ({torques['late_fraction']:.2%}), missing {torques['missing']} "
            f"({torques['missing_fraction']:.2%}), stale {torques['stale']}; "
            f"realtime resyncs {health['realtime']['resyncs']}"
        ),
        "bad inputs: " + ", ".join(f"{name} {counts['bad_inputs']}" for name, counts in services.items()),
        "internal errors: " + ", ".join(f"{name} {counts['internal_errors']}" for name, counts in services.items()),
    ]


def rotated_line(rotated: dict[str, Any]) -> str:
    """What a recording that kept the newest removed, and the span it covers (``report.json``'s ``rotated``)."""
    return (
        f"record.keep = newest: {len(rotated['dropped_files'])} older files removed ({rotated['dropped_mb']} MB); "
        f"the recording covers {rotated['from_s'] or 0:.1f} s to {rotated['to_s'] or 0:.1f} s of simulation time"
    )


def summary(report: dict[str, Any]) -> str:
    """A few lines for the terminal at the end of a run."""

    def metres(value: float | None) -> str:
        return "n/a" if value is None else f"{value * 100:.1f} cm"

    final, start = report["final"]["ground_truth"], report["start"]
    wall = report["wall_time_s"]
    lines = [
        (
            f"scenario {report['scenario'] or '(unknown)'} ({report['mode'] or 'mode unknown'}): "
            f"{report['sim_time_s']:.2f} s simulated in "
            + (
                f"{wall:.2f} s wall, {report['real_time_factor'] or 0:.2f}x real time"
                if wall is not None
                else "an unknown wall time"
            )
            + f", {report['steps'] if report['steps'] is not None else 'unknown'} steps"
        ),
    ]
    lines += [f"missing: {line}" for line in report.get("missing") or ()]
    if rotated := report.get("rotated"):
        lines.append(rotated_line(rotated))
    if outcome := report.get("outcome"):
        lines.append(f"outcome: {outcome['outcome']}" + (f" ({outcome['reason']})" if outcome["reason"] else ""))
    lines += goal_lines(report.get("goals") or [])
    if restarts := report.get("restarts"):
        lines.append(restarts_line(restarts))
    if final and start:
        lines.append(
            f"ground truth ends at ({final['x']:.3f}, {final['y']:.3f}, {math.degrees(final['theta']):.1f} deg), "
            f"{metres(math.hypot(final['x'] - start['x'], final['y'] - start['y']))} from the start"
        )
    lines.append(
        f"odometry error max {metres(report['odometry_error']['max_m'])}, final {metres(report['odometry_error']['final_m'])}"
    )
    if report["path_error"]:
        lines.append(
            f"path error mean {metres(report['path_error']['mean_m'])}, max {metres(report['path_error']['max_m'])}"
        )
    lines += health_lines(report["health"])
    lines += map(degradation_line, report["degraded"])
    return "\n".join(lines)


def write_report(report: dict[str, Any], directory: Path) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "report.json"
    path.write_text(json.dumps(report, indent=2) + "\n")
    return path


def _downsample(series: list[Any], limit: int = 4000) -> list[Any]:
    step = max(1, len(series) // limit)
    return series[::step]


def write_plots(
    recording: Recording,
    planned_path: list[Point] | None,
    geometry: CalibratedGeometry,
    directory: Path,
    goals: Sequence[dict[str, Any]] | None = None,
) -> list[Path]:
    """``trajectory.png`` (ground truth, odometry, localization, planned path, the goals of a goal-mode
    run: ``report.json``'s ``goals``) and ``wheel_speeds.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    figure, axes = plt.subplots(figsize=(7, 7))
    if planned_path:
        xs, ys = zip(*planned_path)
        axes.plot(xs, ys, "k--", linewidth=1, label="planned path")
    for name, series, width in (("ground truth", recording.ground_truth, 4.0), ("odometry", recording.odometry, 1.2)):
        points = _downsample(series)
        if points:
            axes.plot([p[0] for _t, p in points], [p[1] for _t, p in points], linewidth=width, alpha=0.8, label=name)
    if recording.localization:
        axes.plot(
            [p[0] for _t, p in recording.localization],
            [p[1] for _t, p in recording.localization],
            "o",
            label="localization fixes",
        )
    posed = [goal for goal in goals or () if goal["pose"] is not None]
    if posed:
        axes.plot([g["pose"]["x"] for g in posed], [g["pose"]["y"] for g in posed], "kx", markersize=9, label="goals")
        for goal in posed:
            axes.annotate(
                f"{goal['id']}: {goal['outcome'] or 'running'}",
                (goal["pose"]["x"], goal["pose"]["y"]),
                textcoords="offset points",
                xytext=(6, 6),
                fontsize=8,
            )
    axes.set_xlabel("x [m]")
    axes.set_ylabel("y [m]")
    axes.set_aspect("equal", adjustable="datalim")
    axes.grid(True, alpha=0.3)
    axes.legend(loc="best")
    axes.set_title("trajectories")
    trajectory = directory / "trajectory.png"
    figure.savefig(trajectory, dpi=110, bbox_inches="tight")
    plt.close(figure)

    commanded, measured = wheel_speeds(recording, geometry)
    figure, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for index, side in ((1, "left"), (2, "right")):
        panel = axes[index - 1]
        measured_points = _downsample(measured)
        panel.plot(
            [m[0] for m in measured_points], [m[index] for m in measured_points], label="measured", linewidth=0.8
        )
        panel.step([c[0] for c in commanded], [c[index] for c in commanded], where="post", label="commanded")
        panel.set_ylabel(f"{side} wheel [rad/s]")
        panel.grid(True, alpha=0.3)
        panel.legend(loc="best")
    axes[1].set_xlabel("simulated time [s]")
    figure.suptitle("commanded vs measured wheel speeds")
    speeds = directory / "wheel_speeds.png"
    figure.savefig(speeds, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return [trajectory, speeds]
