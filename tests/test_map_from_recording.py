"""``invent map --from run.mcap``: a map built from a recording's scans and wheel angles, or its
odometry poses when it holds no wheel angles (a synthetic run written with the recorder's own
McapWriter, the left wheel read 1 % long), through the real entry point; and its refusals (not an MCAP
file, no scans, no motion, several robots unnamed, --world with --from), each exiting 2 and naming why."""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np
import pytest

from schemas.keys import Keys
from schemas.messages import Time, TimedDoubleSeq, TimedPosition
from services.navigation.grid import OCCUPIED
from services.navigation.map_file import read_map
from services.recording.mcap_files import McapWriter
from tests.harness import refused, run_invent
from tests.mapping_world import box, drive, run_of, share_near_walls

ROOM = np.array(box(0.0, 0.0, 4.0, 3.0) + box(0.8, -0.6, 0.4, 0.3), dtype=np.float64)
TOUR = [(-1.0, 0.0), (1.0, 0.8), (-1.2, -0.8), (0.0, 0.0)]


def write_run(
    path: Path, robots: tuple[str, ...] = ("rh0",), scans: bool = True, odometry: bool = True, wheels: bool = True
) -> None:
    """A recording of a short drive in ROOM: each robot's scans, odometry poses and wheel angles on their keys."""
    writer = McapWriter(path)
    for robot in robots:
        keys = Keys(robot)
        for step, scan in run_of(ROOM, list(drive(TOUR)), seed=7):
            stamp = Time.from_nanoseconds(step.stamp_ns)
            if odometry:
                pose = TimedPosition(
                    tm=stamp, id=[], x=step.odometry.x, y=step.odometry.y, theta=step.odometry.theta, error=[]
                )
                writer.write_sample(keys.odometry_pose, msgspec.json.encode(pose), step.stamp_ns)
            if wheels:
                angles = TimedDoubleSeq(tm=stamp, data=list(step.wheel_angles))
                writer.write_sample(keys.motor_wheel_angles, msgspec.json.encode(angles), step.stamp_ns)
            if scans and scan is not None:
                writer.write_sample(keys.sim_scan, msgspec.json.encode(scan), step.stamp_ns)
    writer.close()


@pytest.mark.parametrize("motion", ["motor/wheel_angles", "odometry/pose"])
def test_a_map_from_a_recorded_run_lies_on_the_walls(tmp_path, motion):
    """Posed by the wheels' angles when the recording holds them, else by the odometry's poses."""
    recording = tmp_path / "run.mcap"
    write_run(recording, wheels=motion == "motor/wheel_angles")
    result = run_invent("map", "--from", str(recording), "-o", str(tmp_path / "map.yaml"), "--resolution", "0.05")
    assert result.returncode == 0, result.stderr
    assert "robot rh0:" in result.stdout and "wrote" in result.stdout
    assert f"samples of invent/rh0/{motion}" in result.stdout
    assert "to lie where the run started" in result.stdout
    assert "100 % of" in result.stderr  # progress
    grid = read_map(tmp_path / "map.yaml")
    assert np.count_nonzero(grid.cells == OCCUPIED) > 100
    assert share_near_walls(grid, ROOM) >= 0.9


def test_a_fleets_recording_maps_the_robot_named(tmp_path, capsys):
    recording = tmp_path / "run.mcap"
    write_run(recording, robots=("rh0", "rh1"))
    code, _, err = refused(capsys, "map", "--from", str(recording), "-o", str(tmp_path / "map.yaml"))
    assert code == 2
    assert "several robots (rh0, rh1)" in err and "--robot" in err
    code, out, _ = refused(capsys, "map", "--from", str(recording), "--robot", "rh1", "-o", str(tmp_path / "map.yaml"))
    assert code == 0 and "robot rh1:" in out
    code, _, err = refused(capsys, "map", "--from", str(recording), "--robot", "rh7", "-o", str(tmp_path / "map.yaml"))
    assert code == 2 and "no robot 'rh7'" in err


@pytest.mark.parametrize(
    ("what", "reason"),
    [
        ("not_mcap", "not an MCAP file"),
        ("no_keys", "not a run's recording"),
        ("no_scans", "no scans of robot 'rh0'"),
        ("no_motion", "no wheel angles (invent/rh0/motor/wheel_angles) nor odometry poses"),
    ],
)
def test_a_recording_it_cannot_map_is_refused_naming_why(tmp_path, capsys, what, reason):
    recording = tmp_path / "run.mcap"
    if what == "not_mcap":
        recording.write_text("a run's notes, not its recording\n")
    elif what == "no_keys":
        writer = McapWriter(recording)
        writer.write_sample("somewhere/else", b"{}", 0)
        writer.close()
    else:
        write_run(recording, scans=what != "no_scans", odometry=what != "no_motion", wheels=what != "no_motion")
    code, _, err = refused(capsys, "map", "--from", str(recording), "-o", str(tmp_path / "map.yaml"))
    assert code == 2
    assert reason in err and str(recording) in err
    assert not (tmp_path / "map.yaml").exists()


def test_from_and_world_are_one_or_the_other(tmp_path, capsys):
    code, _, err = refused(capsys, "map", "--from", "run.mcap", "--world", "room", "-o", str(tmp_path / "map.yaml"))
    assert code == 2 and "not allowed with argument" in err
    code, _, err = refused(capsys, "map", "--world", "room", "--robot", "rh0", "-o", str(tmp_path / "map.yaml"))
    assert code == 2 and "--robot goes with --from" in err
