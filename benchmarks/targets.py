"""What the issues' "Must show" asks of ``make bench``'s figures, and whether a run met it."""

from __future__ import annotations

from typing import Any

TARGETS = {
    "lockstep.floor_ratio": 0.5,
    "lockstep.composed_ratio": 0.4,
    "realtime.late_fraction": 0.001,
    "realtime.latency_us.p99": 500.0,
    "codec.min_ratio": 5.0,
    "fleet.composed.4.steps_per_s": 1000.0,
    "realtime.rt.late_vs_floor": 1.5,
    "realtime.rt.p99_vs_floor": 1.5,
    "fleet.workers_speedup.8": 1.5,
}
"""The issues' "Must show": ratios are lower bounds, late fraction and latency upper bounds; the fleet's
(issue 26): composed with 4 robots at least at real time (1,000 steps/s at the default 1 ms step)."""
UPPER_BOUNDS = frozenset(
    {"realtime.late_fraction", "realtime.latency_us.p99", "realtime.rt.late_vs_floor", "realtime.rt.p99_vs_floor"}
)
"""Issue 32's: realtime 1 kHz with ``--rt`` within 1.5x the paced floor's late fraction and p99; a composed
fleet of 8 over one process per core (``--workers``) at 1.5x its robot-steps/s in one process."""


def _lookup(results: dict[str, Any], dotted: str) -> Any:
    value: Any = results
    for part in dotted.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    return value


def check_targets(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    checks = {}
    for name, target in TARGETS.items():
        value = _lookup(results, name)
        met = None if value is None else (value < target if name in UPPER_BOUNDS else value >= target)
        checks[name] = {"target": target, "value": value, "met": met}
    return checks


_VERDICTS = {True: "met", False: "NOT met", None: "not measured"}


def verdicts(checks: dict[str, dict[str, Any]]) -> list[str]:
    """A line a target, as printed at the end of a run: met, NOT met or not measured, and the figure."""
    return [
        f"target {name} {'<' if name in UPPER_BOUNDS else '>='} {check['target']}: "
        f"{_VERDICTS[check['met']]} ({check['value']})"
        for name, check in checks.items()
    ]
