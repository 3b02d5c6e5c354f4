"""Services that drive, for tests/test_extension_drives.py: written against services/extension/api.py only."""

from __future__ import annotations

from schemas.messages import LaserScan
from services.extension.api import Context, Drives, Lockstep, UserService


class Forward(UserService):
    """Drives forward slowly on every scan: a second service that drives, beside the wanderer."""

    name = "forward"
    reads = ("sim/scan",)
    drives = Drives(rate_hz=10.0)

    def __init__(self, ctx: Context) -> None:
        super().__init__(ctx)
        ctx.subscribe(ctx.keys.sim_scan, LaserScan, lambda scan: ctx.drive(scan.tm, 0.1, 0.0))


class DrivesInLockstep(UserService):
    """Claims to drive and to take part in lockstep on an output of its own: refused."""

    name = "drives_in_lockstep"
    drives = Drives(rate_hz=10.0)
    lockstep = Lockstep(output="x", rate_hz=10.0)


class DrivesAndCalls(UserService):
    """Claims to drive and to call the drive's goals: refused (it has the drive's rights only)."""

    name = "drives_and_calls"
    drives = Drives(rate_hz=10.0)
    calls = ("drive/goal/send",)


class DrivesReadingTheTruth(UserService):
    """Claims to drive on the simulator's ground truth, which the drive does not read: refused."""

    name = "drives_reading_the_truth"
    drives = Drives(rate_hz=10.0)
    reads = ("sim/body_pose",)


class DrivesAtNoRate(UserService):
    name = "drives_at_no_rate"
    drives = Drives(rate_hz=0.0)


class DrivesTrue(UserService):
    name = "drives_true"
    drives = True  # type: ignore[assignment]  # wrong on purpose: a Drives(rate_hz) or None
