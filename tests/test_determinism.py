"""Lockstep means deterministic: ``invent up --scenario square`` gives the same samples, bit for
bit, composed in one process on a quiet machine and as separate processes beside two CPU-burning
processes (the two extremes of how a run is timed; the fleet's test pairs its runs the same way;
tests/test_determinism_goals.py: goals, a detour and amcl, quiet and loaded). The runs drive in the
built-in ``room`` world, so that the lidar's scans (compared too) see walls and posts.

The runs are compared by their recordings (``run.mcap``, made of what each service published, as it
published it): every payload of the ground truth, odometry and localization keys (and the drive's
targets, the scans and the IMU), in publication order. They record at every step
(``--record-full-rate``: the poses are then published at every step too), so the comparisons see
the whole run. (Not a subscriber of this test's router: a composed run may publish its first samples
before the router's subscriptions reach its session, zenoh's startup race. Twice in 27 runs, one
such subscriber had one pose, scan and IMU sample fewer of the composed run than it published.) The two runs of the module are shared by the tests below, including the
ones that check the square itself and composed mode's outside visibility.
"""

from __future__ import annotations

import itertools
import json
import math
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import jsonschema
import pytest
import zenoh
from mcap.reader import make_reader

from benchmarks.loop import cpu_seconds
from schemas.codec import decode
from schemas.keys import Keys, Service, schema_for_key
from schemas.messages import ImuSample, LaserScan, TimedDoubleSeq
from schemas.status_kinds import status_type_of_key
from schemas.topics import Topic
from services.recording.mcap_files import read_messages
from services.recording.scene import LOCALIZATION_TOPIC, ODOMETRY_TOPIC, SCENE_TOPIC, TRANSFORMS_TOPIC
from services.runtime.session import open_session, session_config
from tests.harness import (
    REPO,
    InventProcess,
    free_port,
    invent_command,
    pid_alive,
    run_invent,
    wait_alive,
    wait_until,
)

pytestmark = pytest.mark.slow

KEYS = Keys("rh0")
RECORDED = (
    KEYS.sim_body_pose,
    KEYS.odometry_pose,
    KEYS.localization_pose,
    KEYS.drive_target_velocity,
    KEYS.sim_scan,
    KEYS.sim_imu,
)
WALL_CLOCK_FIELDS = ("wall_time_s", "real_time_factor")
SCHEMA_CHECKED = 500
GOAL_TOPICS = (Topic.DRIVE_GOAL, Topic.DRIVE_GOAL_FEEDBACK, Topic.DRIVE_MAP, Topic.DRIVE_COSTMAP, Topic.DRIVE_PLAN)
"""Published in goal mode only (the navigation's too): a scenario's run has none."""
BURNERS = 2
BURNER_MIN_SHARE = 0.25
"""Each burner must have had at least this share of a core while it ran: enough to prove the loop
shared the machine, whatever the loop's own speed (which a busy CI machine makes noisy)."""


@dataclass
class SquareRun:
    returncode: int
    output: str
    report: dict
    samples: dict[str, list[bytes]]
    """Every payload of each compared key, in publication order (from the run's recording)."""
    report_dir: Path
    outside_status: str = ""
    """``invent status`` run against the loop while it ran (composed run only)."""
    burner_shares: list[float] | None = None
    """Each CPU burner's share of a core during the run (loaded run only)."""


@contextmanager
def _burning_cpus(count: int) -> Iterator[list[float]]:
    """Yields a list that holds, once the block ends, each burner's share of a core while it ran."""
    shares: list[float] = []
    started = time.monotonic()
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        yield shares
    finally:
        lifetime = time.monotonic() - started
        shares.extend(cpu_seconds([burner.pid]) / lifetime for burner in burners)
        for burner in burners:
            burner.kill()
            burner.wait()


def _run_square(report_dir: Path, *flags: str, ask_status: bool = False) -> SquareRun:
    """The square, recorded at every step: :func:`_run`."""
    return _run(report_dir, RECORDED, "--scenario", "square", "--record-full-rate", *flags, ask_status=ask_status)


