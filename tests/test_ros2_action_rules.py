"""NavigateToPose over the wire, checked against rcl_action's and Nav2's rules by a client in
rmw_zenoh's wire format (tests/ros_client.py, written apart from the bridge), against one
``invent up --goals --ros2`` (composed, kinematic engine: the action is the point, not the physics;
``ros2.result_timeout`` short): every ``get_result`` held until its goal ends, however many; a
preempted goal ABORTED as Nav2's navigator ends it; goals in any frame of the bridge's TF tree (a
``base_link`` goal relative to the robot), one in a frame it cannot transform accepted then ABORTED
with the reason, through ``goal_pose`` too; results kept for ``result_timeout``, more than sixteen
of them, a UUID refused while its result is kept and taken again after; cancel by id, by stamp and
all; and every goal's statuses through the run following rcl_action's goal state machine.
"""

from __future__ import annotations

import math
import os
import subprocess
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import zenoh

from schemas.keys import Keys, Service
from tests import ros_client, ros_services
from tests.harness import (
    REPO,
    at_rest,
    call,
    free_port,
    invent_command,
    peer_session,
    status_reply,
    wait_alive,
    wait_until,
)

pytestmark = [pytest.mark.slow, pytest.mark.kinematic]

KEYS = Keys()
ACTION = "/navigate_to_pose"
STATUS = f"{ACTION}/_action/status"
RESULT_TIMEOUT_S = 8.0
"""``ros2.result_timeout`` of the run, in simulated seconds (Nav2's is 900)."""
STARTUP_TIMEOUT_S = 90.0
HELD = 20
"""``get_result`` calls held at once for one goal: more than the 16 the bridge once held in all."""
SUCCEEDED, CANCELED, ABORTED, CANCELING, EXECUTING = 4, 5, 6, 3, 2
TF_ERROR = 9002


@dataclass
class Run:
    session: zenoh.Session
    recorder: ros_client.Recorder
    client: ros_services.ActionClient
    node: ros_client.RosNode

    def status(self, service: Service) -> dict[str, Any]:
        return status_reply(self.session, KEYS, service)

    def pose(self) -> tuple[float, float, float]:
        pose = self.status(Service.SIM)["pose"]
        return pose["x"], pose["y"], pose["theta"]

    def ahead(self, distance: float) -> tuple[float, float, float]:
        x, y, theta = self.pose()
        return x + distance * math.cos(theta), y + distance * math.sin(theta), theta

    def paths(self) -> list[tuple[bytes, list[int]]]:
        return ros_services.status_paths([sample.payload for sample in self.recorder.of(STATUS)])

    def path(self, uuid: bytes) -> list[int]:
        """The goal's statuses (its last life, if its UUID was taken again)."""
        return next((path for goal, path in reversed(self.paths()) if goal == uuid), [])

    def wait_status(self, uuid: bytes, status: int, timeout: float = 30.0) -> list[int]:
        """The goal's statuses once the last is ``status``: the status topic and a result reply are
        separate channels, so a result may come before the status array that ends the goal."""
        return wait_until(
            lambda: (path := self.path(uuid)) and path[-1] == status and path, timeout, f"status {status}"
        )

    def listed(self, uuid: bytes) -> bool:
        samples = self.recorder.of(STATUS)
        return bool(samples) and uuid in ros_services.goal_statuses(samples[-1].payload)

    def navigate(self) -> dict[str, Any]:
        return self.status(Service.ROS2)["navigate"]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    directory: Path = tmp_path_factory.mktemp("action-rules")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    flags = ["--goals", "--ros2", "--composed", "--engine", "kinematic", "--no-record", "--listen", endpoint]
    flags += ["--set", "sim.world=empty", "--set", f"ros2.result_timeout={RESULT_TIMEOUT_S}"]
    with (directory / "up.log").open("w") as log:
        up = subprocess.Popen(invent_command("up", *flags), cwd=REPO, stdout=log, stderr=subprocess.STDOUT, text=True)
        try:
            with peer_session(endpoint) as session:
                recorder = ros_client.Recorder(session, "0/**")
                wait_alive(session, KEYS.alive(Service.ROS2), STARTUP_TIMEOUT_S)
                wait_alive(session, KEYS.alive(Service.DRIVE), STARTUP_TIMEOUT_S)
                loop = Run(session, recorder, ros_services.ActionClient(session, ACTION), ros_client.RosNode(session))
                wait_until(lambda: loop.navigate()["drive_serves_goals"], STARTUP_TIMEOUT_S, "the drive's goals")
                wait_until(lambda: recorder.of("tf"), STARTUP_TIMEOUT_S, "the first /tf")
                yield loop
                recorder.close()
        finally:
            up.send_signal(2)
            try:
                up.wait(60)
            except subprocess.TimeoutExpired:
                up.kill()
    assert up.returncode == 0, (directory / "up.log").read_text()[-3000:]


