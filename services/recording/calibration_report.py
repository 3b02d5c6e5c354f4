"""What ``invent calibrate umbmark`` reports (no zenoh here): ``report.json`` (its inputs, every
benchmark with its runs, the estimated errors and the corrections), the robot description with
the corrections (``-o``) and the lines it prints. The figure and the runs' paths for Foxglove
are ``calibration.py``'s.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

from services.calibration.benchmark import Benchmark, Conclusion
from services.calibration.umbmark import Calibration
from services.config import Config, ConfigError, config_from_description, description_toml

REPORT_FILE = "report.json"
FIGURE_FILE = "umbmark.png"
RECORDING_FILE = "umbmark.mcap"


def make_report_dir(path: Path) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"--report {path}: {error.strerror}") from None


def report(
    config: Config,
    start: Calibration,
    benchmarks: list[Benchmark],
    conclusion: Conclusion,
    *,
    passes: int,
    inputs: dict[str, Any],
    files: dict[str, str],
) -> dict[str, Any]:
    """``report.json``: ``inputs`` (the source's), the robot and the calibration the benchmarks
    started from, each benchmark, what they conclude and the files written."""
    return {
        "method": "umbmark",
        "inputs": {
            **inputs,
            "robot": {
                "radius_of_left_wheel": config.robot.radius_of_left_wheel,
                "radius_of_right_wheel": config.robot.radius_of_right_wheel,
                "length_of_axle": config.robot.length_of_axle,
            },
            "calibration": start.as_dict(),
        },
        "benchmarks": [benchmark.as_dict() for benchmark in benchmarks],
        "passes": passes,
        "ed": conclusion.ed,
        "eb": conclusion.eb,
        "corrections": conclusion.final.as_dict(),
        "e_max_syst": {
            "before": conclusion.e_before,
            "after": conclusion.e_after,
            "reduction": conclusion.reduction,
        },
        "files": files,
    }


def write_description(output: Path, description: dict[str, Any], conclusion: Conclusion) -> Path:
    """``-o``: the robot ``description`` given, with the corrected multipliers (checked to load)."""
    description = copy.deepcopy(description)
    description.setdefault("odometry", {}).update(conclusion.final.as_dict())
    config_from_description(description)
    header = [
        "# The robot description with the odometry calibrated by UMBmark (invent calibrate umbmark): "
        + f"Ed {conclusion.ed:.6f}, Eb {conclusion.eb:.6f};",
        f"# E_max,syst {conclusion.e_before * 1000:.1f} mm before"
        + ("" if conclusion.e_after is None else f", {conclusion.e_after * 1000:.1f} mm after")
        + ". Run the robot with --config FILE.",
    ]
    try:
        output.write_text("\n".join(header) + "\n" + description_toml(description))
    except OSError as error:
        raise ConfigError(f"-o {output}: {error.strerror}") from None
    return output


def summary(conclusion: Conclusion, passes: int, files: dict[str, str]) -> list[str]:
    """The lines printed at the end: the estimate, the corrections, E_max,syst, the files."""
    e_before, e_after = conclusion.e_before, conclusion.e_after
    estimate = f"Ed = D_R/D_L = {conclusion.ed:.6f}, Eb = b_actual/b_nominal = {conclusion.eb:.6f}"
    corrections = conclusion.final.as_dict().items()
    lines = [
        f"estimated: {estimate} ({passes} pass{'es' * (passes > 1)})",
        "corrections: " + ", ".join(f"odometry.{name} = {value:.6f}" for name, value in corrections),
    ]
    if e_after is None:
        lines.append(f"E_max,syst {e_before * 1000:.1f} mm (measure again with the corrections applied)")
    else:
        ratio = e_before / e_after if e_after else math.inf
        lines.append(f"E_max,syst {e_before * 1000:.1f} mm before, {e_after * 1000:.1f} mm after: {ratio:.1f}x smaller")
    lines.append("written: " + ", ".join(files.values()))
    return lines


def benchmark_line(benchmark: Benchmark) -> str:
    """The line printed once a benchmark is evaluated."""
    result = benchmark.result
    (cw_x, cw_y), (ccw_x, ccw_y) = result.cg_cw, result.cg_ccw
    return (
        f"{benchmark.label}: centres of gravity cw ({cw_x * 1000:+.1f}, {cw_y * 1000:+.1f}) mm, "
        f"ccw ({ccw_x * 1000:+.1f}, {ccw_y * 1000:+.1f}) mm; E_max,syst {result.e_max_syst * 1000:.1f} mm; "
        f"alpha {result.alpha:+.6f} rad, beta {result.beta:+.6f} rad; Ed {result.ed:.6f}, Eb {result.eb:.6f}"
    )
