"""Real-time settings of a process on the control path (``--rt``, the robot description's ``[rt]``).

What ros2_control does for its controller manager, offered to the processes of the loop (the sim,
the motor, the router; docs/realtime.md):

- **SCHED_FIFO** at ``rt.priority``: the process's threads run before every ordinary one, so a busy
  machine no longer delays a step's exchange. Applied before the zenoh session opens: zenoh's own
  threads (which receive and send every sample) inherit it from the thread that starts them (numpy's
  BLAS pool, started at import and never on the control path, keeps the ordinary policy).
- **Locked memory** (``mlockall``): no page of the process is ever swapped out or faulted in late.
- **CPU affinity** (``rt.cpus``): the process and the threads it starts run only there; by default
  the last CPU, the same for every process of the control path: a step's exchange then never wakes
  a thread on another core (on the 2-core VM measured here, that halved the CPU per step and took the
  late steps at 1 kHz from ~0.5 % to ~0.01 %).
- **The garbage collector off the control path** (``rt.gc``): Python's cyclic collector stops the
  thread that triggers it, for as long as it takes to scan its generation. ``frozen`` collects once
  after start-up and moves everything then alive to a permanent generation that no collection scans
  again (``gc.freeze``); ``idle`` also collects the young generation when the service thread is
  about to wait (:func:`collect_when_idle`, called by the executor), every generation now and then,
  and leaves automatic collections only as a safety net, at a threshold a hundred times Python's
  (a thread that is never idle still collects).

Where the system refuses a setting (no root, no CAP_SYS_NICE or CAP_IPC_LOCK, an rtprio or memlock
limit, a container without the rights), :func:`apply_realtime` says so in one line and the process
goes on without it. What was applied, and what the collector did, is in every node's ``status``
(``rt``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os
import time
from dataclasses import dataclass, field
from typing import Any

from schemas.keys import Service
from schemas.status import RealtimeStatus
from services.config import ConfigError, CpuChoice, GcPolicy, RtConfig

log = logging.getLogger("invent.rt")

_MCL_CURRENT, _MCL_FUTURE = 1, 2
IDLE_COLLECTION_THRESHOLD = 700
"""Allocations (net of deallocations) after which an idle thread collects the young generation:
Python's own default threshold for an automatic one."""
IDLE_FULL_EVERY = 100
"""Idle collections of the young generation between two of every generation (what was not frozen)."""
SAFETY_THRESHOLD = 100 * IDLE_COLLECTION_THRESHOLD
"""With ``rt.gc = "idle"``: the allocations after which the young generation is collected anyway."""
CONTROL_PATH = frozenset({Service.SIM, Service.MOTOR})
"""The services every step's exchange runs through (with the router between them)."""
HOW_TO_GRANT = "CAP_SYS_NICE and CAP_IPC_LOCK (root has them), or rtprio and memlock limits: docs/realtime.md"


@dataclass
class _State:
    """What this process applied, and what its garbage collector did since (``status.rt``)."""

    enabled: bool = False
    policy: str = "SCHED_OTHER"
    priority: int = 0
    memory_locked: bool = False
    cpus: list[int] | None = None
    gc: str = str(GcPolicy.AUTOMATIC)
    refused: list[str] = field(default_factory=list)
    collections: list[int] = field(default_factory=lambda: [0, 0, 0])
    max_pause_us: float = 0.0
    total_pause_us: float = 0.0
    idle_collections: int = 0
    started_ns: int = 0


_state = _State()
_collecting_when_idle = False


def _on_collection(phase: str, info: dict[str, Any]) -> None:
    if phase == "start":
        _state.started_ns = time.perf_counter_ns()
        return
    pause_us = (time.perf_counter_ns() - _state.started_ns) / 1000.0
    _state.collections[info["generation"]] += 1
    _state.total_pause_us += pause_us
    _state.max_pause_us = max(_state.max_pause_us, pause_us)


def watch_collections() -> None:
    """Count every collection of this process's garbage collector and time its pause (``status.rt``)."""
    if _on_collection not in gc.callbacks:
        gc.callbacks.append(_on_collection)


def chosen_cpus(cpus: tuple[int, ...] | CpuChoice, available: set[int]) -> list[int]:
    """The CPUs ``rt.cpus`` asks of a process that may use ``available``; [] to leave the choice to
    the system (``any``, or ``last`` with a single CPU). ConfigError for a CPU not available."""
    if cpus == CpuChoice.ANY:
        return []
    if cpus == CpuChoice.LAST:
        return [max(available)] if len(available) > 1 else []
    missing = sorted(set(cpus) - available)
    if missing:
        raise ConfigError(f"`rt.cpus`: CPU {missing} not among this process's CPUs {sorted(available)}")
    return sorted(cpus)