def _running(run: Run, distance: float = 3.0) -> bytes:
    uuid, reply = run.client.send_goal(*run.ahead(distance))
    assert reply.response.accepted, run.navigate()
    run.wait_status(uuid, EXECUTING)
    return uuid


def test_every_get_result_is_held_until_its_goal_ends_however_many(run):
    """rclpy completes its future with the reply: one answered early says "done" while the robot drives."""
    uuid = _running(run)
    with ThreadPoolExecutor(HELD) as pool:
        calls = [pool.submit(run.client.get_result, uuid, 60.0) for _ in range(HELD)]
        wait_until(lambda: run.navigate()["waiting"]["results"] == HELD, 20.0, f"{HELD} calls held")
        assert not any(call.done() for call in calls), "none answered while the goal runs"
        assert run.client.cancel(uuid).response.return_code == 0
        replies = [call.result(timeout=60.0) for call in calls]
    assert {(reply.response.status, reply.response.result.error_code) for reply in replies} == {(CANCELED, 0)}
    assert all(reply.attachment[0] == reply.sequence_number for reply in replies), "each reply its own call's"


def test_a_preempted_goal_ends_aborted_as_nav2s_navigator_ends_it(run):
    first = _running(run)
    second = _running(run)
    result = run.client.get_result(first).response
    assert result.status == ABORTED and second.hex() in result.result.error_msg, result
    assert run.wait_status(first, ABORTED)[-2:] == [EXECUTING, ABORTED], "never canceling nor canceled: no one asked"
    run.client.cancel(second)
    assert run.client.get_result(second).response.status == CANCELED


def _started(run: Run, uuid: bytes) -> dict[str, Any]:
    """The goal the drive started last (``drive/goal``, latched), once it is ``uuid``'s."""
    return wait_until(
        lambda: (answer := call(run.session, KEYS.drive_goal))[0] and answer[1]["id"] == uuid.hex() and answer[1],
        20.0,
        "the drive to start the goal",
    )


def test_a_goal_in_base_link_is_relative_to_the_robot_and_reached(run):
    wait_until(lambda: at_rest(run.pose), 20.0, "the robot at rest")
    x, y, theta = run.pose()
    uuid, reply = run.client.send_goal(0.5, 0.0, 0.0, frame="base_link")
    assert reply.response.accepted
    target = _started(run, uuid)
    assert target["frame"] == "map", target
    ahead = (x + 0.5 * math.cos(theta), y + 0.5 * math.sin(theta))
    assert math.hypot(target["x"] - ahead[0], target["y"] - ahead[1]) < 0.05, (target, ahead)
    assert abs(math.remainder(target["theta"] - theta, math.tau)) < 0.05, "facing as the robot faced"
    assert run.client.get_result(uuid, timeout=60.0).response.status == SUCCEEDED


