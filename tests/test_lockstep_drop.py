"""A lockstep sim waits for a participant as long as its liveliness token lives, and drops one
whose process dies at once: real processes over a real router (``invent sim``, ``invent
localization``), the participant killed with SIGKILL while the sim waits at its tick."""

from __future__ import annotations

import os
import signal
import time

import zenoh

from schemas.keys import Keys, Service
from tests.harness import InventProcess, status_reply, wait_alive, wait_until

KEYS = Keys()
TIMEOUT_S = 0.1
"""``sim.lockstep_timeout`` of the run: how often a wait that goes on is said, nothing more."""


def sim_status(session: zenoh.Session) -> dict:
    return status_reply(session, KEYS, Service.SIM)


def test_a_participant_is_waited_for_while_it_lives_and_dropped_at_once_when_its_process_is_killed(session, endpoint):
    """The stub localization's first fix needs the motor's simulated pose, which never comes (no
    motor): the sim's first step, a tick of the localization's, waits for it, far past the
    timeout, until the process is killed; then the sim steps on, its status naming the drop."""
    with InventProcess("localization", "--connect", endpoint, drain=True) as localization:
        wait_alive(session, KEYS.alive(Service.LOCALIZATION))
        with InventProcess(
            "sim",
            "--connect",
            endpoint,
            "--wait-for",
            "localization",
            "--set",
            f"sim.lockstep_timeout={TIMEOUT_S}",
            drain=True,
        ) as sim:
            wait_alive(session, KEYS.alive(Service.SIM))
            waiting = wait_until(
                lambda: (status := sim_status(session))["counters"]["long_waits"] and status, what="a long wait"
            )
            time.sleep(20 * TIMEOUT_S)  # a give-up at the timeout would have stepped on by now
            still = sim_status(session)
            assert waiting["steps"] == still["steps"] == 0, "the first step waits at the localization's tick"
            assert still["lockstep_participants"]["localization"]["waited_for"] is True
            assert still["counters"]["long_waits"] == 1 and still["dropped_participants"] == []

            killed_at = time.monotonic()
            os.kill(localization.process.pid, signal.SIGKILL)
            wait_until(lambda: sim_status(session)["steps"] > 0, timeout=10, what="the sim to step on")
            stepped_on_s = time.monotonic() - killed_at
            print(f"the sim stepped on {stepped_on_s:.2f} s of wall time after the participant's SIGKILL")
            status = sim_status(session)
            assert status["dropped_participants"] == [{"service": "localization", "sim_time_s": 0.0}]
            assert "localization" not in status["lockstep_participants"]
            code, _out, err = sim.stop()
        assert code == 0, err
        assert "still waiting for localization/pose for t = 0.000 s after " in err
        assert "localization gone at t = 0.000 s (its liveliness token): dropped" in err
