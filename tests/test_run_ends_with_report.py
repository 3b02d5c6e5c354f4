"""Every run leaves a report: a run of ``invent up`` that ends because a service died (a service of
one's own, a built-in one) still writes ``report.json`` and the plots, its outcome naming the
service and how it ended, and ``up`` exits 1; ``invent report`` rebuilds a report from any run's
recording, cut short or without its summary, saying what is missing, and exits 2 only for a file
that is not a recording. Two end-to-end runs on the kinematic engine, shared by the tests that
read them; the rest on recordings written here from journals (no zenoh)."""

from __future__ import annotations

import json
import os
import re
import signal
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import pytest

from schemas.codec import encode
from schemas.keys import Keys, Service, user_service_name
from schemas.messages import PlannedPath, RunSummary, Time, TimedDoubleSeq
from schemas.status import BadInputStatus
from services.config import load_config
from services.recording.mcap_files import McapWriter, read_messages, read_run
from services.recording.record import write_run_recording
from services.recording.report import loop_health
from services.recording.run_report import robot_report
from services.runtime.journal import Journal, journal_path
from tests.harness import REPO, free_port, peer_session, run_invent, start_up, wait_until
from tests.status_samples import motor_status, sim_status, user_service_status

KEYS = Keys()
ODOMETER = f"{REPO / 'examples' / 'services' / 'odometer.py'}:Odometer"
ODOMETER_NAME = user_service_name("odometer")
PUBLISHED_NS = 1_800_000_000 * 10**9
MS = 1_000_000


@dataclass
class KilledRun:
    """An ``invent up`` run one of whose services was killed (SIGKILL) mid-run."""

    code: int
    output: str
    report_dir: Path

    @property
    def report(self) -> dict[str, Any]:
        return json.loads((self.report_dir / "report.json").read_text())


