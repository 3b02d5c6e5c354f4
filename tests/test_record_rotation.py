"""Recordings that keep the newest (``record.keep = "newest"``): the journals share ``record.max_size``
by what each writes, their oldest whole files removed (services/runtime/journal.py); ``run.mcap``'s
oldest files removed as it is written, each file left a whole MCAP readable alone, named from
``run.mcap`` on, the last saying what was removed and which span is kept (services/recording/)."""

from __future__ import annotations

import json
import re
import signal
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from schemas.codec import encode
from schemas.keys import Keys, Service
from schemas.messages import Time, TimedDoubleSeq
from services.config import ConfigError, load_config
from services.recording.mcap_files import RECORDING_ROTATED_TOPIC, read_messages, read_run, recording_parts
from services.recording.record import write_run_recording
from services.recording.run_report import robot_report
from services.runtime.journal import (
    BATCH_BYTES,
    BATCH_SAMPLES,
    DROPPED_KEY,
    SUFFIX,
    Journal,
    JournalLimits,
    JournalReader,
    journal_path,
)
from tests.harness import free_port, run_invent, start_up, wait_until

KEYS = Keys()
MB = 1_000_000
MS = 1_000_000
PUBLISHED_NS = 1_800_000_000 * 10**9
WORLD = b'{"tm":{"sec":0,"nanosec":0},"name":"empty","obstacles":[]}'


def _body_pose(stamp_ns: int) -> bytes:
    return encode(TimedDoubleSeq(Time.from_nanoseconds(stamp_ns), [0.1, 0.0, 0.05, 1, 0, 0, 0, 1, 0, 0, 0, 1]))


@pytest.mark.parametrize(
    ("settings", "named"),
    [
        ({"record.keep": "newest", "record.split_size": 0.5}, "split_size"),
        ({"record.keep": "newest", "record.max_size": 3, "record.split_size": 2}, "max_size"),
        ({"record.keep": "newest", "record.max_size": "none"}, "max_size"),
    ],
)
def test_a_rotation_that_cannot_hold_one_file_of_the_minimum_size_is_refused_naming_it(settings, named):
    with pytest.raises(ConfigError, match=named):
        load_config(None, settings)


def test_without_a_split_size_the_newest_are_kept_in_eight_files():
    record = load_config(None, {"record.keep": "newest"}).record
    assert record.rotation_size == record.max_size / 8
    assert record.journal_max_bytes(6) == record.max_size * MB, "the whole budget, shared by what each writes"


