"""Real-time settings (``--rt``, ``[rt]``; services/runtime/realtime.py): applied to real processes,
read back from the kernel (/proc), and refused without a crash where the system refuses them."""

import os
import shutil
from pathlib import Path

import pytest

from schemas.keys import Keys, Service
from services.config import ConfigError, CpuChoice
from services.runtime.realtime import chosen_cpus
from services.runtime.session import free_port
from tests.harness import InventProcess, call, peer_session, refused, wait_alive, wait_until

KEYS = Keys("rh0")
CAN_SCHEDULE_FIFO = os.geteuid() == 0
WITHOUT_THE_RIGHTS = ["setpriv", "--bounding-set", "-sys_nice,-ipc_lock", "--inh-caps", "-sys_nice,-ipc_lock"]


ZENOH_THREADS = ("rx-", "tx-", "net-", "acc-", "app-")


def _control_threads(pid: int) -> list[int]:
    """The main thread (the service's) and zenoh's, which receive and send every sample; numpy's
    BLAS pool, started at import and never on the control path, is left as it is."""
    threads = [int(tid) for tid in os.listdir(f"/proc/{pid}/task")]
    return [
        tid
        for tid in threads
        if tid == pid or Path(f"/proc/{pid}/task/{tid}/comm").read_text().startswith(ZENOH_THREADS)
    ]


def _locked_kb(pid: int) -> int:
    line = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("VmLck"))
    return int(line.split()[1])


@pytest.mark.skipif(not CAN_SCHEDULE_FIFO, reason="SCHED_FIFO and mlockall need root (or CAP_SYS_NICE, CAP_IPC_LOCK)")
def test_a_motor_with_rt_runs_its_and_zenohs_threads_sched_fifo_locked_on_its_cpus_its_collector_as_told():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with (
        InventProcess("router", "--listen", endpoint) as router,
        peer_session(endpoint) as session,
        InventProcess(
            "motor", "--connect", endpoint, "--rt", "--set", "rt.priority=30", "--set", "rt.cpus=[0]",
            "--set", 'rt.gc="idle"',
        ) as motor,
    ):  # fmt: skip
        wait_alive(session, KEYS.alive(Service.MOTOR))
        ok, status = call(session, KEYS.status(Service.MOTOR))
        pid = motor.process.pid
        threads = _control_threads(pid)
        policies = {tid: os.sched_getscheduler(tid) for tid in threads}
        priorities = {tid: os.sched_getparam(tid).sched_priority for tid in threads}
        affinities = {tid: os.sched_getaffinity(tid) for tid in threads}
        locked_kb = _locked_kb(pid)
        code, _out, err = motor.stop()
        router.stop()
    assert ok and code == 0, err
    assert len(threads) > 3, "zenoh's threads as well as the service's"
    assert set(policies.values()) == {os.SCHED_FIFO}, policies
    assert set(priorities.values()) == {30}, priorities
    assert all(cpus == {0} for cpus in affinities.values()), affinities
    assert locked_kb > 10_000, "mlockall: the whole process is locked in memory"
    rt = status["rt"]
    assert (rt["policy"], rt["priority"], rt["memory_locked"], rt["cpus"], rt["gc"], rt["refused"]) == (
        "SCHED_FIFO", 30, True, [0], "idle", []
    )  # fmt: skip
    assert "real time: SCHED_FIFO priority 30, memory locked, CPUs [0]" in err


