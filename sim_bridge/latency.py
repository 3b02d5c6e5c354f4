"""Torque latency of the sim bridge: wheel angles published -> the torque answering them received.

Pure (no zenoh, no PyBullet). The per-step cost is a few array stores: publish times live in a
small ring indexed by step, latencies are counted in a preallocated histogram of fixed-width
bins, and percentiles are computed only when the status asks. The status also carries the
histogram itself (its non-empty bins), so a reader can subtract two replies and get the
percentiles of just the steps in between (benchmarks/loop.py does).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from schemas.status import TorqueLatencyStatus

BIN_NS = 10_000
"""Histogram bin width: latencies are resolved to 10 µs."""
BINS = 1_000
"""Bins up to 10 ms; the last bin also holds every longer latency. (A status reply stays well
under the 64 KiB a low-latency zenoh link carries in one message.)"""
STEPS_IN_FLIGHT = 8
"""Steps whose publish time is remembered: a torque answering an older step is not timed."""
NANOSECONDS_PER_MICROSECOND = 1000


def percentiles(counts: Mapping[int, int], fractions: Iterable[float]) -> list[float | None]:
    """Nearest-rank percentiles in µs (the upper edge of the bin holding them) of a histogram
    ``{bin index: count}``; None for an empty histogram."""
    total = sum(counts.values())
    if total <= 0:
        return [None for _ in fractions]
    ordered = sorted((index, count) for index, count in counts.items() if count > 0)
    results: list[float | None] = []
    for fraction in fractions:
        rank, seen = max(1, math.ceil(total * fraction)), 0
        for index, count in ordered:
            seen += count
            if seen >= rank:
                results.append((index + 1) * BIN_NS / NANOSECONDS_PER_MICROSECOND)
                break
    return results


class TorqueLatency:
    """Times each step's exchange: :meth:`published` when its wheel angles go out, :meth:`answered`
    when the torque carrying its ``tm`` comes back (clock: ``time.perf_counter_ns``)."""

    def __init__(self, step_ns: int) -> None:
        self._step_ns = step_ns
        # Lists, not arrays, and comparisons, not min()/max(): this runs twice per step, and the
        # arrays' boxing and the builtins' calls cost twice the time (583 against 253 ns a step).
        self._sent_step = [-1] * STEPS_IN_FLIGHT
        self._sent_at = [0] * STEPS_IN_FLIGHT
        self._bins = [0] * BINS
        self.samples = 0
        self.max_ns = 0

    def published(self, tm_ns: int, now_ns: int) -> None:
        step = tm_ns // self._step_ns
        slot = step % STEPS_IN_FLIGHT
        self._sent_step[slot] = step
        self._sent_at[slot] = now_ns

    def answered(self, tm_ns: int, now_ns: int) -> None:
        """Count the latency of the torque stamped ``tm_ns`` (ignored unless its step is in flight)."""
        step = tm_ns // self._step_ns
        slot = step % STEPS_IN_FLIGHT
        if self._sent_step[slot] != step:
            return
        self._sent_step[slot] = -1
        latency = now_ns - self._sent_at[slot]
        index = latency // BIN_NS
        self._bins[index if index < BINS else BINS - 1] += 1
        self.samples += 1
        if latency > self.max_ns:  # noqa: PLR1730 (a comparison, not a max() call: see __init__)
            self.max_ns = latency

    def histogram(self) -> dict[int, int]:
        """The non-empty bins: ``{index: count}``, bin i holding latencies in [i, i + 1) x BIN_NS."""
        return {index: count for index, count in enumerate(self._bins) if count}

    def summary(self) -> TorqueLatencyStatus:
        """Percentiles since the start in µs (None before the first latency), and the histogram."""
        counts = self.histogram()
        p50, p99 = percentiles(counts, (0.50, 0.99))
        return TorqueLatencyStatus(
            samples=self.samples,
            p50_us=p50,
            p99_us=p99,
            max_us=self.max_ns / NANOSECONDS_PER_MICROSECOND if self.samples else None,
            bin_us=BIN_NS / NANOSECONDS_PER_MICROSECOND,
            histogram=[[index, count] for index, count in counts.items()],
        )
