"""services/runtime/memory.py: a process hands the allocator's free pages back at an idle moment, so
its resident size follows what it uses (glibc; skipped elsewhere)."""

import ctypes
import time
from pathlib import Path

import pytest

from services.runtime import memory
from services.runtime.executor import Executor

pytestmark = pytest.mark.skipif(memory.status().allocator != "glibc", reason="trimming needs glibc's malloc_trim")


def _rss_mb() -> float:
    line = next(line for line in Path("/proc/self/status").read_text().splitlines() if line.startswith("VmRSS"))
    return int(line.split()[1]) / 1024


def _freed_in_the_middle(megabytes: int) -> ctypes.c_void_p:
    """``megabytes`` of 1 kB blocks written and freed but for the last, which pins the heap's top:
    glibc keeps the rest for reuse (its automatic trim only releases a free top)."""
    libc = ctypes.CDLL(None)
    libc.malloc.restype = ctypes.c_void_p
    libc.free.argtypes = [ctypes.c_void_p]
    blocks = [libc.malloc(1024) for _ in range(megabytes * 1024)]
    for block in blocks:
        ctypes.memset(block, 1, 1024)
    for block in blocks[:-1]:
        libc.free(block)
    return blocks[-1]


def test_an_idle_moment_after_the_trim_period_hands_the_freed_pages_back(monkeypatch):
    pinned = _freed_in_the_middle(64)
    before, trims = _rss_mb(), memory.status().trims
    assert memory.status().free_mb > 50, "freed, kept by the allocator"
    # a period just begun, whatever the suite's earlier tests left: the last trim may be over a period ago
    monkeypatch.setattr(memory, "_next_trim", time.monotonic() + memory.TRIM_PERIOD_S)
    memory.trim_when_due()
    assert memory.status().trims == trims, "not before the period is over"
    monkeypatch.setattr(memory, "_next_trim", 0.0)
    Executor().spin_once(0.01)  # an executor about to wait is the idle moment
    after = _rss_mb()
    ctypes.CDLL(None).free(ctypes.c_void_p(pinned))
    assert memory.status().trims == trims + 1
    assert before - after > 40, f"RSS {before:.1f} -> {after:.1f} MB"
