"""What a long-running process's C allocator holds, and giving back what it no longer uses.

A service's memory is mostly the C allocator's (zenoh's buffers, PyBullet, numpy, and Python's
larger objects): glibc keeps what is freed in its arenas for reuse, so a moment of load that made
a process allocate much (a realtime sim that fell a second behind, its peers' samples piling up)
left its resident size at that high-water mark for good, though the memory in use went back down:
the sim's RSS grew 10-12 MB over the soak's hour, in steps at its busiest moments, where its
allocations in use (glibc's ``mallinfo2``) stayed flat (benchmarks/README.md, "Soak"). Every :data:`TRIM_PERIOD_S`, at a
moment its thread is about to wait, a process hands the free pages back (``malloc_trim``), so its
resident size follows what it uses. Both figures are in every node's ``status`` (``memory``).

glibc only: elsewhere (musl, macOS) nothing is trimmed and ``memory`` holds what is known.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time
from typing import Any

from schemas.status import MemoryStatus

TRIM_PERIOD_S = 60.0
"""Wall seconds between two trims: each walks the allocator's arenas (about a millisecond)."""
MB = 1_000_000


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost"
        )
    ]  # fmt: skip


def _glibc() -> Any:
    libc = ctypes.CDLL(ctypes.util.find_library("c") or None)
    if not (hasattr(libc, "mallinfo2") and hasattr(libc, "malloc_trim")):
        return None
    libc.mallinfo2.restype = _MallInfo2
    libc.malloc_trim.argtypes = [ctypes.c_size_t]
    return libc


_libc = _glibc()
_next_trim = time.monotonic() + TRIM_PERIOD_S
_trims = 0
_max_trim_us = 0.0


def trim_when_due() -> None:
    """The thread is about to wait: give the allocator's free pages back if a period has passed."""
    global _next_trim, _trims, _max_trim_us
    if _libc is None:
        return
    now = time.monotonic()
    if now < _next_trim:
        return
    _libc.malloc_trim(0)
    done = time.monotonic()
    _next_trim = done + TRIM_PERIOD_S
    _trims += 1
    _max_trim_us = max(_max_trim_us, (done - now) * 1e6)


def status() -> MemoryStatus:
    """The allocator's memory in use and free (MB), and the trims done (every node's ``status.memory``)."""
    if _libc is None:
        return MemoryStatus(allocator=None)
    info = _libc.mallinfo2()
    return MemoryStatus(
        allocator="glibc",
        in_use_mb=round((info.uordblks + info.hblkhd) / MB, 3),
        free_mb=round(info.fordblks / MB, 3),
        trims=_trims,
        max_trim_us=round(_max_trim_us, 1),
    )
