"""Issue 52: in a ``--secure`` run, the particle filter's credentials grant no ground truth, and it
localizes all the same: ``invent up --secure`` (separate processes, each logged in as its role, the
router enforcing the rules), ``localization.mode = amcl`` on the three_rooms map, a goal in the first
room; the estimate against the ground truth of the recording."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import pytest
import zenoh

from schemas.codec import decode
from schemas.keys import Keys, Service
from schemas.messages import TimedDoubleSeq, TimedPosition
from services.recording.mcap_files import read_run
from services.recording.report import pose_from_body_pose
from services.security import ROUTER_CONFIG
from tests.harness import REPO, free_port, invent_command, run_invent

pytestmark = [pytest.mark.slow, pytest.mark.kinematic]

KEYS = Keys()


def intersect(key_expr: str, key: str) -> bool:
    return zenoh.KeyExpr(key_expr).intersects(zenoh.KeyExpr(key))


GOAL = """name = "first_room"

[[goals]]
at = 0.0
x = 1.2
y = -1.0
time_limit = 30.0
id = "corner"
"""


def test_a_secure_amcl_run_has_no_grant_on_the_ground_truth_and_localizes(tmp_path: Path) -> None:
    map_file = tmp_path / "three_rooms.yaml"
    assert run_invent("map", "--world", "three_rooms", "-o", str(map_file)).returncode == 0
    goals = tmp_path / "goal.toml"
    goals.write_text(GOAL)
    report = tmp_path / "report"
    result = subprocess.run(
        invent_command(
            "up",
            "--secure",
            "--engine",
            "kinematic",
            "--listen",
            f"tcp/127.0.0.1:{free_port()}",
            "--report",
            str(report),
            "--set",
            "sim.world=three_rooms",
            "--map",
            str(map_file),
            "--goal-file",
            str(goals),
            "--set",
            "localization.mode=amcl",
            "--set",
            "localization.seed=5",
            "--sim-set",
            "robot.radius_of_right_wheel=0.101",
            "--sim-set",
            "lidar.noise=0.01",
        ),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    output = result.stdout[-4000:] + result.stderr[-3000:]
    assert result.returncode == 0, output

    router = json.loads(str(zenoh.Config.from_file(str(report / "secrets" / ROUTER_CONFIG))))
    access = router["access_control"]
    (policy,) = [policy for policy in access["policies"] if "role-localization" in policy["subjects"]]
    subscribed = [
        key
        for rule in access["rules"]
        if rule["id"] in policy["rules"] and "declare_subscriber" in rule["messages"] and rule["flows"] == ["ingress"]
        for key in rule["key_exprs"]
    ]
    assert subscribed, "the localization subscribes to something"
    for key in subscribed:
        assert not (intersect(key, KEYS.sim_body_pose) or intersect(key, KEYS.motor_sim_pose_localization)), key

    messages = read_run(report / "run.mcap").messages
    truth = {}
    for message in messages:
        if message.topic == KEYS.sim_body_pose:
            sample = decode(TimedDoubleSeq, message.data)
            truth[sample.tm.to_nanoseconds()] = pose_from_body_pose(sample.data)
    estimates = [decode(TimedPosition, m.data) for m in messages if m.topic == KEYS.localization_pose]
    assert len(estimates) > 5 and all(len(estimate.error) == 6 for estimate in estimates), "amcl's estimates"
    errors = [
        math.hypot(estimate.x - truth[stamp].x, estimate.y - truth[stamp].y)
        for estimate in estimates
        if (stamp := estimate.tm.to_nanoseconds()) in truth
    ]
    print(f"secure amcl: {len(errors)} estimates, worst {max(errors) * 100:.2f} cm")
    assert max(errors) <= 0.10
    statuses = [json.loads(m.data) for m in messages if m.topic == KEYS.status(Service.LOCALIZATION)]
    assert statuses[-1]["filter"]["updates"] > 10 and statuses[-1]["bad_input"]["total"] == 0
