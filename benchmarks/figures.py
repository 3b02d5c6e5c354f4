"""What the sections of ``make bench`` share: one measurement taken and timed on the console (a run
that fails is listed, not fatal), the medians, ratios and costs over a section's runs, and a figure
as the table prints it."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from typing import Any

from benchmarks import loop


def timed(what: str, action: Callable[[], Any], failures: list[str]) -> Any:
    """``action()``, timed on the console; None (and the reason in ``failures``) if a run failed."""
    started = time.monotonic()
    print(f"  {what} ...", end="", flush=True)
    try:
        result = action()
    except RuntimeError as error:
        print(f" failed: {str(error).splitlines()[0]}", flush=True)
        failures.append(f"{what}: {error}")
        return None
    print(f" {time.monotonic() - started:.1f} s", flush=True)
    return result


def keep(runs: list[loop.LoopResult], result: loop.LoopResult | None) -> None:
    """Add ``result`` to ``runs`` unless the run failed (None: listed under ``failures``)."""
    if result is not None:
        runs.append(result)


def median(values: Sequence[float | None]) -> float | None:
    present = [value for value in values if value is not None]
    return statistics.median(present) if present else None


def ratio(numerator: float | None, denominator: float | None) -> float | None:
    return numerator / denominator if numerator is not None and denominator else None


def cost(recording: float | None, not_recording: float | None) -> float | None:
    """How much slower the loop ran with its recorder, in % of the speed without (measured in the same run)."""
    fraction = ratio(recording, not_recording)
    return None if fraction is None else 100.0 * (1.0 - fraction)


def cpu_cost(recording: float | None, not_recording: float | None) -> float | None:
    """How much more CPU per step the loop took with its recording, in % of the CPU without."""
    fraction = ratio(recording, not_recording)
    return None if fraction is None else 100.0 * (fraction - 1.0)


def cpu_per_step(runs: list[loop.LoopResult]) -> float | None:
    return median([run.cpu_us_per_step for run in runs])


def percent(fraction: float | None) -> float | None:
    return None if fraction is None else 100 * fraction


def fmt(value: Any, digits: int = 0) -> str:
    if value is None:
        return "n/a"
    return f"{value:,.{digits}f}"