def test_a_goal_in_a_frame_the_bridge_cannot_transform_is_accepted_then_aborted_with_the_reason(run):
    sent_before = run.navigate()["sent"]
    uuid, reply = run.client.send_goal(1.0, 0.0, 0.0, frame="earth")
    assert reply.response.accepted, "accepted, as Nav2's navigator accepts it"
    result = run.client.get_result(uuid).response
    assert (result.status, result.result.error_code) == (ABORTED, TF_ERROR)
    assert "frame_id 'earth'" in result.result.error_msg and "not in the bridge's TF tree" in result.result.error_msg
    assert run.wait_status(uuid, ABORTED) == [1, EXECUTING, ABORTED]
    listed = {goal for goal, _ in run.paths()}
    run.node.put("goal_pose", ros_services.pose_stamped(1.0, 0.0, 0.0, "earth", ros_client.TYPESTORE))
    new = wait_until(lambda: [g for g, path in run.paths() if g not in listed and path[-1] == ABORTED], 10.0, "it")
    assert len(new) == 1, "through goal_pose too: a goal aborted in the status, never vanishing"
    assert run.navigate()["sent"] == sent_before and run.navigate()["frame_errors"] >= 2, "none reached the drive"


def test_results_are_kept_for_result_timeout_beyond_sixteen_and_a_uuid_refused_meanwhile(run):
    burst = [run.client.send_goal(1.0, 0.0, 0.0, frame="earth")[0] for _ in range(20)]
    first = burst[0]
    assert run.client.get_result(first).response.status == ABORTED, "the first of 20 results still kept"
    again = run.client.call(
        "send_goal", ros_services.send_goal_request(first, ros_services.pose_stamped(1.0, 0.0, 0.0))
    )
    assert not again.response.accepted, "its UUID is not taken again while its result is kept"
    assert "exists already" in run.navigate()["last_rejection"]
    wait_until(lambda: not run.listed(first), 3 * RESULT_TIMEOUT_S + 30.0, "the result forgotten after its time")
    assert run.client.get_result(first).response.status == 0, "unknown once forgotten, as rcl_action"
    reused = ros_services.send_goal_request(first, ros_services.pose_stamped(1.0, 0.0, 0.0, "earth"))
    assert run.client.call("send_goal", reused).response.accepted, "the UUID taken again"


def test_cancel_by_stamp_cancels_the_goals_accepted_at_or_before_it(run):
    uuid, reply = run.client.send_goal(*run.ahead(3.0))
    run.wait_status(uuid, EXECUTING)
    stamp_ns = reply.response.stamp.sec * 1_000_000_000 + reply.response.stamp.nanosec
    before = run.client.cancel(stamp_ns=stamp_ns - 1).response
    assert before.return_code == 0 and list(before.goals_canceling) == [], "accepted after the stamp: not canceled"
    canceled = run.client.cancel(stamp_ns=stamp_ns).response
    assert [bytes(bytearray(g.goal_id.uuid)) for g in canceled.goals_canceling] == [uuid]
    assert run.client.get_result(uuid).response.status == CANCELED
    assert run.wait_status(uuid, CANCELED)[-3:] == [EXECUTING, CANCELING, CANCELED]
    other, _ = run.client.send_goal(*run.ahead(3.0))
    run.wait_status(other, EXECUTING)
    assert run.client.cancel(os.urandom(16)).response.return_code == 2, "an unknown id"
    everything = run.client.cancel().response
    assert [bytes(bytearray(g.goal_id.uuid)) for g in everything.goals_canceling] == [other], "zero id and stamp: all"
    assert run.client.get_result(other).response.status == CANCELED
    assert run.client.cancel(other).response.return_code == 3, "terminated"


def test_every_goals_statuses_through_the_run_follow_rcl_actions_state_machine(run):
    paths = run.paths()
    assert len(paths) > 25
    deviations = {goal.hex(): found for goal, path in paths if (found := ros_services.state_machine_deviations(path))}
    assert deviations == {}, deviations
    assert run.status(Service.ROS2)["internal_errors"] == 0