def apply_realtime(rt: RtConfig, who: str, *, control_path: bool, composed: bool = False) -> _State:
    """Apply ``rt`` to this process (call it before opening a zenoh session, whose threads inherit
    the scheduling and the affinity); what the system refuses is said in one line and skipped.
    ConfigError for ``rt.cpus`` naming a CPU this process cannot have.

    ``control_path``: the process is the sim, the motor or the router. With ``rt.partition`` (and
    ``rt.enabled`` or not), such a process, or one given ``--rt``, runs on ``rt.cpus``, and every
    other process on the CPUs left: the observers' threads (the view's, the ROS 2 bridge's, each
    taking the 1 kHz keys or a status) then never preempt a step's exchange. Measured on the 2-core
    VM, realtime square with the ROS 2 bridge and the view, side by side: 13.1 % of the steps late
    without the partition, 1.0 % with it (benchmarks/README.md, "Compose").

    ``composed``: the CPUs are left to :func:`pin_loop_thread`, for the thread the loop runs on
    alone. A composed lockstep loop never blocks: a thread sharing its one core at its priority
    (zenoh's, zenoh-python's callback threads, ``up``'s own) would never run, since ``SCHED_FIFO``
    does not share a core between threads of one priority, and nothing outside the process would
    reach it."""
    watch_collections()
    available = os.sched_getaffinity(0)
    cpus = chosen_cpus(rt.cpus, available)
    if not rt.enabled:
        if rt.partition and cpus and not composed:
            _partition(cpus if control_path else sorted(available - set(cpus)), control_path, who)
        return _state
    _state.enabled = True
    refused: list[str] = []
    if cpus and not composed:
        _pin(cpus, refused)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt.priority))
        _state.policy, _state.priority = "SCHED_FIFO", rt.priority
    except OSError as error:
        refused.append(f"SCHED_FIFO priority {rt.priority} ({error.strerror})")
    if rt.lock_memory:
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:
            _state.memory_locked = True
        else:
            refused.append(f"locked memory ({os.strerror(ctypes.get_errno())})")
    _state.refused = refused
    if refused:
        log.warning(
            "%s: real-time settings refused by the system: %s; running without them (they need %s)",
            who,
            ", ".join(refused),
            HOW_TO_GRANT,
        )
    else:
        log.info(
            "%s: real time: %s priority %d%s%s",
            who,
            _state.policy,
            _state.priority,
            ", memory locked" if _state.memory_locked else "",
            f", CPUs {_state.cpus}" if _state.cpus else "",
        )
    return _state


def _partition(cpus: list[int], control_path: bool, who: str) -> None:
    """``rt.partition`` without ``rt.enabled``: hold this process to ``cpus`` (none left: nothing to do)."""
    if not cpus:
        return
    refused: list[str] = []
    _pin(cpus, refused)
    if refused:
        _state.refused.extend(refused)
        log.warning("%s: CPU affinity refused by the system: %s; running where the system likes", who, refused[0])
    else:
        side = "the control path's" if control_path else "off the control path's"
        log.info("%s: on CPUs %s, %s (rt.partition)", who, cpus, side)


def _pin(cpus: list[int], refused: list[str]) -> None:
    """Hold the calling thread, and the threads it starts from now on, to ``cpus`` (Linux: an
    affinity is a thread's)."""
    try:
        os.sched_setaffinity(0, cpus)
        _state.cpus = cpus
    except OSError as error:
        refused.append(f"CPU affinity {cpus} ({error.strerror})")


def pin_loop_thread(rt: RtConfig, who: str) -> None:
    """A composed process: hold the calling thread, the one its loop runs on, to ``rt.cpus``
    (every other thread of the process stays free: see :func:`apply_realtime`)."""
    if not rt.enabled:
        return
    cpus = chosen_cpus(rt.cpus, os.sched_getaffinity(0))
    refused: list[str] = []
    if cpus:
        _pin(cpus, refused)
    if refused:
        _state.refused.extend(refused)
        log.warning("%s: real-time settings refused by the system: %s; running without them", who, refused[0])
    elif cpus:
        log.info("%s: its loop's thread on CPUs %s", who, cpus)


def settle_garbage_collector(rt: RtConfig) -> None:
    """Once the process has started (its services built), keep the collector off the control path as
    ``rt.gc`` says (with ``rt.enabled``)."""
    global _collecting_when_idle
    if not rt.enabled or rt.gc is GcPolicy.AUTOMATIC:
        return
    gc.collect()
    gc.freeze()
    _state.gc = str(rt.gc)
    if rt.gc is GcPolicy.IDLE:
        gc.set_threshold(SAFETY_THRESHOLD, *gc.get_threshold()[1:])
        _collecting_when_idle = True


def collect_when_idle() -> None:
    """The service thread is about to wait: with ``rt.gc = "idle"``, collect the young generation
    if enough was allocated since the last collection (and every generation now and then)."""
    if not _collecting_when_idle or gc.get_count()[0] < IDLE_COLLECTION_THRESHOLD:
        return
    _state.idle_collections += 1
    gc.collect(2 if _state.idle_collections % IDLE_FULL_EVERY == 0 else 0)


def status() -> RealtimeStatus:
    """What was applied and what the collector did (every node's ``status.rt``)."""
    return RealtimeStatus(
        enabled=_state.enabled,
        policy=_state.policy,
        priority=_state.priority,
        memory_locked=_state.memory_locked,
        cpus=_state.cpus,
        refused=list(_state.refused),
        gc=_state.gc,
        gc_collections=list(_state.collections),
        gc_max_pause_us=round(_state.max_pause_us, 1),
        gc_total_pause_us=round(_state.total_pause_us, 1),
    )
