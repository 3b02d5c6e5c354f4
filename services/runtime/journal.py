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
drive's outcome) and what happens rarely (:data:`ALWAYS_KEPT`) it keeps to the end. With
``record.keep = "newest"`` (:attr:`JournalLimits.file_bytes`) it never stops for its size: it goes
on in a new file (``sim.1.journal``, ...; each begins with the last sample of each
:data:`ALWAYS_KEPT` key) and, after each batch, removes the oldest whole files of its directory,
whoever wrote them, while they hold more than ``max_bytes`` together (:func:`remove_oldest`),
saying so in a :data:`DROPPED_KEY` entry.
"""

from __future__ import annotations

import logging
import os
import struct
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec

from schemas.topics import Topic

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
DROPPED_KEY = "@journal/dropped"
"""The entry a journal writes when it removed older files: its payload JSON ``{"files", "bytes"}``."""
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
log = logging.getLogger("invent.journal")


@dataclass(frozen=True)
class JournalLimits:
    """When a journal stops keeping samples (None: never for that reason)."""

    max_bytes: int | None = None
    max_stamp_ns: int | None = None
    min_free_bytes: int = 0
    file_bytes: int | None = None
    """With ``record.keep = "newest"``: a new file at this size, and ``max_bytes`` the budget of
    every journal file of the directory together (the oldest removed), not this journal's alone."""


def journal_path(directory: Path, name: str) -> Path:
    """The journal of the publisher ``name`` (a service, or ``up``) in ``directory``."""
    return directory / f"{name}{SUFFIX}"


def _journal_file(path: Path) -> tuple[str, int]:
    """(journal name, file number) of ``sim.journal`` (0) or ``sim.3.journal`` (3)."""
    name, _, number = path.name.removesuffix(SUFFIX).partition(".")
    return name, int(number) if number.isdigit() else 0


def _next_number(path: Path) -> int:
    """The number of ``path``'s next file: 0, or one past the highest of its journal's files there."""
    name = _journal_file(path)[0]
    numbers = [
        _journal_file(file)[1] for file in path.parent.glob(f"{name}*{SUFFIX}") if _journal_file(file)[0] == name
    ]
    return max(numbers) + 1 if numbers else 0


def remove_oldest(directory: Path, max_bytes: int) -> list[tuple[str, int]]:
    """Remove the oldest whole journal files of ``directory`` (by when each was last written; never
    a journal's newest, which may be being written) while all of them hold more than ``max_bytes``:
    (name, bytes) of each removed. Another process may remove the same files meanwhile."""
    files = []
    for path in directory.glob(f"*{SUFFIX}"):
        try:
            files.append((path, path.stat()))
        except FileNotFoundError:
            continue
    newest: dict[str, int] = {}
    for path, _stat in files:
        name, number = _journal_file(path)
        newest[name] = max(newest.get(name, 0), number)
    total = sum(stat.st_size for _path, stat in files)
    removable = sorted(
        (stat.st_mtime_ns, number, path, stat.st_size)
        for path, stat in files
        if (number := _journal_file(path)[1]) < newest[_journal_file(path)[0]]
    )
    removed = []
    for _mtime, _number, path, size in removable:
        if total <= max_bytes:
            break
        try:
            path.unlink()
            removed.append((path.name, size))
        except FileNotFoundError:
            pass
        total -= size
    return removed


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
        self._file_number = _next_number(path) if self.limits.file_bytes is not None else 0
        """With ``file_bytes``, a service started again goes on after its files, never over them."""
        self._file = self._numbered(self._file_number).open("wb")
        self._written = 0
        self._batch: list[JournalEntry] = []
        self._batch_bytes = 0
        self._encoder = msgspec.msgpack.Encoder()
        self._last_kept: dict[str, JournalEntry] = {}
        """The last sample of each :data:`ALWAYS_KEPT` key: where each new file begins."""
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
        entry = (key, payload, time.time_ns() if time_ns is None else time_ns)
        self._batch.append(entry)
        if self.limits.file_bytes is not None and key.endswith(ALWAYS_KEPT):
            self._last_kept[key] = entry
        self._batch_bytes += len(payload)
        if len(self._batch) >= BATCH_SAMPLES or self._batch_bytes >= BATCH_BYTES:
            self._write_batch()

    def _write_batch(self, last: bool = False) -> None:
        """The batch as one frame; ``last``: the journal's (never a new file for it alone)."""
        file_bytes, max_bytes = self.limits.file_bytes, self.limits.max_bytes
        if file_bytes is not None and self._written >= file_bytes and not last:
            self._next_file()
        frame = self._encoder.encode(self._batch)
        self._file.write(_LENGTH.pack(len(frame)) + frame)
        self._file.flush()
        self._written += _LENGTH.size + len(frame)
        last_ns = self._batch[-1][2]
        self._batch.clear()
        self._batch_bytes = 0
        if file_bytes is not None and max_bytes is not None:
            self._remove_oldest(max_bytes, last_ns)
        elif max_bytes is not None and self._written >= max_bytes:
            self._stop(f"record.max_size: this journal reached its share, {max_bytes / MB:.1f} MB")
        self._check_disk()

    def _next_file(self) -> None:
        """Close this file and go on in the next one, the batch to write beginning with the last of
        each :data:`ALWAYS_KEPT` key it lacks."""
        self._file.write(_LENGTH.pack(0))
        self._file.close()
        self._file_number += 1
        self._file = self._numbered(self._file_number).open("wb")
        self._written = 0
        in_batch = {id(entry) for entry in self._batch}
        carried = [entry for entry in self._last_kept.values() if id(entry) not in in_batch]
        self._batch[:0] = sorted(carried, key=lambda entry: entry[2])

    def _numbered(self, number: int) -> Path:
        return self.path if number == 0 else self.path.with_name(f"{_journal_file(self.path)[0]}.{number}{SUFFIX}")

    def _remove_oldest(self, max_bytes: int, last_ns: int) -> None:
        """After each batch: the directory's oldest files removed while over ``max_bytes``, said in
        the next batch, stamped as the last entry written (a bridge's bag journal is in simulation
        time, the others in Unix time)."""
        removed = remove_oldest(self.path.parent, max_bytes)
        if removed:
            files = [file for file, _size in removed]
            dropped = {"files": files, "bytes": sum(size for _file, size in removed)}
            self._batch.append((DROPPED_KEY, msgspec.json.encode(dropped), last_ns))
            log.info("record.keep = newest: removed the oldest journal files %s", ", ".join(files))

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
            self._write_batch(last=True)
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
