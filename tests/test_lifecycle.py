"""Every service: alive while it runs, clean exit 0 on SIGINT and SIGTERM, token withdrawn."""

import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh

from schemas.keys import Keys, Service
from services.exits import ExitStatus
from tests.harness import REPO, InventProcess, invent_command, wait_alive, wait_until


@pytest.mark.parametrize("stop_signal", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("service", list(Service), ids=str)
def test_service_exits_0_on_signal_and_withdraws_its_token(endpoint, session, service, stop_signal):
    token = Keys("rh0").alive(service)
    withdrawn = threading.Event()
    watcher = session.liveliness().declare_subscriber(
        token, lambda sample: sample.kind == zenoh.SampleKind.DELETE and withdrawn.set()
    )
    extra = ("--scenario", "square") if service is Service.DRIVE else ()
    with InventProcess(str(service), "--connect", endpoint, *extra) as process:
        wait_alive(session, token)
        process.process.send_signal(stop_signal)
        code, _out, err = process.stop()
    assert code == 0, err
    wait_until(withdrawn.is_set, 10, f"{token} to be withdrawn")
    watcher.undeclare()


@pytest.mark.parametrize("delay_s", [0.1, 0.2, 0.3])
def test_a_service_interrupted_while_it_starts_exits_without_a_traceback_of_its_code(endpoint, delay_s):
    """``invent up`` stops every service with SIGINT when one fails to start; one still importing or
    opening its session then says it was interrupted (130), or stops as usual (0). A signal that
    lands while the interpreter itself starts (before any of the project's code: a loaded machine
    can take that long) is Python's to report; no frame of the project's may ever show."""
    process = subprocess.Popen(
        invent_command("localization", "--connect", endpoint),
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    stopped = threading.Timer(delay_s, process.send_signal, (signal.SIGINT,))
    stopped.start()
    try:
        _out, err = process.communicate(timeout=20)
    finally:
        stopped.cancel()
        if process.poll() is None:
            process.kill()
    frames = re.findall(r'File "([^"]+)"', err)
    # the venv may live in the repository (.venv): its frames (site's start-up) are the interpreter's
    ours = [frame for frame in frames if frame.startswith(str(REPO)) and not frame.startswith(sys.prefix)]
    assert not ours, err
    if not frames:
        # 0: it had started and stopped as usual; 130: interrupted while starting; killed by SIGINT:
        # the interpreter (seen under load, after the project's own line) ends so on an interrupt.
        assert process.returncode in (0, ExitStatus.INTERRUPTED, -signal.SIGINT), err


IGNORING_SIGINT = (
    "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_IGN); os.execv(sys.argv[1], sys.argv[1:])"
)
"""A ``python -c`` that runs its arguments (the same process, after ``exec``) with SIGINT ignored."""


def started_taking_sigint(pid: int) -> bool:
    """Whether process ``pid`` is the service (past the ``exec``) and no longer ignores SIGINT."""
    proc = Path(f"/proc/{pid}")
    if (proc / "cmdline").read_bytes().split(b"\0")[1:3] != [b"-m", b"services.cli"]:
        return False
    ignored = re.search(r"^SigIgn:\s*([0-9a-f]+)$", (proc / "status").read_text(), re.MULTILINE)
    return ignored is not None and not int(ignored.group(1), 16) & (1 << (signal.SIGINT - 1))


def test_a_service_started_with_sigint_ignored_takes_it_back_at_once_and_an_early_sigint_interrupts_it(endpoint):
    """A script's background job (a shell without job control) starts a service with SIGINT
    ignored, which Python leaves so: the entry point takes it back before importing the project, so a
    SIGINT sent as soon as it has (the service still starting) interrupts it (130), not only one
    sent once the service has taken over its signals."""
    command = invent_command("localization", "--connect", endpoint)
    process = subprocess.Popen(
        [sys.executable, "-c", IGNORING_SIGINT, *command], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True
    )
    try:
        wait_until(lambda: started_taking_sigint(process.pid), 20, "the entry point to take SIGINT back")
        process.send_signal(signal.SIGINT)
        _out, err = process.communicate(timeout=20)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == ExitStatus.INTERRUPTED and "interrupted while starting" in err, err