def _run(report_dir: Path, recorded: tuple[str, ...], *flags: str, ask_status: bool = False) -> SquareRun:
    """One ``invent up`` run connected to this test's router; every sample of ``recorded`` from its
    recording, in publication order."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    status = ""
    with open_session(session_config(listen=[endpoint], mode="router")) as router:
        process = subprocess.Popen(
            invent_command(
                "up",
                "--set",
                "sim.world=room",
                "--report",
                str(report_dir),
                "--connect",
                endpoint,
                *flags,
            ),
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            if ask_status:
                wait_alive(router, KEYS.alive(Service.SIM), timeout=60)
                status = run_invent("status", "--connect", endpoint).stdout

            try:
                wait_until(lambda: process.poll() is not None, 300, "the run to end")
            except AssertionError as error:
                process.kill()
                raise AssertionError(f"{error}; its output:\n{process.stdout.read()[-6000:]}") from None
            output = process.stdout.read()
        finally:
            if process.poll() is None:
                process.kill()
            process.wait()
    report_file = report_dir / "report.json"
    report = json.loads(report_file.read_text()) if report_file.exists() else {}
    recording = report_dir / "run.mcap"
    messages = read_messages(recording).messages if recording.exists() else []
    samples = {key: [message.data for message in messages if message.topic == key] for key in recorded}
    return SquareRun(process.returncode, output, report, samples, report_dir, status)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, SquareRun]:
    base = tmp_path_factory.mktemp("square")
    with _burning_cpus(BURNERS) as burner_shares:
        loaded = _run_square(base / "loaded")
    loaded.burner_shares = burner_shares
    composed = _run_square(base / "composed", "--composed", ask_status=True)
    return {"loaded": loaded, "composed": composed}


def _comparable(report: dict) -> dict:
    return {name: value for name, value in report.items() if name not in (*WALL_CLOCK_FIELDS, "composed")}


def _assert_loaded(run: SquareRun) -> None:
    """The run did share the machine with the burners (checked after its samples, so that a
    machine too busy for the burners still shows whether the samples matched)."""
    assert run.burner_shares is not None and len(run.burner_shares) == BURNERS
    assert min(run.burner_shares) >= BURNER_MIN_SHARE, f"the burners did not load the machine: {run.burner_shares}"


def _assert_same_samples(first: SquareRun, second: SquareRun) -> None:
    differences = []
    for key in first.samples:
        a, b = first.samples[key], second.samples[key]
        assert a, f"nothing recorded on {key}"
        if len(a) != len(b):
            differences.append(f"{key}: {len(a)} samples against {len(b)}")
            continue
        differing = next((index for index, (x, y) in enumerate(zip(a, b, strict=True)) if x != y), None)
        if differing is not None:
            differences.append(f"{key}: sample {differing} differs: {a[differing]!r} against {b[differing]!r}")
    assert not differences, "\n".join(differences)


def _repeated(samples: list[bytes]) -> list[bytes]:
    seen: set[bytes] = set()
    return [sample[:40] for sample in samples if sample in seen or seen.add(sample)]


def test_square_returns_to_the_start_and_writes_the_report(runs):
    run = runs["loaded"]
    assert run.returncode == 0, run.output[-4000:]
    report = run.report
    assert (report["scenario"], report["mode"]) == ("square", "lockstep")
    for estimate in ("ground_truth", "odometry", "localization"):
        assert set(report["final"][estimate]) == {"x", "y", "theta"}, estimate
    start, end = report["start"], report["final"]["ground_truth"]
    assert math.hypot(end["x"] - start["x"], end["y"] - start["y"]) < 0.05
    assert report["path_error"]["max_m"] < 0.10
    assert report["odometry_error"]["max_m"] < 0.05
    assert report["steps"] == round(report["sim_time_s"] / 0.001)
    assert report["bad_inputs"] == {"motor": 0, "odometry": 0, "sim": 0, "localization": 0, "drive": 0}
    assert report["degraded"] == []
    assert (run.report_dir / "trajectory.png").stat().st_size > 10_000
    assert (run.report_dir / "wheel_speeds.png").stat().st_size > 10_000
    assert "scenario square (lockstep)" in run.output
    pids = {name: int(pid) for name, pid in re.findall(r"started (\w+) \(pid (\d+)\)", run.output)}
    assert set(pids) == {"motor", "odometry", "localization", "sim", "drive"}, (
        "no router (it connects to ours), no recorder (each service keeps what it publishes)"
    )
    assert not (run.report_dir / "journals").exists(), "the journals are gone once run.mcap is written"
    assert not [name for name, pid in pids.items() if pid_alive(pid)]


def test_the_scans_see_the_room_and_the_imu_turns_as_the_robot_does(runs):
    """The lidar sees the room's walls and posts on every scan; the IMU's yaw rate, integrated over
    the square, is the heading the robot turned (ground truth, unwrapped) within 2 %."""
    run = runs["loaded"]
    scans = [decode(LaserScan, payload) for payload in run.samples[KEYS.sim_scan]]
    assert len(scans) == math.floor(run.report["sim_time_s"] * 10) + 1, "10 Hz of simulation time, from t = 0"
    assert all(any(reading is not None for reading in scan.ranges) for scan in scans)
    assert {"wall_south", "wall_west", "post_1"} <= {body for scan in scans for body in scan.bodies}
    samples = [decode(ImuSample, payload) for payload in run.samples[KEYS.sim_imu]]
    integrated = sum(
        (later.tm.to_nanoseconds() - earlier.tm.to_nanoseconds()) / 1e9 * earlier.angular_velocity[2]
        for earlier, later in itertools.pairwise(samples)
    )
    poses = [decode(TimedDoubleSeq, payload).data for payload in run.samples[KEYS.sim_body_pose]]
    headings = [math.atan2(pose[6], pose[3]) for pose in poses]
    turned = sum(math.remainder(b - a, math.tau) for a, b in itertools.pairwise(headings))
    assert turned > math.pi, "the square turns the robot three quarters round, at least"
    assert integrated == pytest.approx(turned, rel=0.02)


def test_every_step_of_the_run_is_recorded(runs):
    """The comparisons below see the whole run: one ground-truth sample per step, from t = 0."""
    run = runs["loaded"]
    assert len(run.samples[KEYS.sim_body_pose]) == run.report["steps"] + 1
    assert len(run.samples[KEYS.odometry_pose]) == run.report["steps"] + 1
    fixes = len(run.samples[KEYS.localization_pose])
    assert fixes == math.floor(run.report["sim_time_s"]) + 1, "one fix per second of simulation time, from t = 0"


def test_composed_on_a_quiet_machine_and_separate_beside_burners_give_the_same_samples_and_report(runs):
    loaded, composed = runs["loaded"], runs["composed"]
    assert loaded.returncode == 0, loaded.output[-4000:]
    assert loaded.report["degraded"] == [], "lockstep waits for what lives: nothing degrades"
    assert composed.returncode == 0, composed.output[-4000:]
    assert "(pid" not in composed.output, "composed mode must not start child processes"
    assert composed.report["composed"] is True
    _assert_same_samples(composed, loaded)
    assert _comparable(loaded.report) == _comparable(composed.report)
    _assert_loaded(loaded)


def test_no_service_refuses_anything_of_its_own_loop(runs):
    """The report counts the bad input of the services still running at its end; the drive has
    ended by then, so its refusals (a clock sample handed over out of order) show only in the log."""
    for name, run in runs.items():
        refusals = [line for line in run.output.splitlines() if "bad input on " in line]
        assert refusals == [], (name, refusals[:5])


def test_composed_services_are_seen_by_outside_tools_and_publish_blocking_in_lockstep(runs):
    statuses = {line["service"]: line for line in map(json.loads, runs["composed"].outside_status.splitlines())}
    services = ("sim", "motor", "odometry", "localization", "drive")
    assert set(services) <= set(statuses)
    assert {statuses[name]["status"]["congestion"] for name in services} == {"block"}, "up gave each its run's mode"


PER_STEP_TOPICS = (
    Topic.SIM_WHEEL_ANGLES,
    Topic.SIM_BODY_POSE,
    Topic.MOTOR_TORQUE,
    Topic.MOTOR_WHEEL_ANGLES,
    Topic.MOTOR_SIM_POSE_GUI,
    Topic.MOTOR_SIM_POSE_LOCALIZATION,
    Topic.ODOMETRY_POSE,
)
SCENE_SCHEMAS = {
    TRANSFORMS_TOPIC: "foxglove.FrameTransforms",
    SCENE_TOPIC: "foxglove.SceneUpdate",
    ODOMETRY_TOPIC: "foxglove.PoseInFrame",
    LOCALIZATION_TOPIC: "foxglove.PoseInFrame",
}


@pytest.mark.parametrize("name", ["loaded", "composed"])
def test_the_recording_has_every_key_valid_against_its_schema_and_the_foxglove_scene(runs, name):
    """Every message of both runs, each service's status replies too, is decoded with the project's
    types, which the schemas are generated from; the separate run's first :data:`SCHEMA_CHECKED` of each key are also checked against
    the JSON schema in the file (about 100 µs each: every one of a full-rate run's 10^5 took 15 s)."""
    run = runs[name]
    checked = SCHEMA_CHECKED if name == "loaded" else 1
    assert run.returncode == 0, run.output[-4000:]
    with open(run.report_dir / "run.mcap", "rb") as file:
        reader = make_reader(file)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, "a complete, indexed file"
        counts: dict[str, int] = {}
        schemas: dict[str, tuple[str, str]] = {}
        validators: dict[int, jsonschema.protocols.Validator] = {}
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            schemas[channel.topic] = (schema.name, schema.encoding) if schema else ("", "")
            topic_type = schema_for_key(channel.topic)
            message_type = topic_type or status_type_of_key(channel.topic)
            if message_type is not None:
                assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
                assert schema.name == message_type.__name__, channel.topic
                validator = validators.get(schema.id)
                if validator is None:
                    schema_document = json.loads(schema.data)
                    jsonschema.Draft202012Validator.check_schema(schema_document)
                    validator = validators[schema.id] = jsonschema.Draft202012Validator(schema_document)
                if counts[channel.topic] <= checked:
                    validator.validate(json.loads(message.data))
                decoded = decode(message_type, message.data)
                if topic_type is not None:
                    assert message.publish_time == decoded.tm.to_nanoseconds()
    # no bump in the room, no goals in a scenario, no particles from the stub localization, no wheel
    # speed targets from a motor sending torques
    absent = (Topic.SIM_BUMP, Topic.LOCALIZATION_PARTICLES, Topic.MOTOR_WHEEL_VELOCITY, *GOAL_TOPICS)
    published = [topic for topic in Topic if topic not in absent]
    assert {KEYS.topic(topic) for topic in published} <= set(counts), sorted(counts)
    for topic in PER_STEP_TOPICS:
        assert counts[KEYS.topic(topic)] == run.report["steps"] + 1, topic
    for topic, schema_name in SCENE_SCHEMAS.items():
        assert schemas[topic] == (schema_name, "protobuf") and counts[topic] > 0, topic
    assert counts[KEYS.status(Service.MOTOR)] > 0, "the services' status, for the motor state and the sim counters"


def test_invent_report_rebuilds_the_report_up_wrote_from_the_recording(runs, tmp_path):
    run = runs["loaded"]
    result = run_invent("report", str(run.report_dir / "run.mcap"), "--output-dir", str(tmp_path))
    assert result.returncode == 0, result.stdout + result.stderr
    assert json.loads((tmp_path / "report.json").read_text()) == run.report
    assert (tmp_path / "trajectory.png").stat().st_size > 0 and (tmp_path / "wheel_speeds.png").stat().st_size > 0


def test_replaying_wheel_angles_and_fixes_into_a_fresh_odometry_reproduces_its_poses_exactly(runs):
    """``invent replay --rate 0`` of a recorded run's motor/wheel_angles and localization/pose, re-keyed
    onto another robot, into a fresh ``invent odometry``: the same odometry/pose payloads, bit for bit."""
    recording = runs["loaded"].report_dir / "run.mcap"
    recorded = [m.data for m in read_messages(recording).messages if m.topic == KEYS.odometry_pose]
    replayed = Keys("replayed")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with open_session(session_config(listen=[endpoint], mode="router")) as router:
        poses = router.declare_subscriber(replayed.odometry_pose, zenoh.handlers.FifoChannel(1 << 20))
        with InventProcess("odometry", "--robot", replayed.robot, "--connect", endpoint) as odometry:
            wait_alive(router, replayed.alive(Service.ODOMETRY))
            replay = run_invent(
                "replay",
                str(recording),
                "--keys",
                str(Topic.MOTOR_WHEEL_ANGLES),
                str(Topic.LOCALIZATION_POSE),
                "--rate",
                "0",
                "--robot",
                replayed.robot,
                "--connect",
                endpoint,
                timeout=120,
            )
            assert replay.returncode == 0, replay.stdout + replay.stderr
            assert "consumers: " in replay.stderr and "→ odometry" in replay.stderr
            got: list[bytes] = []

            def all_poses() -> bool:
                while (sample := poses.try_recv()) is not None:
                    got.append(sample.payload.to_bytes())
                return len(got) >= len(recorded)

            wait_until(all_poses, 10, "the odometry's poses")
            code, _out, err = odometry.stop()
            assert code == 0, err
    assert len(got) == len(recorded)
    differing = next((index for index, (a, b) in enumerate(zip(got, recorded, strict=True)) if a != b), None)
    assert differing is None, f"pose {differing}: {got[differing]!r} replayed, {recorded[differing]!r} recorded"
