"""How ``make soak-day`` judges each process's memory over a day (benchmarks/soak_day.py): growth per
simulated hour from a process's last start, and past the high water of the first hostile burst it
lived through (zenoh's buffers grow once, to a burst's size, and stay: benchmarks/burst_memory.py);
each burst's step."""

from __future__ import annotations

from typing import Any

from benchmarks.soak import slope_per_hour

FLAT_MB_PER_HOUR = 1.0
"""The issue's bound on a process's memory growth, MB per simulated hour."""


def growth(samples: list[dict[str, Any]], name: str, since_h: float) -> float | None:
    """``name``'s resident memory growth in MB per simulated hour from ``since_h`` on (the first hour
    left out; for the router and the service beside, their last process's: the faults start them again)."""
    points = [(s["sim_h"] * 3600, s["rss_mb"][name]) for s in samples if s["sim_h"] >= since_h and s["rss_mb"][name]]
    return round(slope_per_hour(points), 3) if len(points) > 1 else None


def since(faults: list[dict[str, Any]], kind: str | None, warm_up_h: float) -> float:
    """The simulated hour from which a process's memory counts: after the warm-up, and after its last restart."""
    return max([warm_up_h, *(fault["at_sim_h"] for fault in faults if fault["kind"] == kind)])


def past_high_water(faults: list[dict[str, Any]], kind: str | None, warm_up_h: float) -> float:
    """From :func:`since` on, and past the first burst of hostile input the process then lived through
    (its buffers' high water, benchmarks/burst_memory.py); with no such burst, :func:`since`."""
    start = since(faults, kind, warm_up_h)
    bursts = [fault["done_at_sim_h"] for fault in faults if fault["kind"] == "hostile" and fault["at_sim_h"] >= start]
    return bursts[0] if bursts else start


def steps_at_bursts(samples: list[dict[str, Any]], faults: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each process's resident memory just after each burst less just before it, MB."""
    steps = []
    for fault in faults:
        if fault["kind"] != "hostile":
            continue
        before = [s for s in samples if s["sim_h"] <= fault["at_sim_h"]]
        after = [s for s in samples if s["sim_h"] >= fault["done_at_sim_h"]]
        if before and after:
            step = {
                name: round(after[0]["rss_mb"][name] - mb, 1)
                for name, mb in before[-1]["rss_mb"].items()
                if mb and after[0]["rss_mb"][name]
            }
            steps.append({"at_sim_h": fault["at_sim_h"], "mb": step})
    return steps
