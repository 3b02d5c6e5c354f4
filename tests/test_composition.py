"""``invent up --composed``'s composition: every service on the sim's thread."""

import threading

from schemas import Keys, Service
from services.drive.options import DriveOptions
from services.drive.scenarios import ConstantSegment, Scenario
from services.launch.composition import ComposedService, Composition
from services.launch.service_plans import BUILT_IN, ChildPlan
from tests.harness import status_reply, wait_until

KEYS = Keys("rh0")
SERVICES = {"motor", "odometry", "localization", "sim", "drive"}


def compose_the_loop(composition: Composition) -> ComposedService:
    """The loop's services at their defaults in ``composition``, the drive last on a 0.3 s constant
    segment: the drive's, which finishes by itself."""
    for service in ("motor", "odometry", "localization", "sim"):
        command, options = BUILT_IN[service]
        composition.start_service(ChildPlan(service, command, options()))
    constant = Scenario(name="constant", segments=[ConstantSegment(vx=0.2, w=0.0, duration=0.3)])
    command, _ = BUILT_IN["drive"]
    return composition.start_service(ChildPlan("drive", command, DriveOptions("constant", constant)))


def _status(session, service: Service) -> dict:
    return status_reply(session, KEYS, service)


def test_every_service_runs_on_the_sims_thread_and_the_drive_finishes_without_one(session):
    composition = Composition(session)
    threads_before = set(threading.enumerate())
    try:
        drive = compose_the_loop(composition)
        wait_until(lambda: drive.finished() == 0, 60, "the drive to finish its 0.3 s")
        assert [c.name for c in composition.services if c.thread is not None] == ["sim"]
        started = {thread.name for thread in set(threading.enumerate()) - threads_before}
        assert started & SERVICES == {"sim"}
        assert _status(session, Service.DRIVE)["state"] == "done"
        assert _status(session, Service.LOCALIZATION)["fixes_published"] >= 1
        assert _status(session, Service.ODOMETRY)["counters"]["wheel_angle_samples"] >= 300
        assert composition.exited(exclude="drive") is None
    finally:
        codes = composition.stop()
    assert codes == dict.fromkeys(SERVICES, 0)
