"""A service's journal (services/runtime/journal.py): what it published, read back whole, or as far
as it goes when its writer was killed."""

from __future__ import annotations

import json
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from services.runtime.journal import BATCH_BYTES, BATCH_SAMPLES, STOPPED_KEY, Journal, JournalLimits, JournalReader

KEY = "invent/rh0/sim/wheel_angles"


def _read(path: Path) -> tuple[list[tuple[str, bytes, int]], bool | None]:
    reader = JournalReader(path)
    return list(reader), reader.complete


def _written(path: Path, count: int, close: bool = True) -> Journal:
    journal = Journal(path)
    for index in range(count):
        journal.write(KEY, b'{"n":%d}' % index, index)
    if close:
        journal.close()
    return journal


def test_a_closed_journal_reads_back_every_sample_in_order_across_batches(tmp_path):
    path = tmp_path / "sim.journal"
    _written(path, 2 * BATCH_SAMPLES + 7)
    entries, complete = _read(path)
    assert complete
    assert entries == [(KEY, b'{"n":%d}' % index, index) for index in range(2 * BATCH_SAMPLES + 7)]


def test_a_sample_is_stamped_with_its_publication_time_when_none_is_given(tmp_path):
    path = tmp_path / "motor.journal"
    journal = Journal(path)
    journal.write(KEY, b"{}")
    journal.close()
    journal.close()
    ((_key, _payload, published_ns),), _complete = _read(path)
    assert published_ns > 1_700_000_000 * 10**9


def test_a_killed_writer_loses_only_its_unwritten_batch_and_the_reader_says_so(tmp_path):
    """A SIGKILL leaves the file as it is: the whole batches written, no end."""
    path = tmp_path / "odometry.journal"
    _written(path, BATCH_SAMPLES + 10, close=False)
    entries, complete = _read(path)
    assert complete is False
    assert [published_ns for _key, _payload, published_ns in entries] == list(range(BATCH_SAMPLES))


@settings(max_examples=30, deadline=None)
@given(cut=st.integers(min_value=0, max_value=400))
def test_a_journal_cut_anywhere_reads_its_whole_batches_and_says_it_was_cut(tmp_path_factory, cut):
    path = tmp_path_factory.mktemp("cut") / "drive.journal"
    _written(path, BATCH_SAMPLES + 3)
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) - 1 - cut])
    entries, complete = _read(path)
    assert complete is False
    assert len(entries) in (0, BATCH_SAMPLES, BATCH_SAMPLES + 3), "the whole batches before the cut"
    assert [published_ns for _key, _payload, published_ns in entries] == list(range(len(entries)))


def test_bytes_after_the_end_mark_the_journal_as_not_whole(tmp_path):
    path = tmp_path / "up.journal"
    _written(path, 3)
    path.write_bytes(path.read_bytes() + b"\x05\x00")
    entries, complete = _read(path)
    assert complete is False and len(entries) == 3


OUTCOME = "invent/rh0/drive/outcome"


def test_a_journal_at_its_share_of_the_size_stops_keeping_samples_but_how_the_run_ended(tmp_path):
    path = tmp_path / "sim.journal"
    journal = Journal(path, JournalLimits(max_bytes=1000))
    for index in range(3 * BATCH_SAMPLES):
        journal.write(KEY, b'{"n":%d}' % index, index)
    journal.write(OUTCOME, b"{}", 3 * BATCH_SAMPLES)
    journal.close()
    entries, complete = _read(path)
    assert complete and journal.stopped is not None
    assert [entry[2] for entry in entries if entry[0] == KEY] == list(range(BATCH_SAMPLES)), "its first batch only"
    stop = [entry for entry in entries if entry[0] == STOPPED_KEY]
    assert len(stop) == 1 and json.loads(stop[0][1]) == {"reason": journal.stopped[1], "journal": "sim.journal"}
    assert entries[-1][0] == OUTCOME


def test_a_journal_keeps_nothing_stamped_after_its_max_duration(tmp_path):
    path = tmp_path / "motor.journal"
    journal = Journal(path, JournalLimits(max_stamp_ns=5_000_000))
    for stamp_ms in range(10):
        journal.write(KEY, b"{}", stamp_ms, stamp_ns=stamp_ms * 1_000_000)
    journal.close()
    entries, _complete = _read(path)
    assert [entry[2] for entry in entries if entry[0] == KEY] == [0, 1, 2, 3, 4, 5]
    assert b"record.max_duration" in next(entry[1] for entry in entries if entry[0] == STOPPED_KEY)


def test_a_journal_on_a_disk_with_less_free_than_its_minimum_keeps_nothing_and_says_so(tmp_path):
    journal = Journal(tmp_path / "odometry.journal", JournalLimits(min_free_bytes=10**18))
    journal.write(KEY, b"{}", 1)
    journal.close()
    entries, complete = _read(tmp_path / "odometry.journal")
    assert complete and [entry[0] for entry in entries] == [STOPPED_KEY]
    assert b"record.min_free_disk" in entries[0][1]


def test_large_samples_are_written_once_their_batch_holds_a_megabyte_not_4096_of_them(tmp_path):
    path = tmp_path / "up.journal"
    journal = Journal(path)
    status = b"x" * 10_000  # a status reply with its histogram
    for index in range(BATCH_BYTES // len(status) + 1):
        journal.write(KEY, status, index)
    assert path.stat().st_size > BATCH_BYTES, "written before the end: memory held stays near a megabyte"
    journal.close()
    entries, complete = _read(path)
    assert complete and len(entries) == BATCH_BYTES // len(status) + 1