def _killed_run(report_dir: Path, victim: str, under_way_key: str, extra: tuple[str, ...] = ()) -> KilledRun:
    """``invent up --engine kinematic --scenario square`` (and ``extra``), ``victim``'s process killed
    once 15 samples of ``under_way_key`` have come: the run is under way."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = start_up(
        *("--engine", "kinematic", "--scenario", "square", *extra),
        *("--report", str(report_dir), "--listen", endpoint),
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(up.stdout or ()), daemon=True)
    reader.start()
    try:
        samples: list[bytes] = []
        with peer_session(endpoint) as session:
            session.declare_subscriber(under_way_key, lambda sample: samples.append(sample.payload.to_bytes()))

            def under_way() -> bool:
                if up.poll() is not None:
                    raise AssertionError(f"invent up ended early:\n{''.join(lines)}")
                return len(samples) >= 15

            wait_until(under_way, 60, f"15 samples of {under_way_key}")
        pids = dict(re.findall(r"started (\w+) \(pid (\d+)\)", "".join(lines)))
        os.kill(int(pids[victim]), signal.SIGKILL)
        code = up.wait(60)
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
    reader.join(5)
    return KilledRun(code, "".join(lines), report_dir)


@pytest.fixture(scope="module")
def user_service_killed(tmp_path_factory: pytest.TempPathFactory) -> KilledRun:
    return _killed_run(
        tmp_path_factory.mktemp("odometer"), "odometer", KEYS.own(ODOMETER_NAME, "distance"), ("--with", ODOMETER)
    )


@pytest.fixture(scope="module")
def built_in_killed(tmp_path_factory: pytest.TempPathFactory) -> KilledRun:
    return _killed_run(tmp_path_factory.mktemp("odometry"), "odometry", KEYS.odometry_pose)


def _assert_ends_naming(run: KilledRun, service: str) -> None:
    assert run.code == 1, run.output
    assert f"{service} exited unexpectedly (killed by SIGKILL); stopped everything" in run.output
    outcome = run.report["outcome"]
    assert outcome["outcome"] == "service_died", outcome
    assert (outcome["service"], outcome["signal"], outcome["exit_code"]) == (service, "SIGKILL", None)
    assert outcome["reason"] == f"{service} killed by SIGKILL"
    assert f"outcome: service_died ({service} killed by SIGKILL)" in run.output, "the summary printed says so"
    assert run.report["missing"] == [], "the run's recording is whole: its summary says how it ended"
    assert run.report["sim_time_s"] > 0.1 and run.report["final"]["ground_truth"] is not None
    for plot in ("trajectory.png", "wheel_speeds.png"):
        assert (run.report_dir / plot).stat().st_size > 0, plot


@pytest.mark.slow
def test_a_user_service_killed_mid_run_ends_the_run_naming_it_and_leaves_its_report(user_service_killed):
    _assert_ends_naming(user_service_killed, "odometer")
    assert user_service_killed.report["health"]["user_services"] == {"odometer": None}, "it answered no more"


@pytest.mark.slow
def test_a_built_in_service_killed_mid_run_ends_the_run_naming_it_and_leaves_its_report(built_in_killed):
    _assert_ends_naming(built_in_killed, "odometry")
    assert "odometry" not in built_in_killed.report["health"]["services"], "it answered no more"


@pytest.mark.slow
def test_invent_report_rebuilds_the_report_of_a_recording_cut_short_saying_what_is_missing(
    user_service_killed, tmp_path
):
    whole = (user_service_killed.report_dir / "run.mcap").read_bytes()
    # two thirds of the messages (the data section: the footer's summary_start, 28 bytes before the
    # file's end), so the summary, published last, is lost however large the summary section is
    data_end = int.from_bytes(whole[-28:-20], "little")
    cut = tmp_path / "run.mcap"
    cut.write_bytes(whole[: data_end * 2 // 3])
    assert not read_run(cut).complete

    result = run_invent("report", str(cut))

    assert result.returncode == 0, result.stderr
    assert "missing: the file was cut short" in result.stdout
    assert "missing: no run summary: the run did not end cleanly; outcome unknown" in result.stdout
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["outcome"] is None and report["wall_time_s"] is None and report["scenario"] is None
    assert report["missing"][0].startswith("the file was cut short")
    assert 0 < report["sim_time_s"] < user_service_killed.report["sim_time_s"]
    assert report["mode"] == "lockstep", "from the sim's last status recorded"
    assert report["health"]["services"]["odometer"]["internal_errors"] == 0, "from the recorded status replies"
    assert (tmp_path / "trajectory.png").exists() and (tmp_path / "wheel_speeds.png").exists()


@pytest.mark.slow
def test_invent_report_rebuilds_the_report_of_a_whole_recording_without_its_summary(built_in_killed, tmp_path):
    """Every message of the run but its summary, in a whole file (as ``invent record`` beside a run
    whose ``up`` was killed keeps it)."""
    unsummarized = tmp_path / "run.mcap"
    writer = McapWriter(unsummarized)
    for message in read_messages(built_in_killed.report_dir / "run.mcap").messages:
        if message.topic != KEYS.run_summary:
            writer.write_sample(message.topic, message.data, message.log_time_ns, message.publish_time_ns)
    writer.close()

    result = run_invent("report", str(unsummarized), "--output-dir", str(tmp_path / "report"))

    assert result.returncode == 0, result.stderr
    assert "missing: no run summary: the run did not end cleanly; outcome unknown" in result.stdout
    assert "cut short" not in result.stdout
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["outcome"] is None and len(report["missing"]) == 1
    assert report["sim_time_s"] >= built_in_killed.report["sim_time_s"], "not cut at a summary's stamp"
    assert report["path_error"] is not None, "the path the drive published"


def test_invent_report_refuses_only_a_file_that_is_not_a_recording(tmp_path):
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    result = run_invent("report", str(text))
    assert result.returncode == 2 and "not an MCAP recording" in result.stderr, result.stderr
    assert not (tmp_path / "report.json").exists()


def _journals(directory: Path, summary: RunSummary | None, steps: int = 4000) -> None:
    """Four simulated seconds as a run's processes journal them: the sim's ground truth every ms
    (about 600 kB: a few chunks), the drive's path, the services' status replies every 0.5 s in
    ``up``'s journal (and someone's bad one), and ``summary`` last, if any."""
    directory.mkdir()
    sim = Journal(journal_path(directory, str(Service.SIM)))
    for step in range(steps):
        pose = [step * 1e-4, 0.0, 0.05, 1, 0, 0, 0, 1, 0, 0, 0, 1]
        sim.write(
            KEYS.sim_body_pose, encode(TimedDoubleSeq(Time.from_nanoseconds(step * MS), pose)), PUBLISHED_NS + step * MS
        )
    sim.close()
    drive = Journal(journal_path(directory, str(Service.DRIVE)))
    drive.write(KEYS.drive_path, encode(PlannedPath(Time(0, 0), "straight", [(0.0, 0.0), (1.0, 0.0)])), PUBLISHED_NS)
    drive.close()
    up = Journal(journal_path(directory, "up"))
    for half in range(steps // 500):
        at = PUBLISHED_NS + half * 500 * MS
        sim = msgspec.structs.replace(
            sim_status("lockstep", half * 500, torques_applied=half * 500), bad_input=BadInputStatus(total=half)
        )
        up.write(KEYS.status(Service.SIM), msgspec.json.encode(sim), at)
        up.write(KEYS.status(Service.MOTOR), msgspec.json.encode(motor_status(bad=half)), at + 1)
        up.write(KEYS.status(ODOMETER_NAME), user_service_status(bad=half, distance_m=half), at + 2)
    up.write(KEYS.status(Service.ODOMETRY), b'{"bad_input": "lots"}', PUBLISHED_NS + 3)
    if summary is not None:
        up.write(KEYS.run_summary, encode(summary), PUBLISHED_NS + steps * MS)
    up.close()


def _died_summary(t_s: int) -> RunSummary:
    """``up``'s summary of a run whose odometry was killed at ``t_s`` simulated seconds."""
    health = loop_health(None, {})
    return RunSummary(
        Time(t_s, 0), "square", "lockstep", False, 2.0, t_s * 1000, health, "service_died", "odometry", -9
    )