def test_journals_share_the_budget_by_what_each_writes_removing_the_oldest_whole_files(tmp_path):
    limits = JournalLimits(max_bytes=3 * MB, file_bytes=MB // 2)
    busy = Journal(journal_path(tmp_path, str(Service.SIM)), limits)
    quiet = Journal(journal_path(tmp_path, str(Service.ODOMETRY)), limits)
    busy.write(KEYS.sim_world, WORLD, PUBLISHED_NS)
    sizes = []
    for step in range(40_000):
        busy.write(KEYS.sim_body_pose, _body_pose(step * MS), PUBLISHED_NS + step)
        if step % 10 == 0:
            quiet.write(KEYS.sim_body_pose, _body_pose(step * MS), PUBLISHED_NS + step)
        if step % 500 == 0:
            sizes.append(sum(path.stat().st_size for path in tmp_path.glob(f"*{SUFFIX}")))
    busy.close()
    quiet.close()

    batch = BATCH_SAMPLES * (len(KEYS.sim_body_pose) + len(_body_pose(0)) + 16)
    assert max(sizes) <= 3 * MB + batch, "within the budget but for the batch just written"
    files = list(tmp_path.glob(f"*{SUFFIX}"))
    assert not (tmp_path / "sim.journal").exists(), "the busy journal's oldest removed"
    assert (tmp_path / "odometry.journal").exists(), "the quiet one keeps what it wrote: the budget is shared"
    oldest_sim = min((path for path in files if path.name.startswith("sim")), key=lambda p: p.stat().st_mtime_ns)
    assert next(iter(JournalReader(oldest_sim)))[:2] == (KEYS.sim_world, WORLD), "each file begins with the world"
    dropped = [json.loads(payload) for path in files for key, payload, _ns in JournalReader(path) if key == DROPPED_KEY]
    assert dropped and "sim.journal" in [name for entry in dropped for name in entry["files"]]


def _rotating_journals(directory: Path, samples: int) -> None:
    directory.mkdir()
    sim = Journal(journal_path(directory, str(Service.SIM)))
    sim.write(KEYS.sim_world, WORLD, PUBLISHED_NS)
    for step in range(samples):
        sim.write(KEYS.sim_body_pose, _body_pose(step * 20 * MS), PUBLISHED_NS + step)
    sim.close()


def test_a_recording_keeping_the_newest_removes_its_oldest_files_each_left_readable_alone(tmp_path):
    _rotating_journals(tmp_path / "journals", 30_000)
    config = load_config(None, {"record.keep": "newest", "record.max_size": 3, "record.split_size": 1})
    output = tmp_path / "run.mcap"

    written = write_run_recording(tmp_path / "journals", output, config, record=config.record)

    assert written.rotated is not None and written.rotated["dropped_files"][0] == "run.mcap"
    parts = recording_parts(output)
    assert parts == written.parts and [p.name for p in parts][:2] == ["run.mcap", "run_1.mcap"]
    for part in parts:
        with part.open("rb") as file:
            topics = {channel.topic for _schema, channel, _message in make_reader(file).iter_messages()}
        assert KEYS.sim_world in topics, f"{part.name} begins with the world: readable alone"
    read = read_run(output)
    assert sum(len(m.data) for m in read.messages) <= 3 * MB
    assert [m.topic for m in read.messages].count(KEYS.sim_world) == 1, "the latched world once, read together"
    poses = [m.publish_time_ns for m in read.messages if m.topic == KEYS.sim_body_pose]
    assert poses[-1] == 29_999 * 20 * MS, "the newest kept"
    assert written.rotated["from_s"] == pytest.approx(poses[0] / 1e9)
    for part in parts:  # each alone, as `invent report run_1.mcap` reads it
        assert robot_report(part, read_messages(part), config)[0]["final"]["ground_truth"] is not None
    report, _recording = robot_report(output, read, config)
    assert report["rotated"]["to_s"] == pytest.approx(poses[-1] / 1e9)
    with parts[-1].open("rb") as file:
        last_topics = {channel.topic for _schema, channel, _message in make_reader(file).iter_messages()}
    assert RECORDING_ROTATED_TOPIC in last_topics, "the last file says what was removed"


@pytest.mark.slow
@pytest.mark.kinematic
def test_a_loop_run_keeping_the_newest_stays_within_its_budget_and_its_report_reads_it(tmp_path):
    """``invent up --loop`` keeps the newest by default; ``--record-ros2`` beside it rotates the bag too."""
    max_size, split_size = 4, 1
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    process = start_up(
        *("--loop", "--composed", "--engine", "kinematic", "--ros2", "--record-ros2"),
        *("--set", f"record.max_size={max_size}"),
        *("--set", f"record.split_size={split_size}", "--report", str(tmp_path), "--listen", endpoint),
    )
    journals = tmp_path / "journals"
    sizes: list[int] = []
    try:

        def rotated() -> bool:
            files = list(journals.glob(f"*{SUFFIX}")) if journals.exists() else []
            sizes.append(sum(path.stat().st_size for path in files if path.exists()))
            later_sim_files = [path for path in files if re.fullmatch(r"sim\.\d+\.journal", path.name)]
            return bool(later_sim_files) and not (journals / "sim.journal").exists()

        wait_until(rotated, 120, "the sim's first journal file removed")
        process.send_signal(signal.SIGINT)
        output, _ = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 0, output[-3000:]
    # a batch: BATCH_BYTES of payloads, their keys and times besides
    assert max(sizes) <= max_size * MB + 1.5 * BATCH_BYTES, (
        "the journals within the budget but for a batch just written"
    )
    parts = sorted(tmp_path.glob("run*.mcap"))
    assert sum(part.stat().st_size for part in parts) <= max_size * MB
    for part in parts:
        with part.open("rb") as file:
            assert sum(1 for _ in make_reader(file).iter_messages()) > 0, f"{part.name} readable alone"
    bag_files = list((tmp_path / "rosbag2").glob("*.mcap"))
    assert bag_files and sum(file.stat().st_size for file in bag_files) <= max_size * MB
    numbers = sorted(int(re.fullmatch(r"rosbag2_(\d+)\.mcap", file.name).group(1)) for file in bag_files)  # type: ignore[union-attr]
    assert numbers == list(range(numbers[0], numbers[0] + len(numbers))), f"the bag's own files in a row: {numbers}"
    with Reader(tmp_path / "rosbag2") as reader:
        assert reader.message_count > 0 and sum(1 for _ in reader.messages()) == reader.message_count
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["rotated"]["dropped_files"], report["rotated"]
    imu = [m.publish_time_ns for m in read_run(tmp_path / "run.mcap").messages if m.topic == KEYS.sim_imu]
    assert imu[0] > 1e9, "the sim's oldest removed, its newest kept"
    assert imu[-1] / 1e9 == pytest.approx(report["rotated"]["to_s"], abs=1.0), "to the end"
    assert report["sim_time_s"] > 0
    assert re.search(r"record.keep = newest: \d+ older files removed", output)
    again = run_invent("report", str(tmp_path / "run.mcap"), "--output-dir", str(tmp_path / "again"), timeout=120)
    assert again.returncode == 0, again.stderr[-2000:]
    assert "the recording covers" in again.stdout
    assert json.loads((tmp_path / "again" / "report.json").read_text())["rotated"] == report["rotated"]


def test_a_journal_started_again_goes_on_after_its_files_never_over_them(tmp_path):
    limits = JournalLimits(max_bytes=10 * MB, file_bytes=MB // 2)
    first = Journal(journal_path(tmp_path, str(Service.MOTOR)), limits)
    for step in range(20_000):
        first.write(KEYS.sim_body_pose, _body_pose(step * MS), PUBLISHED_NS + step)
    first.close()
    before = {path.name: path.stat().st_size for path in tmp_path.glob(f"*{SUFFIX}")}

    again = Journal(journal_path(tmp_path, str(Service.MOTOR)), limits)
    again.write(KEYS.sim_body_pose, _body_pose(0), PUBLISHED_NS + 20_000)
    again.close()

    after = {path.name: path.stat().st_size for path in tmp_path.glob(f"*{SUFFIX}")}
    assert len(before) > 1 and {name: after[name] for name in before} == before, "the first run's files untouched"
    assert set(after) - set(before) == {f"motor.{len(before)}{SUFFIX}"}
