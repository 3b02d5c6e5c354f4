"""invent up: the whole loop in separate processes, its report, how a run ends (its outcome and exit
status), and its failure handling."""

import json
import math
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from schemas.keys import Keys, Service
from services.cli.main import build_parser
from services.cli.up import plan_from_args
from services.config import DriveConfig
from services.drive.outcome import Outcome
from services.drive.scenarios import BUILTIN_SCENARIOS, planned_duration
from services.planar import Pose
from services.recording.mcap_files import read_messages
from services.recording.scene import SCAN_TOPIC
from tests.harness import (
    REPO,
    call,
    free_port,
    invent_command,
    peer_session,
    pid_alive,
    refused,
    run_invent,
    start_up,
    wait_until,
)

pytestmark = pytest.mark.slow

KEYS = Keys()
KINEMATIC = ("--engine", "kinematic")
"""For a long composed run whose subject is the launcher, not the physics: the loop without PyBullet
takes less CPU (the square: 2.4 s against 3.0-3.8 s measured; benchmarks/README.md)."""


def _child_pids(output: str) -> dict[str, int]:
    return {name: int(pid) for name, pid in re.findall(r"started (\w+) \(pid (\d+)\)", output)}


def test_killing_the_motor_mid_run_stops_everything_exits_non_zero_and_leaves_the_run_so_far(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    process = start_up("--scenario", "square", "--report", str(tmp_path), "--listen", endpoint)
    output: list[str] = []
    try:

        def under_way() -> bool:
            """Two progress lines (a second apart), the last past 0.5 s: up's status poll (every
            0.5 s) has then recorded the sim's status, also on a loaded machine."""
            line = process.stdout.readline()
            output.append(line)
            progress = [float(seconds) for seconds in re.findall(r"sim +([\d.]+) s \|", "".join(output))]
            return (len(progress) >= 2 and progress[-1] > 0.5) or not line

        wait_until(under_way, 60, "the loop to run")
        pids = _child_pids("".join(output))
        os.kill(pids["motor"], signal.SIGKILL)
        rest, _ = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    text = "".join(output) + rest
    assert process.returncode != 0
    assert "motor exited unexpectedly (killed by SIGKILL)" in text
    wait_until(lambda: not [pid for pid in pids.values() if pid_alive(pid)], 15, "every child to be gone")
    assert json.loads((tmp_path / "report.json").read_text())["outcome"]["service"] == "motor", "its report names it"
    assert "motor.journal was cut short" in text
    recorded = read_messages(tmp_path / "run.mcap")
    assert recorded.complete, "the run up to the motor's death, in a whole file"
    assert {KEYS.sim_wheel_angles, KEYS.drive_path, KEYS.status(Service.SIM)} <= {m.topic for m in recorded.messages}


def test_up_straight_follows_the_waypoints_with_the_real_services(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    result = subprocess.run(
        invent_command("up", "--scenario", "straight", "--report", str(tmp_path), "--listen", endpoint),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stdout[-4000:]
    report = json.loads((tmp_path / "report.json").read_text())
    goal = report["planned_path"][-1]
    end = report["final"]["ground_truth"]
    assert math.hypot(end["x"] - goal[0], end["y"] - goal[1]) < 0.05
    assert report["path_error"]["max_m"] < 0.05
    assert report["outcome"] == {**report["outcome"], "outcome": "completed", "reason": ""}
    # recorded at the observed steps (sim.observe_every = 20: 50 Hz), not at every step
    assert (tmp_path / "run.mcap").stat().st_size <= 0.1e6 * report["sim_time_s"], "at most 0.1 MB per simulated s"
    recorded = read_messages(tmp_path / "run.mcap").messages
    poses = [m for m in recorded if m.topic == KEYS.sim_body_pose]
    assert len(poses) == pytest.approx(report["steps"] / 20, abs=2), (len(poses), report["steps"])
    # the sensors at their own rates (lidar 10 Hz, IMU 100 Hz), the scan drawn as each came
    sensors = {key: [m for m in recorded if m.topic == key] for key in (KEYS.sim_scan, KEYS.sim_imu, SCAN_TOPIC)}
    for key, rate_hz, schema in ((KEYS.sim_scan, 10, "LaserScan"), (KEYS.sim_imu, 100, "ImuSample")):
        assert len(sensors[key]) == pytest.approx(report["sim_time_s"] * rate_hz, abs=2), (key, report["sim_time_s"])
        assert {m.schema_name for m in sensors[key]} == {schema}
    assert [m.publish_time_ns for m in sensors[SCAN_TOPIC]] == [m.publish_time_ns for m in sensors[KEYS.sim_scan]]
    assert {m.schema_name for m in sensors[SCAN_TOPIC]} == {"foxglove.LaserScan"}


@pytest.mark.parametrize(
    ("bound", "reason"),
    [("record.max_duration=2", "record.max_duration"), ("record.min_free_disk=1e12", "record.min_free_disk")],
)
def test_a_recording_that_stops_at_its_bound_says_so_and_the_robot_goes_on(tmp_path, bound, reason):
    result = _up("--composed", "--scenario", "straight", "--report", str(tmp_path), "--set", bound)
    assert result.returncode == 0, result.stdout[-4000:]
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["recording"]["reason"].startswith(reason), report["recording"]
    assert report["outcome"]["outcome"] == "completed", "the robot drove its 2 m: the run did not stop"
    assert report["outcome"]["elapsed_s"] > 6.0
    assert f"the recording stopped before the run did ({reason}" in result.stdout
    recorded_until = report["sim_time_s"]
    assert recorded_until <= 2.0, "nothing after the bound (on a low disk: nothing at all)"


def test_no_record_runs_the_loop_and_writes_nothing_with_a_live_view_beside_it(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    view_port = free_port()
    result = subprocess.run(
        invent_command(
            "up",
            "--composed",
            *KINEMATIC,
            "--no-record",
            "--scenario",
            "square",
            "--listen",
            endpoint,
            "--view",
            str(view_port),
        ),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert "no recording, no report (--no-record)" in result.stdout
    assert f"Foxglove live view: ws://127.0.0.1:{view_port}" in result.stdout, "serving before the loop starts"
    assert "view did not exit cleanly" not in result.stdout, "the view stopped with the run"
    assert "handshake failed" not in result.stdout and "ERROR" not in result.stdout, "a readiness probe without errors"
    assert list(tmp_path.iterdir()) == [], "no runs/ directory, no report, no plots"
    final_sim_time = float(re.findall(r"sim +([\d.]+) s \|", result.stdout)[-1])
    assert final_sim_time > 20.0, "the square scenario ran to its end"


def _up(*flags: str, cwd: Path = REPO) -> subprocess.CompletedProcess[str]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    command = invent_command("up", *flags, "--listen", endpoint)
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=180, check=False)


NO_MONITOR = ("--set", "collision_monitor.enabled=false")
"""The bump tests drive into the box: without it, the collision monitor holds the robot short of it."""


def test_a_straight_into_the_box_ends_by_itself_aborted_naming_the_bump_and_the_box(tmp_path):
    result = _up("--set", "sim.world=bump", *NO_MONITOR, "--scenario", "straight", "--report", str(tmp_path))
    assert result.returncode == Outcome.ABORTED.exit_code == 3, result.stdout[-4000:]
    outcome = json.loads((tmp_path / "report.json").read_text())["outcome"]
    assert outcome["outcome"] == "aborted" and outcome["iteration"] == 0, outcome
    assert outcome["reason"].startswith("bumped into 'box' at t = 1.8"), outcome
    # the box touched at 1.87 s, given up drive.give_up_after_stop (2 s) later
    assert outcome["t_s"] == pytest.approx(3.9, abs=0.1), outcome
    assert "outcome: aborted (bumped into 'box'" in result.stdout
    assert "the scenario was given up: exit 3" in result.stdout


BACK_M = 1.5
"""How much further from the box than in the bump world the approach starts."""


def test_the_collision_monitor_holds_a_straight_short_of_the_box_it_drove_towards_and_the_drive_gives_it_up(tmp_path):
    """In the bump world the box is inside the stop zone at the start: the robot would be held where
    it stands. Here it starts 1.5 m further back (the odometry and localization told so: the drive
    places the straight there), drives towards the box, and is held short of it."""
    bump_world = (REPO / "sim_bridge" / "worlds" / "bump.toml").read_text()
    world = tmp_path / "approach.toml"
    world.write_text(bump_world.replace("[initial_pose]\nx = 0.0", f"[initial_pose]\nx = {-BACK_M}"))
    assert f"x = {-BACK_M}" in world.read_text()
    start = _sets((f"sim.world={world}", f"odometry.initial_x={-BACK_M}", f"localization.initial_x={-BACK_M}"))
    result = _up("--composed", *start, "--scenario", "straight", "--report", str(tmp_path / "report"))
    assert result.returncode == Outcome.ABORTED.exit_code, result.stdout[-4000:]
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    outcome = report["outcome"]
    assert re.match(r"held by the collision monitor for 2\.0\d\d s", outcome["reason"]), outcome
    assert "obstacle 'box' in the stop zone" in outcome["reason"], outcome
    assert "bumps 0, bump_stop_calls 0," in result.stdout + result.stderr, "held before it touched: no sim/bump"
    assert report["start"]["x"] == pytest.approx(-BACK_M, abs=1e-3), report["start"]
    end = report["final"]["ground_truth"]["x"]
    assert end - report["start"]["x"] >= 1.0, f"it drove towards the box: from x = {-BACK_M} to {end:.3f}"
    # the body (0.45 m) touches the box's face at x = 0.45: at least 5 cm short
    assert end <= 0.40, report["final"]


def test_a_scenario_the_motor_is_too_slow_for_ends_timed_out_at_its_time_limit(tmp_path):
    limit_s = 1.0 * planned_duration(BUILTIN_SCENARIOS["straight"], Pose(0.0, 0.0, 0.0), DriveConfig()) + 1.0
    too_slow = ("motor.max_vx=0.01", "drive.time_limit_factor=1", "drive.time_limit_margin=1")
    result = _up("--composed", "--scenario", "straight", "--report", str(tmp_path), *_sets(too_slow))
    assert result.returncode == Outcome.TIMED_OUT.exit_code == 4, result.stdout[-4000:]
    report = json.loads((tmp_path / "report.json").read_text())
    outcome = report["outcome"]
    assert outcome["outcome"] == "timed_out" and f"past its time limit of {limit_s:.3f} s" in outcome["reason"]
    assert outcome["elapsed_s"] == pytest.approx(limit_s, abs=0.05), outcome
    assert report["final"]["ground_truth"]["x"] < 0.15, "crawled at 1 cm/s, far short of the 2 m"


def test_a_stop_latched_in_the_motor_state_file_aborts_the_scenario_naming_it(tmp_path):
    """The motor publishes its restored stop before the drive starts: the drive asks for it."""
    gains = {"p_gain_l": 5.0, "p_gain_r": 5.0, "d_gain_l": 2.0, "d_gain_r": 2.0}
    (tmp_path / "motor-state.json").write_text(json.dumps({"stopped": True, "finished": False, "gains": gains}))
    result = _up("--composed", "--scenario", "straight", "--report", str(tmp_path))
    assert result.returncode == 3, result.stdout[-4000:]
    outcome = json.loads((tmp_path / "report.json").read_text())["outcome"]
    assert outcome["reason"].startswith("the stop latched in the motor's state file"), outcome
    assert outcome["t_s"] == pytest.approx(2.0, abs=0.05), "given up 2 s into the run"


def test_loop_ends_with_the_outcome_of_the_pass_that_gave_up(tmp_path):
    result = _up(
        *("--loop", "--composed", "--set", "sim.world=bump", *NO_MONITOR, "--scenario", "straight"),
        *("--report", str(tmp_path / "run")),
    )
    assert result.returncode == 3, result.stdout[-4000:]
    assert "outcome: aborted (bumped into 'box'" in result.stdout
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert report["outcome"]["outcome"] == "aborted", report["outcome"]


def _sets(overrides: tuple[str, ...]) -> list[str]:
    return [flag for override in overrides for flag in ("--set", override)]


def _started_pids(process: subprocess.Popen[str], output: list[str]) -> dict[str, int]:
    """Read ``up``'s output until it has started the drive; the children's pids."""

    def drive_started() -> bool:
        line = process.stdout.readline()
        output.append(line)
        return "started drive" in line or not line

    wait_until(drive_started, 60, "invent up to start the drive")
    return _child_pids("".join(output))


def test_a_realtime_run_with_a_stalled_motor_reports_its_degradation_and_strict_exits_1(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # paced at twice the wall clock: the straight's 7.5 simulated seconds in under 4 s; --split: the
    # motor a process of its own, to stall alone (composed with the sim, it would stall the sim too)
    process = start_up(
        "--scenario",
        "straight",
        "--mode",
        "realtime",
        "--split",
        "--set",
        "sim.realtime_factor=2",
        "--strict",
        "--report",
        str(tmp_path),
        "--listen",
        endpoint,
    )
    output: list[str] = []
    try:
        motor = _started_pids(process, output)["motor"]
        with peer_session(endpoint) as session:  # the straight under way
            wait_until(lambda: call(session, KEYS.status(Service.SIM))[1]["sim_time_s"] > 2.0, 60, "2 s simulated")
        os.kill(motor, signal.SIGSTOP)
        time.sleep(0.2)  # the stall itself: 200 ms with no torque
        os.kill(motor, signal.SIGCONT)
        rest, _ = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    output.append(rest)
    text = "".join(output)
    assert process.returncode == 1, text[-3000:]
    report = json.loads((tmp_path / "report.json").read_text())
    torques = report["health"]["torques"]
    assert torques["missing_fraction"] > 0.01, torques
    assert torques["late_fraction"] > 0.0, torques
    assert any(reason.startswith("missing torques") for reason in report["degraded"]), report["degraded"]
    assert "WARNING: the run degraded: missing torques" in text
    assert "--strict: the run degraded" in text


def test_gui_without_a_display_exits_2_before_anything_starts():
    environment = {name: value for name, value in os.environ.items() if name != "DISPLAY"}
    result = subprocess.run(
        invent_command("up", "--gui"),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        env=environment,
        check=False,
    )
    assert result.returncode == 2 and "--gui needs a display" in result.stderr
    assert "started" not in result.stdout and "Traceback" not in result.stderr + result.stdout


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (("--scenario", "nope"), "scenario 'nope' is neither a built-in"),
        (("--set", "sim.world=nowhere"), "'nowhere' is neither a file nor a built-in world"),
        (("--ros2",), "ROS_DOMAIN_ID"),
        (("--teleop",), "--teleop (--ros2)"),
        (("--ros2", "--teleop", "--mode", "lockstep"), "--teleop (--mode lockstep)"),
        (("--goals", "--scenario", "circle", "--loop"), "--goals with --scenario, --loop: in goal mode"),
        (("--goals", "--ros2", "--teleop"), "--goals with --teleop"),
        (("--goal-file", "nowhere.toml"), "goal file 'nowhere.toml'"),
        (("--fleet", "examples/fleets/two_squares.toml", "--goal-file", "g.toml"), "--fleet with --goal-file"),
        (("--mode", "realtime", "--split", "--composed"), "--split with --composed"),
        (("--goals", "--map", "nowhere.yaml"), "nowhere.yaml"),
    ],
)
def test_a_scenario_or_world_a_service_would_refuse_exits_2_before_anything_starts(
    tmp_path, monkeypatch, capsys, flags, message
):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("ROS_DOMAIN_ID", "999")
    if flags[0] == "--fleet":
        flags = ("--fleet", str(REPO / flags[1]), *flags[2:])
    code, out, err = refused(capsys, "up", *flags)
    assert code == 2 and message in err, err
    assert "started" not in out
    assert list(tmp_path.iterdir()) == [], "nothing left behind"


def test_a_run_interrupted_before_the_sim_starts_leaves_nothing_behind(tmp_path):
    """Ctrl-C while the services start: the run never started, so no run.mcap of nothing and no
    runs/ directory (a service at another router, here none, never shows its token)."""
    nobody = f"tcp/127.0.0.1:{free_port()}"
    up = subprocess.Popen(
        invent_command("up", "--connect", nobody),
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert up.stdout is not None
    lines = []
    for line in up.stdout:
        lines.append(line)
        if "started localization" in line:
            up.send_signal(signal.SIGINT)
            break
    lines.extend(up.stdout)
    assert up.wait(timeout=60) == 130, "".join(lines)
    assert any("never started" in line for line in lines), "".join(lines)
    assert list(tmp_path.iterdir()) == [], "no runs/ directory, no run.mcap"


def test_a_view_on_any_free_port_is_refused_naming_the_flag():
    result = run_invent("up", "--view", "0")
    assert result.returncode == 2 and "--view" in result.stderr


def test_loop_repeats_the_scenario_until_ctrl_c_recording_with_flat_memory(tmp_path):
    from schemas.keys import Keys, Service
    from tests.harness import call, peer_session

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    report = tmp_path / "run"
    process = start_up("--loop", "--composed", "--scenario", "straight", "--listen", endpoint, "--report", str(report))
    output: list[str] = []
    try:
        _started_pids(process, output)
        with peer_session(endpoint) as session:

            def iteration() -> int:
                ok, status = call(session, Keys().status(Service.DRIVE))
                return status["iteration"] if ok else 0

            wait_until(lambda: iteration() >= 2, 120, "two passes of the scenario")
            rss_early = _rss_mb(process.pid)
            wait_until(lambda: iteration() >= 8, 240, "eight passes of the scenario")
            rss_late = _rss_mb(process.pid)
        process.send_signal(signal.SIGINT)
        rest, _ = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    text = "".join(output) + rest
    assert process.returncode == 0, text[-3000:]
    assert "torques: late" in text and (report / "report.json").exists(), "its recording and report written"
    assert rss_late - rss_early < 20, f"memory grew from {rss_early:.0f} to {rss_late:.0f} MB over six passes"


def _rss_mb(pid: int) -> float:
    line = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("VmRSS"))
    return int(line.split()[1]) / 1024


@pytest.mark.parametrize(
    ("flags", "keep"),
    [
        (["--goals"], "newest"),
        (["--loop"], "newest"),
        (["--goals", "--set", "record.keep=until_full"], "until_full"),
        (["--scenario", "square"], "until_full"),
    ],
)
def test_a_deployments_run_keeps_the_newest_of_its_recording_unless_told_otherwise(flags, keep):
    plan = plan_from_args(build_parser("up").parse_args(["up", *flags]))
    assert str(plan.description.load().record.keep) == keep
