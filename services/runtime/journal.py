"""What a service published, kept where it was published: the pieces ``invent up`` makes its
``run.mcap`` of (services/recording/record.py, :func:`~services.recording.record.write_run_recording`).

Recording a run from another process costs the loop zenoh's delivery of every sample to that
process, on both ends of the link: it nearly doubled the loop's CPU per step
(benchmarks/README.md). A sample appended here, where it is published, costs a fraction of a
microsecond. A journal is a file of frames, each a little-endian ``uint32`` length and then a
msgpack array of ``[key, payload, publication time in Unix ns]``, one frame per
:data:`BATCH_SAMPLES` samples, and a frame of length 0 at the end of a journal closed properly. A
service killed with SIGKILL loses at most the batch it was filling; :class:`JournalReader` reads
every whole frame of a journal without its end, and says it was cut short.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Iterator
from pathlib import Path

import msgspec

SUFFIX = ".journal"
BATCH_SAMPLES = 4096
"""Samples written at once: about half a second of a service's output in lockstep."""
_LENGTH = struct.Struct("<I")

JournalEntry = tuple[str, bytes, int]
"""(key, payload, publication time in Unix ns)"""

_BATCH = msgspec.msgpack.Decoder(list[JournalEntry])


def journal_path(directory: Path, name: str) -> Path:
    """The journal of the publisher ``name`` (a service, or ``up``) in ``directory``."""
    return directory / f"{name}{SUFFIX}"


class Journal:
    """Appends the samples one process publishes to its journal file; :meth:`close` writes the rest."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file = path.open("wb")
        self._batch: list[JournalEntry] = []
        self._encoder = msgspec.msgpack.Encoder()

    def write(self, key: str, payload: bytes, time_ns: int | None = None) -> None:
        """A sample of ``key`` published (or, for ``time_ns``, taken) now."""
        self._batch.append((key, payload, time.time_ns() if time_ns is None else time_ns))
        if len(self._batch) >= BATCH_SAMPLES:
            self._write_batch()

    def _write_batch(self) -> None:
        frame = self._encoder.encode(self._batch)
        self._file.write(_LENGTH.pack(len(frame)) + frame)
        self._file.flush()
        self._batch.clear()

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
