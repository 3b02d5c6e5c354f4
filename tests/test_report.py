"""The run's health in the report: the sim's torque figures and each service's counters, and
when a run counts as degraded; the outcome of a run that ended early, what a report lacks, and the
health rebuilt from recorded status replies, whatever they hold."""

import json

import msgspec
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas.status import DroppedParticipant
from services.recording.report import (
    DEGRADED_FRACTION,
    degradations,
    early_outcome,
    loop_health,
    missing_parts,
    readable_status,
    recorded_health,
)
from tests.status_samples import drive_status, service_status, sim_status


def test_realtime_late_and_missing_fractions_come_from_the_sims_counters():
    health = loop_health(
        sim_status("realtime", 15_490, realtime_late_steps=12_930, missing_torques=6_114, realtime_resyncs=3),
        {"motor": service_status(bad=2), "odometry": service_status(), "sim": None},
    )
    assert health["torques"]["late_fraction"] == 12_930 / 15_490
    assert health["torques"]["missing_fraction"] == 6_114 / 15_490
    assert health["realtime"]["resyncs"] == 3
    assert health["services"] == {
        "motor": {"bad_inputs": 2, "internal_errors": 0, "dropped_events": 0},
        "odometry": {"bad_inputs": 0, "internal_errors": 0, "dropped_events": 0},
    }
    reasons = degradations(health)
    assert len(reasons) == 2 and "late torques on 83.5%" in reasons[0] and "missing torques on 39.5%" in reasons[1]


def test_a_clean_run_is_not_degraded_and_the_threshold_is_exclusive():
    steps = 10_000
    at_threshold = round(steps * DEGRADED_FRACTION)
    health = loop_health(
        sim_status("realtime", steps, realtime_late_steps=at_threshold), {"motor": service_status(bad=5)}
    )
    assert degradations(health) == [], "bad input refused is no degradation of the loop"
    health = loop_health(sim_status("realtime", steps, realtime_late_steps=at_threshold + 1), {})
    assert len(degradations(health)) == 1


def test_an_internal_error_or_a_dropped_event_degrades_a_run_and_a_lockstep_step_is_never_late():
    health = loop_health(
        sim_status("lockstep", 20_000, missing_torques=3),
        {"motor": service_status(internal=1), "odometry": service_status(dropped=7)},
    )
    assert health["torques"]["late"] == 0 and health["torques"]["missing"] == 3, "a lockstep step waits"
    assert degradations(health) == ["motor: 1 internal errors", "odometry: 7 dropped events"]


def test_no_sim_status_gives_zeros_not_an_error():
    health = loop_health(None, {})
    assert health["torques"]["late_fraction"] == 0.0 and degradations(health) == []


def test_a_drive_tick_commanded_from_an_older_pose_degrades_a_lockstep_run():
    drive = drive_status(pose_wait_timeouts=1)
    health = loop_health(sim_status("lockstep", 20_000), {"motor": service_status(), "drive": drive})
    assert health["lockstep"]["pose_wait_timeouts"] == 1
    (reason,) = degradations(health)
    assert reason.startswith("1 drive ticks commanded from an older pose")
    realtime = loop_health(sim_status("realtime", 20_000), {"drive": drive})
    assert degradations(realtime) == [], "in realtime the drive never waits for a pose"


def test_a_health_recorded_before_the_drive_was_reported_still_reads():
    health = loop_health(sim_status("lockstep", 20_000), {})
    del health["lockstep"]["pose_wait_timeouts"]
    assert degradations(health) == []


def test_the_outcome_of_a_run_a_service_ended_says_which_and_how():
    killed = early_outcome("service_died", "odometer", -9, 2.5)
    assert (killed["reason"], killed["signal"], killed["exit_code"], killed["t_s"]) == (
        "odometer killed by SIGKILL",
        "SIGKILL",
        None,
        2.5,
    )
    exited = early_outcome("service_died", "control", 1, 0.0)
    assert (exited["reason"], exited["signal"], exited["exit_code"]) == ("control exited with code 1", None, 1)
    assert early_outcome("service_died", "sim", -999, 0.0)["reason"] == "sim killed by signal 999"
    interrupted = early_outcome("interrupted", "", None, 1.0)
    assert interrupted == {
        "outcome": "interrupted",
        "reason": "Ctrl-C or SIGTERM before the scenario ended",
        "t_s": 1.0,
    }


def test_what_a_report_lacks_is_said_once_each_and_nothing_for_a_whole_run():
    whole = {"complete": True, "summary": True, "outcome": True, "statuses": False, "ground_truth": True}
    assert missing_parts(**whole) == []
    cut = missing_parts(**{**whole, "complete": False, "summary": False, "outcome": False})
    assert cut[0].startswith("the file was cut short")
    assert cut[1] == (
        "no run summary: the run did not end cleanly; outcome unknown, wall time unknown, the loop's health unknown"
    )
    assert missing_parts(**{**whole, "ground_truth": False}) == [
        "no ground truth (sim/body_pose): no final pose, no odometry or path error"
    ]


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda children: st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=12), children, max_size=4),
    max_leaves=12,
)


# nested JSON is slow to draw on a loaded machine: the draws are the point, not their speed
@settings(suppress_health_check=[HealthCheck.too_slow])
@given(
    st.dictionaries(
        st.sampled_from(["sim", "motor", "drive", "odometer"]),
        st.fixed_dictionaries(
            {"bad_input": st.one_of(json_values, st.fixed_dictionaries({"total": json_values}))},
            optional={
                "internal_errors": json_values,
                "steps": json_values,
                "mode": json_values,
                "counters": json_values,
                "navigation": json_values,
                "collision_monitor": json_values,
                "pose_wait_timeouts": json_values,
            },
        )
        | json_values,
    )
)
def test_recorded_status_replies_never_break_the_health_only_the_readable_count(statuses):
    readable = {
        name: status
        for name, reply in statuses.items()
        if (status := readable_status(name, json.dumps(reply).encode())) is not None
    }
    health = recorded_health(readable)
    degradations(health)
    assert set(health["services"]) <= set(readable) <= set(statuses)


def test_a_recorded_reply_of_its_kind_is_read_and_one_of_another_shape_is_not():
    sim = msgspec.json.encode(sim_status("lockstep", 20_000, missing_torques=3))
    readable = readable_status("sim", sim)
    assert readable is not None and readable[0].counters.missing_torques == 3
    assert readable_status("motor", sim) is None, "a sim's reply is no motor's"
    assert readable_status("sim", sim.replace(b'"steps":20000', b'"steps":"many"')) is None
    assert readable_status("sim", b"not json") is None
    user = readable_status(
        "odometer", b'{"poses": 3, "sim_alive": true, "sim_time_s": null, "lockstep": null, "outputs": {}, "calls": {}}'
    )
    assert user is not None and user[1]["poses"] == 3, "a user service's own fields come with it"
    assert recorded_health({"odometer": user})["user_services"] == {"odometer": user[1]}


def test_a_participant_dropped_mid_run_is_named_and_degrades_it_but_long_waits_do_not():
    sim = sim_status("lockstep", 20_000, (DroppedParticipant("localization", 3.2),), long_waits=3)
    health = loop_health(sim, {"sim": service_status()})
    assert "long_waits" not in health["lockstep"], "how long waits took is the machine's, as the wall time"
    (reason,) = degradations(health)
    assert reason == "localization dropped at t = 3.200 s (its token went first)"
    health = loop_health(sim_status("lockstep", 20_000, long_waits=3), {"sim": service_status()})
    assert degradations(health) == [], "a wait that went on is only slower: the run is the same"