@pytest.mark.skipif(not CAN_SCHEDULE_FIFO, reason="SCHED_FIFO and mlockall need root (or CAP_SYS_NICE, CAP_IPC_LOCK)")
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: nothing to choose")
def test_the_control_path_with_rt_shares_the_last_cpu_by_default():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    last = max(os.sched_getaffinity(0))
    with (
        InventProcess("router", "--listen", endpoint, "--rt") as router,
        peer_session(endpoint) as session,
        InventProcess("motor", "--connect", endpoint, "--rt") as motor,
    ):
        wait_alive(session, KEYS.alive(Service.MOTOR))
        ok, status = call(session, KEYS.status(Service.MOTOR))
        affinities = {
            (name, tid): os.sched_getaffinity(tid)
            for name, process in (("router", router), ("motor", motor))
            for tid in _control_threads(process.process.pid)
        }
        motor.stop()
        router.stop()
    assert ok and status["rt"]["cpus"] == [last], status["rt"]
    assert set(map(frozenset, affinities.values())) == {frozenset({last})}, affinities


def _affinities(processes: dict[str, InventProcess]) -> dict[str, set[frozenset[int]]]:
    """Each process's CPU sets: its main thread's and zenoh's threads'."""
    return {
        name: {frozenset(os.sched_getaffinity(tid)) for tid in _control_threads(process.process.pid)}
        for name, process in processes.items()
    }


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: nothing to partition")
@pytest.mark.parametrize("partition", [True, False])
def test_without_rt_the_control_path_runs_on_the_last_cpu_and_the_observers_on_the_others(partition):
    """rt.partition (default on, no privilege needed): the router and the motor on the last CPU,
    odometry and the view on the CPUs left; off, every process where the system likes."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    available = os.sched_getaffinity(0)
    last = max(available)
    setting = ("--set", f"rt.partition={str(partition).lower()}")
    with (
        InventProcess("router", "--listen", endpoint, *setting) as router,
        peer_session(endpoint) as session,
        InventProcess("motor", "--connect", endpoint, *setting) as motor,
        InventProcess("odometry", "--connect", endpoint, *setting) as odometry,
        InventProcess("view", "--connect", endpoint, "--port", "0", *setting) as view,
    ):
        for service in (Service.MOTOR, Service.ODOMETRY):
            wait_alive(session, KEYS.alive(service))
        wait_until(lambda: call(session, KEYS.view_status)[0], what="the view's status")
        affinities = _affinities({"router": router, "motor": motor, "odometry": odometry, "view": view})
        ok, status = call(session, KEYS.status(Service.MOTOR))
        for process in (view, odometry, motor, router):
            process.stop()
    if partition:
        on_control_path, off_it = {frozenset({last})}, {frozenset(available - {last})}
        assert ok and status["rt"]["cpus"] == [last] and status["rt"]["policy"] == "SCHED_OTHER", status["rt"]
    else:
        on_control_path = off_it = {frozenset(available)}
        assert ok and status["rt"]["cpus"] is None, status["rt"]
    assert affinities == {"router": on_control_path, "motor": on_control_path, "odometry": off_it, "view": off_it}


@pytest.mark.skipif(not CAN_SCHEDULE_FIFO, reason="SCHED_FIFO and mlockall need root (or CAP_SYS_NICE, CAP_IPC_LOCK)")
@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: nothing to choose")
def test_a_composed_loop_with_rt_holds_its_loop_thread_to_the_last_cpu_and_still_answers_from_outside(tmp_path):
    """A composed lockstep loop never blocks: any other thread on its core at its priority (zenoh's,
    zenoh-python's callback threads) would never run, and no query from outside would be answered."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    circle = tmp_path / "circle.toml"
    circle.write_text('name = "circle"\n\n[[segments]]\ntype = "constant"\nvx = 0.2\nw = 0.5\nduration = 100000.0\n')
    last = max(os.sched_getaffinity(0))
    with (
        InventProcess(
            "up", "--composed", "--rt", "--no-record", "--scenario", str(circle), "--listen", endpoint, drain=True
        ) as up,
        peer_session(endpoint) as session,
    ):
        wait_alive(session, KEYS.alive(Service.DRIVE), timeout=30)
        # the drive is alive before the sim starts stepping (up starts the sim last)
        wait_until(lambda: call(session, KEYS.status(Service.SIM))[1]["steps"] > 0, 30, "the sim to step")
        answers = [call(session, KEYS.status(Service.SIM)) for _ in range(3)]
        pid = up.process.pid
        held = [int(tid) for tid in os.listdir(f"/proc/{pid}/task") if os.sched_getaffinity(int(tid)) == {last}]
        up.stop()
    assert all(ok for ok, _status in answers), answers
    statuses = [status for _ok, status in answers]
    assert statuses[-1]["steps"] > statuses[0]["steps"], "the loop runs while it answers"
    assert statuses[-1]["rt"]["cpus"] == [last] and statuses[-1]["rt"]["policy"] == "SCHED_FIFO", statuses[-1]["rt"]
    assert len(held) == 1 and held[0] != pid, f"only the loop's thread (not up's main thread) is held to CPU {last}"


@pytest.mark.parametrize(
    ("cpus", "available", "chosen"),
    [
        (CpuChoice.LAST, {0, 1, 2, 3}, [3]),
        (CpuChoice.LAST, {2, 5}, [5]),
        (CpuChoice.LAST, {1}, []),
        (CpuChoice.ANY, {0, 1}, []),
        ((1, 0), {0, 1, 2}, [0, 1]),
    ],
)
def test_rt_cpus_chooses_the_last_cpu_any_or_the_ones_named(cpus, available, chosen):
    assert chosen_cpus(cpus, available) == chosen


def test_rt_cpus_naming_a_cpu_the_process_may_not_use_is_a_configuration_error():
    with pytest.raises(ConfigError, match=r"`rt.cpus`: CPU \[2\] not among this process's CPUs \[0, 1\]"):
        chosen_cpus((1, 2), {0, 1})


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="setpriv (util-linux) takes the rights away")
def test_a_router_and_a_motor_refused_real_time_say_so_in_one_line_and_serve_without_it():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with (
        InventProcess("router", "--listen", endpoint, "--rt", wrapper=WITHOUT_THE_RIGHTS) as router,
        peer_session(endpoint) as session,
        InventProcess("motor", "--connect", endpoint, "--rt", wrapper=WITHOUT_THE_RIGHTS) as motor,
    ):
        wait_alive(session, KEYS.alive(Service.MOTOR), timeout=30)
        ok, status = call(session, KEYS.status(Service.MOTOR))
        policy = os.sched_getscheduler(motor.process.pid)
        motor_code, _out, motor_err = motor.stop()
        router_code, _out, router_err = router.stop()
    assert ok and motor_code == 0 and router_code == 0, motor_err + router_err
    assert policy == os.SCHED_OTHER
    assert status["rt"]["policy"] == "SCHED_OTHER" and status["rt"]["refused"], status["rt"]
    for who, err in (("router", router_err), ("motor", motor_err)):
        refusals = [line for line in err.splitlines() if "real-time settings refused" in line]
        assert len(refusals) == 1, err
        assert f"invent {who}" in refusals[0] and "SCHED_FIFO priority 50" in refusals[0], refusals
        assert "docs/realtime.md" in refusals[0]


@pytest.mark.parametrize(
    ("command", "setting", "named"),
    [
        (("config",), "rt.priority=100", "rt.priority"),
        (("config",), 'rt.gc="sometimes"', "rt.gc"),
        (("config",), 'rt.cpus="sometimes"', "rt.cpus"),
        (("motor", "--rt", "--connect", "tcp/127.0.0.1:9"), "rt.cpus=[4096]", "rt.cpus"),
        (
            ("router", "--rt", "--listen", "tcp/127.0.0.1:9"),
            "motor.p_gain_l=3",
            "a router takes only the [rt] settings",
        ),
    ],
)
def test_a_real_time_setting_out_of_range_exits_2_naming_it(command, setting, named, capsys):
    code, _out, stderr = refused(capsys, *command, "--set", setting)
    assert code == 2, stderr
    assert named in stderr
