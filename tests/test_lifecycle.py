"""Every service: alive while it runs, clean exit 0 on SIGINT and SIGTERM, token withdrawn."""

import signal
import threading

import pytest
import zenoh

from schemas.keys import Keys, Service
from tests.harness import InventProcess, wait_alive, wait_until


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