def test_a_recording_without_its_summary_takes_its_health_from_the_last_status_replies(tmp_path):
    _journals(tmp_path / "journals", None)
    write_run_recording(tmp_path / "journals", tmp_path / "run.mcap", load_config(None, {}))

    report, recording = robot_report(tmp_path / "run.mcap", read_run(tmp_path / "run.mcap"), load_config(None, {}))

    assert len(recording.ground_truth) == 4000 and report["outcome"] is None
    assert (report["mode"], report["steps"], report["wall_time_s"], report["real_time_factor"]) == (
        "lockstep",
        3500,
        None,
        None,
    )
    services = report["health"]["services"]
    assert set(services) == {"sim", "motor", "odometer"}, "odometry's bad status left out, not fatal"
    assert services["motor"]["bad_inputs"] == 7, "the last reply recorded"
    assert services["odometer"]["bad_inputs"] == 7 and services["sim"]["bad_inputs"] == 7
    assert report["health"]["user_services"]["odometer"]["distance_m"] == 7
    assert report["health"]["torques"]["applied"] == 3500
    assert report["missing"] == [
        (
            "no run summary: the run did not end cleanly; outcome unknown, wall time unknown, "
            "the loop's health from the last status replies recorded"
        )
    ]
    assert report["path_error"] is not None, "along the path the drive published"


def test_a_recording_cut_mid_chunk_is_reported_up_to_its_last_whole_chunk(tmp_path):
    _journals(tmp_path / "journals", _died_summary(4))
    whole = tmp_path / "run.mcap"
    write_run_recording(tmp_path / "journals", whole, load_config(None, {}))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])

    report, recording = robot_report(cut, read_run(cut), load_config(None, {}))

    assert 0 < len(recording.ground_truth) < 4000
    assert report["missing"][0].startswith("the file was cut short")
    assert report["missing"][1].startswith("no run summary"), "the summary came last: lost with the cut"


def test_a_summary_that_says_a_service_died_is_the_reports_outcome(tmp_path):
    summary = _died_summary(3)
    _journals(tmp_path / "journals", summary)
    write_run_recording(tmp_path / "journals", tmp_path / "run.mcap", load_config(None, {}))

    report, recording = robot_report(tmp_path / "run.mcap", read_run(tmp_path / "run.mcap"), load_config(None, {}))

    assert report["outcome"] == {
        "outcome": "service_died",
        "reason": "odometry killed by SIGKILL",
        "t_s": 3.0,
        "service": "odometry",
        "exit_code": None,
        "signal": "SIGKILL",
    }
    assert report["missing"] == [] and recording.ground_truth[-1][0] == 3.0, "cut at the summary's stamp"


def test_a_recording_of_other_robots_only_is_refused_naming_them(tmp_path):
    _journals(tmp_path / "journals", None)
    write_run_recording(tmp_path / "journals", tmp_path / "run.mcap", load_config(None, {}))
    result = run_invent("report", str(tmp_path / "run.mcap"), "--robot", "rh7")
    assert result.returncode == 2 and "robots recorded: rh0" in result.stderr, result.stderr
