"""``invent control``: the sim and the motor composed in one process, over a router, as docker
compose's control container runs them (real router, real processes); and which runs of ``invent
up`` start it in place of the two (a plain function, no zenoh)."""

from __future__ import annotations

import json
import math

import msgspec

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq, TimedVelocity
from schemas.status import ControlStatus
from schemas.topics import Method, MethodFamily
from services.config import SimMode
from services.exits import ExitStatus
from services.launch.plan import UpPlan
from services.launch.up import composes_control_path
from tests.harness import (
    REPO,
    Collector,
    InventProcess,
    call,
    peer_session,
    refused,
    running_router,
    wait_alive,
    wait_until,
)

ROBOT = "ctl"
KEYS = Keys(ROBOT)


def _reply(session, key: str) -> dict:
    ok, reply = call(session, key)
    assert ok, reply
    return reply


def test_one_invent_control_process_serves_the_sim_and_the_motor_and_a_target_velocity_moves_the_robot(tmp_path):
    with running_router() as endpoint, peer_session(endpoint) as session:
        poses = Collector(session, KEYS.sim_body_pose, TimedDoubleSeq)
        flags = ("--connect", endpoint, "--robot", ROBOT)
        state = tmp_path / "motor.json"
        with InventProcess("control", *flags, "--mode", "realtime", "--state", str(state), drain=True) as control:
            wait_alive(session, KEYS.alive(Service.MOTOR))
            wait_alive(session, KEYS.alive(Service.SIM))
            start = poses.get(timeout=10.0).data
            forward = encode(TimedVelocity(Time.from_nanoseconds(0), [], 0.2, 0.0, 0.0, []))

            def moved() -> bool:
                session.put(KEYS.drive_target_velocity, forward)
                pose = poses.drain()
                return bool(pose) and math.dist(pose[-1].data[:2], start[:2]) > 0.05

            wait_until(moved, 20.0, "the robot to move 5 cm forward")
            sim, motor = _reply(session, KEYS.status(Service.SIM)), _reply(session, KEYS.status(Service.MOTOR))
            whole = _reply(session, KEYS.control_status)
            stopped, _ = call(session, KEYS.method(MethodFamily.GUI, Method.STOP))
            code, _, log = control.stop()
        with InventProcess("control", *flags, "--mode", "realtime", "--state", str(state), drain=True) as again:
            wait_alive(session, KEYS.alive(Service.MOTOR))
            restarted = _reply(session, KEYS.status(Service.MOTOR))
            again.stop()
        poses.close()
    assert sim["service"] == "sim" and motor["service"] == "motor"
    assert motor["state"] == "running"
    assert sim["counters"]["torques_applied"] > 0, "the motor's torques reached the sim in the process"
    assert whole["service"] == "control" and whole["state"] == "running", "the process's own status"
    assert set(whole["services"]) == {"sim", "motor"} and whole["steps"] >= sim["steps"]
    assert whole["internal_errors"] == 0
    typed = msgspec.json.decode(json.dumps(whole), type=ControlStatus)
    assert typed.services.sim.service == "sim" and typed.services.motor.state == "running", "each status as its kind's"
    assert "started motor in this process" in log and "started sim in this process" in log
    assert code == ExitStatus.OK, log
    assert stopped and restarted["state"] == "stopped", "an operator's stop held across the restart"


def test_invent_control_ends_with_the_sims_exit_status_when_its_duration_is_up(tmp_path):
    with running_router() as endpoint, peer_session(endpoint) as session:
        flags = ("--connect", endpoint, "--robot", ROBOT, "--state", str(tmp_path / "motor.json"))
        with InventProcess("control", *flags, "--duration", "0.5", drain=True) as control:
            control.process.wait(30.0)
            code, _, log = control.stop()
        assert not list(session.liveliness().get(KEYS.alive(Service.MOTOR), timeout=1.0)), "the motor went too"
    assert code == ExitStatus.OK, log
    assert "sim returned 0: stopping the others" in log


def test_invent_control_refuses_a_fleet_naming_the_flag(capsys):
    code, _, err = refused(capsys, "control", "--fleet", str(REPO / "examples" / "fleets" / "two_squares.toml"))
    assert code == ExitStatus.CONFIG
    assert "invent control --fleet" in err


def test_invent_up_composes_the_control_path_in_realtime_runs_of_one_robot_only():
    """Which runs of ``invent up`` start ``invent control`` in place of a sim and a motor apart:
    realtime ones of one robot in separate processes, unless ``--split`` (docs/realtime.md)."""
    realtime, lockstep = SimMode.REALTIME, SimMode.LOCKSTEP
    assert composes_control_path(UpPlan(), realtime)
    assert not composes_control_path(UpPlan(), lockstep), "a lockstep run has no late steps: as it was"
    assert not composes_control_path(UpPlan(split=True), realtime)
    assert not composes_control_path(UpPlan(composed=True), realtime), "the whole loop is one process already"
    assert not composes_control_path(UpPlan(fleet="fleet.toml"), realtime), "a fleet's sim is the fleet's"
