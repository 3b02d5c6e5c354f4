"""The ``localization`` section of ``make bench``: what knowing where the robot is costs, in-process, as
a share of the lidar's period (0.1 s at 10 Hz): the particle filter's update per scan
(benchmarks/amcl.py) and a map made from a run per simulated minute (benchmarks/mapping.py)."""

from __future__ import annotations

import argparse
from typing import Any

from benchmarks import amcl, mapping
from benchmarks.figures import fmt, timed


def run_section(args: argparse.Namespace, failures: list[str]) -> dict[str, Any]:
    """The section's figures (``--quick``: a few updates and scans)."""
    print("localization", flush=True)
    return {
        "amcl": timed("the particle filter's updates", lambda: amcl.run(args.quick), failures),
        "mapping": timed("a map from a run", lambda: mapping.run(args.quick), failures),
    }


def table(results: dict[str, Any]) -> str:
    """The section as a Markdown table."""
    lines = ["| localization | ms | share of the lidar's period | detail |", "|---|---|---|---|"]
    filter_results = results["amcl"]
    if filter_results is not None:
        for name, label in (("converged", "converged"), ("max_particles", "at max_particles")):
            entry = filter_results[name]
            lines.append(
                f"| amcl update per scan, {label} | {fmt(entry['ms'], 2)} (p95 {fmt(entry['p95_ms'], 2)}) "
                f"| {fmt(100 * entry['share'], 1)} % | {fmt(entry['particles'])} particles, {entry['updates']} updates, "
                f"error RMS {fmt(100 * entry['rms_m'], 2)} cm |"
            )
        lines.append(
            f"| likelihood field of a 400 × 400 map | {fmt(filter_results['field_build_ms'], 1)} | — | once, at the start |"
        )
    made = results["mapping"]
    if made is not None:
        lines.append(
            f"| map from a run, per scan | {fmt(made['ms_per_scan_median'], 2)} (p95 {fmt(made['ms_per_scan_p95'], 2)}) "
            f"| {fmt(100 * made['period_share'], 1)} % | {fmt(made['wall_s_per_simulated_minute'], 2)} s per simulated "
            f"minute; {made['scans']} scans; occupied cells within 10 cm {fmt(100 * made['occupied_within_10cm'], 1)} % "
            f"(odometry alone {fmt(100 * made['odometry_only_within_10cm'], 1)} %) |"
        )
    return "\n".join(lines)
