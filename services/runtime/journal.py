"""What a service published, kept where it was published: the pieces ``invent up`` makes its
``run.mcap`` of (services/recording/record.py, :func:`~services.recording.record.write_run_recording`).

Recording a run from another process costs the loop zenoh's delivery of every sample to that
process, on both ends of the link: it nearly doubled the loop's CPU per step
(benchmarks/README.md). A sample appended here, where it is published, costs a fraction of a
microsecond. A journal is a file of frames, each a little-endian ``uint32`` length and then a
msgpack array of ``[key, payload, publication time in Unix ns]``, one frame per
:data:`BATCH_SAMPLES` samples (or :data:`BATCH_BYTES` of payloads), and a frame of length 0 at the end of a journal closed properly. A
service killed with SIGKILL loses at most the batch it was filling; :class:`JournalReader` reads
every whole frame of a journal without its end, and says it was cut short.

A journal is bounded (:class:`JournalLimits`, from the robot description's ``[record]``): it stops
keeping samples once its file reaches its share of ``record.max_size``, once a sample is stamped
after ``record.max_duration``, or once its disk has less than ``record.min_free_disk`` free, and
then writes a :data:`STOPPED_KEY` entry saying when and why. What ends a run (``up/run``, the
drive's outcome) and what happens rarely (:data:`ALWAYS_KEPT`) it keeps to the end.
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec

from schemas.keys import Topic

SUFFIX = ".journal"
BATCH_SAMPLES = 4096
"""Samples written at once: about half a second of a service's output in lockstep."""
BATCH_BYTES = 1 << 20
"""Or fewer, once their payloads reach this: ``up``'s status replies (a few kB each, the sim's with
its latency histogram) would otherwise hold tens of MB for minutes."""
_LENGTH = struct.Struct("<I")

JournalEntry = tuple[str, bytes, int]
"""(key, payload, publication time in Unix ns)"""

_BATCH = msgspec.msgpack.Decoder(list[JournalEntry])
STOPPED_KEY = "@journal/stopped"
"""The entry a journal that stops early writes: its payload JSON ``{"reason", "journal"}`` (its
file's name), its time when."""
ALWAYS_KEPT = tuple(
    f"/{topic}"
    for topic in (
        Topic.RUN_SUMMARY,
        Topic.DRIVE_OUTCOME,
        Topic.DRIVE_PATH,
        Topic.DRIVE_GOAL,
        Topic.SIM_WORLD,
        Topic.MOTOR_STATE,
        Topic.SIM_BUMP,
        Topic.DRIVE_MAP,
    )
)
"""Keys (by suffix) a stopped journal still keeps: a few samples per run, what says how it ended
(each goal of a goal-mode run too: its outcome names it, ``drive/goal`` says where it was), and the
map goals navigate on."""
MB = 1_000_000


@dataclass(frozen=True)
class JournalLimits:
    """When a journal stops keeping samples (None: never for that reason)."""

    max_bytes: int | None = None
    max_stamp_ns: int | None = None
    min_free_bytes: int = 0


def journal_path(directory: Path, name: str) -> Path:
    """The journal of the publisher ``name`` (a service, or ``up``) in ``directory``."""
    return directory / f"{name}{SUFFIX}"


class Journal:
    """Appends the samples one process publishes to its journal file, within its :class:`JournalLimits`;
    :meth:`close` writes the rest."""

    def __init__(self, path: Path, limits: JournalLimits | None = None, every_step: bool = False) -> None:
        self.path = path
        self.limits = limits or JournalLimits()
        self.every_step = every_step
        """Whether the run records every simulation step (``record.rate``), not the observed ones."""
        self.stopped: tuple[int, str] | None = None
        """(Unix ns, reason) once the journal has stopped keeping samples."""
        self._file = path.open("wb")
        self._written = 0
        self._batch: list[JournalEntry] = []
        self._batch_bytes = 0
        self._encoder = msgspec.msgpack.Encoder()
        self._check_disk()

    def write(self, key: str, payload: bytes, time_ns: int | None = None, stamp_ns: int | None = None) -> None:
        """A sample of ``key`` published (or, for ``time_ns``, taken) now, stamped ``stamp_ns`` in
        simulation time (checked against ``max_stamp_ns`` when given)."""
        if self.stopped is not None and not key.endswith(ALWAYS_KEPT):
            return
        limit = self.limits.max_stamp_ns
        if limit is not None and stamp_ns is not None and stamp_ns > limit and not key.endswith(ALWAYS_KEPT):
            self._stop(f"record.max_duration: nothing stamped after {limit / 1e9:.3f} s is recorded")
            return
        self._batch.append((key, payload, time.time_ns() if time_ns is None else time_ns))
        self._batch_bytes += len(payload)
        if len(self._batch) >= BATCH_SAMPLES or self._batch_bytes >= BATCH_BYTES:
            self._write_batch()

    def _write_batch(self) -> None:
        frame = self._encoder.encode(self._batch)
        self._file.write(_LENGTH.pack(len(frame)) + frame)
        self._file.flush()
        self._written += _LENGTH.size + len(frame)
        self._batch.clear()
        self._batch_bytes = 0
        max_bytes = self.limits.max_bytes
        if max_bytes is not None and self._written >= max_bytes:
            self._stop(f"record.max_size: this journal reached its share, {max_bytes / MB:.1f} MB")
        self._check_disk()

    def _check_disk(self) -> None:
        if self.limits.min_free_bytes <= 0 or self.stopped is not None:
            return
        disk = os.statvfs(self.path.parent)
        free = disk.f_bavail * disk.f_frsize
        if free < self.limits.min_free_bytes:
            self._stop(
                f"record.min_free_disk: {free / MB:.0f} MB free on the disk of {self.path.parent}, "
                f"under {self.limits.min_free_bytes / MB:.0f} MB"
            )

    def _stop(self, reason: str) -> None:
        """Keep nothing more but :data:`ALWAYS_KEPT`, and say so in the journal, in time order."""
        if self.stopped is None:
            self.stopped = (time.time_ns(), reason)
            stop = {"reason": reason, "journal": self.path.name}
            self._batch.append((STOPPED_KEY, msgspec.json.encode(stop), self.stopped[0]))

    def close(self) -> None:
        if self._file.closed:
            return
        if self._batch:
            self._write_batch()
        self._file.write(_LENGTH.pack(0))
        self._file.close()


class JournalReader:
    """The samples of a journal in the order they were written, read a frame at a time (a long
    run's journals need not fit in memory); :attr:`complete` once they are all read."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.complete: bool | None = None
        """After iterating: False when the file lacks its end (its writer was killed), every whole
        frame read; None before."""

    def __iter__(self) -> Iterator[JournalEntry]:
        with self.path.open("rb") as file:
            while len(header := file.read(_LENGTH.size)) == _LENGTH.size:
                (length,) = _LENGTH.unpack(header)
                if length == 0:
                    self.complete = file.read(1) == b""
                    return
                frame = file.read(length)
                try:
                    batch = _BATCH.decode(frame) if len(frame) == length else None
                except msgspec.DecodeError:
                    batch = None
                if batch is None:
                    break
                yield from batch
        self.complete = False
