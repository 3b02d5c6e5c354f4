"""Runs as MCAP files: writing what zenoh delivers and reading it back (a run's report from it:
services/recording/run_report.py; no zenoh here).

A recording has one channel per zenoh key, named by the key, message encoding ``json``: the
payloads as they were published. A key of the project's key space (``schemas/keys.py``) has a
``jsonschema`` schema named after its message type and generated from it
(``msgspec.json.schema``); any other key has no schema. ``log_time`` is when the sample was
received (services/recording/record.py), ``publish_time`` the message's ``tm`` where it has one (simulation time), else the
``log_time``. Beside those, the Foxglove channels of :mod:`services.recording.scene` (protobuf, with
Foxglove's well-known schemas), so Foxglove shows a recording as it shows the live view.

Messages are written in chunks of :data:`CHUNK_SIZE` bytes, each straight to the file: a
recorder killed with SIGKILL loses at most the chunk it was filling, and :func:`read_messages`
then reads every whole chunk and says the file was cut short (a file closed properly ends with
an index and a summary, which the ``mcap`` CLI and Foxglove use to seek).
"""

from __future__ import annotations

import io
import json
import struct
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import msgspec
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

if TYPE_CHECKING:
    from _typeshed import ReadableBuffer

from schemas.keys import parse_data_key, schema_for_key
from schemas.messages import NANOSECONDS_PER_SECOND, Time
from schemas.status_kinds import status_type_of_key
from schemas.topics import LATCHED_TOPICS, Topic
from services.config import ConfigError, RecordConfig
from services.runtime.journal import ALWAYS_KEPT

MB = 1_000_000
LATCHED_SUFFIXES = tuple(f"/{topic}" for topic in LATCHED_TOPICS)
"""Keys (by suffix) whose last sample each file of a recording that keeps the newest begins with."""

CHUNK_SIZE = 256 * 1024
"""Bytes of messages per chunk: about a fifth of a second of the loop in lockstep."""
JSON = "json"
JSON_SCHEMA = "jsonschema"
PROFILE = ""
"""No MCAP profile: the channels are zenoh keys, not ROS topics."""


class _Stamped(msgspec.Struct):
    """Any message with a ``tm``, for its stamp alone."""

    tm: Time


_STAMPED = msgspec.json.Decoder(_Stamped)


LATEST_STAMP_NS = (2**32 - 1) * NANOSECONDS_PER_SECOND
"""The latest stamp a recording or a view shows: Foxglove's timestamps count seconds in 32 bits.
A message stamped later (a buggy or hostile publisher) keeps its receive time as publish time
and is left out of the scene."""


def publish_time(payload: bytes, log_time_ns: int) -> int:
    """The message's ``tm`` in ns, or ``log_time_ns`` when it has none or one past :data:`LATEST_STAMP_NS`."""
    try:
        stamp_ns = _STAMPED.decode(payload).tm.to_nanoseconds()
    except (msgspec.DecodeError, msgspec.ValidationError):
        return log_time_ns
    return stamp_ns if stamp_ns <= LATEST_STAMP_NS else log_time_ns


def key_json_schema(key: str) -> tuple[str, str, bytes] | None:
    """(name, encoding, data) of the JSON schema of ``key``'s message type (a status key's: its
    service's status Struct), named after the type, as a recording and the live view hold it; None
    for a key that is neither a data key nor a status key."""
    message_type: type | None = schema_for_key(key) or status_type_of_key(key)
    if message_type is None:
        return None
    return message_type.__name__, JSON_SCHEMA, json.dumps(msgspec.json.schema(message_type)).encode()


class McapWriter:
    """One recording being written; :meth:`close` ends it with its index and summary."""

    def __init__(self, path: Path, declared: Sequence[str] = ()) -> None:
        """``declared``: keys whose channels the file holds from its start, in this order, published
        on or not (what the services declare they publish: services/interfaces.py)."""
        self._file = _Flushing(io.FileIO(path, "wb"))
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library="invent-zenoh")
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        for key in declared:
            self._channels[key] = self._writer.register_channel(key, JSON, self._key_schema(key))
        self.messages = 0
        self.message_bytes = 0
        """The messages' bytes, uncompressed (the file, compressed by chunks, is smaller)."""

    def write_sample(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """A zenoh sample, on the channel of its key; ``publish_time_ns`` its ``tm`` (found here when None)."""
        channel = self._channels.get(key)
        if channel is None:
            channel = self._channels[key] = self._writer.register_channel(key, JSON, self._key_schema(key))
        if publish_time_ns is None:
            publish_time_ns = publish_time(payload, log_time_ns)
        self._write(channel, payload, log_time_ns, publish_time_ns)

    def write_json(self, topic: str, value: Any, schema: dict[str, Any], stamp_ns: int, log_time_ns: int) -> None:
        """A JSON message of ``schema`` (a JSON schema with a ``title``) on ``topic``."""
        channel = self._channels.get(topic)
        if channel is None:
            schema_id = self._schema(schema["title"], JSON_SCHEMA, json.dumps(schema).encode())
            channel = self._channels[topic] = self._writer.register_channel(topic, JSON, schema_id)
        self._write(channel, json.dumps(value).encode(), log_time_ns, stamp_ns)

    def write_foxglove(self, topic: str, message: Any, stamp_ns: int, log_time_ns: int) -> None:
        """A Foxglove well-known message (``foxglove.messages``), protobuf-encoded."""
        channel = self._channels.get(topic)
        if channel is None:
            schema = message.get_schema()
            schema_id = self._schema(schema.name, schema.encoding, bytes(schema.data))
            channel = self._channels[topic] = self._writer.register_channel(topic, schema.encoding, schema_id)
        self._write(channel, message.encode(), log_time_ns, stamp_ns)

    def _write(self, channel: int, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        self._writer.add_message(channel, log_time_ns, data, publish_time_ns, sequence=self.messages)
        self.messages += 1
        self.message_bytes += len(data)

    def _key_schema(self, key: str) -> int:
        schema = key_json_schema(key)
        return 0 if schema is None else self._schema(*schema)

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = self._schemas.get(name)
        if schema is None:
            schema = self._schemas[name] = self._writer.register_schema(name, encoding, data)
        return schema

    def close(self) -> None:
        self._writer.finish()
        self._file.close()


class _Flushing(io.BufferedWriter):
    """A file whose every write (the writer writes a whole chunk at once) reaches the disk's cache
    at once: a killed recorder loses only the chunk it was filling."""

    def write(self, data: ReadableBuffer) -> int:
        written = super().write(data)
        self.flush()
        return written


@dataclass(frozen=True)
class RecordedMessage:
    topic: str
    schema_name: str | None
    data: bytes
    log_time_ns: int
    publish_time_ns: int


@dataclass
class ReadResult:
    messages: list[RecordedMessage]
    complete: bool
    """False when the file ends before its summary (the recorder was killed): every whole chunk was read."""


def part_path(path: Path, number: int) -> Path:
    """The file ``number`` of the recording ``path``: ``path`` itself (0), ``<stem>_<number>.mcap``."""
    return path if number == 0 else path.with_name(f"{path.stem}_{number}{path.suffix}")


def recording_parts(path: Path) -> list[Path]:
    """The files of the recording ``path`` in order: ``path`` itself, then, for a recording split
    by ``record.split_size`` or ``record.split_duration``, ``<stem>_1.mcap``, ``<stem>_2.mcap``, ..."""
    parts = [path]
    while (part := part_path(path, len(parts))).exists():
        parts.append(part)
    return parts


def read_run(path: Path) -> ReadResult:
    """Every message of the recording ``path`` and of the files it was split into, in order (the
    latched samples a file of a rotated recording begins with, once). ConfigError when ``path`` is
    not an MCAP file at all."""
    with open(path, "rb") as file:
        if file.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC:
            raise ConfigError(f"{path}: not an MCAP recording (a run's recording is its run.mcap)")
    results = [read_messages(part) for part in recording_parts(path)]
    seen: set[tuple[str, int, bytes]] = set()
    messages = []
    for result in results:
        for message in result.messages:
            if message.topic.endswith(LATCHED_SUFFIXES):
                latched = (message.topic, message.log_time_ns, message.data)
                if latched in seen:
                    continue
                seen.add(latched)
            messages.append(message)
    return ReadResult(messages, all(r.complete for r in results))


def read_messages(path: Path) -> ReadResult:
    """Every message of a recording, in log-time order; a file cut short is read up to its last whole chunk."""
    with open(path, "rb") as file:
        try:
            reader = make_reader(file)
            messages = [_recorded(schema, channel, message) for schema, channel, message in reader.iter_messages()]
            return ReadResult(messages, complete=True)
        except (McapError, EOFError, ValueError, KeyError, struct.error):
            file.seek(0)
            return ReadResult(sorted(_stream_messages(file), key=lambda m: m.log_time_ns), complete=False)


def _recorded(schema: Schema | None, channel: Channel, message: Message) -> RecordedMessage:
    return RecordedMessage(
        channel.topic, schema.name if schema else None, message.data, message.log_time, message.publish_time
    )


def _stream_messages(file: IO[bytes]) -> Iterator[RecordedMessage]:
    """The messages of the whole records of a file read front to back, up to where it is cut."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    try:
        for record in StreamReader(file, skip_magic=False).records:
            for inner in breakup_chunk(record) if isinstance(record, Chunk) else [record]:
                if isinstance(inner, Schema):
                    schemas[inner.id] = inner
                elif isinstance(inner, Channel):
                    channels[inner.id] = inner
                elif isinstance(inner, Message):
                    channel = channels[inner.channel_id]
                    yield _recorded(schemas.get(channel.schema_id), channel, inner)
    except (McapError, EOFError, ValueError, KeyError, struct.error):
        return


@dataclass(frozen=True)
class Replayed:
    """One recorded sample to publish again."""

    topic: Topic
    data: bytes
    stamp_ns: int


NOT_REPLAYED = frozenset({Topic.RUN_SUMMARY})
"""Recorded, but not data a service consumes: a replay of every key leaves them out."""


def replay_schedule(messages: list[RecordedMessage], topics: Collection[Topic] = ()) -> tuple[str, list[Replayed]]:
    """The robot a recording is of, and its samples of ``topics`` (default: every data key it
    holds, but :data:`NOT_REPLAYED`) in simulation-time order (recorded order between equal stamps:
    a consumer gets them as the loop's consumers did). ConfigError when the file holds no data
    key, keys of several robots, or none of a requested topic."""
    data = [(parsed, message) for message in messages if (parsed := parse_data_key(message.topic)) is not None]
    robots = sorted({robot for (robot, _topic), _message in data})
    if len(robots) != 1:
        found = ", ".join(robots) if robots else "none"
        raise ConfigError(f"a replay needs the recording of one robot; robots recorded: {found}")
    wanted = set(topics) or {topic for (_robot, topic), _message in data} - NOT_REPLAYED
    missing = sorted(wanted - {topic for (_robot, topic), _message in data})
    if missing:
        raise ConfigError(f"--keys: the recording holds no samples of {', '.join(missing)}")
    schedule = [
        Replayed(topic, message.data, message.publish_time_ns) for (_robot, topic), message in data if topic in wanted
    ]
    schedule.sort(key=lambda replayed: replayed.stamp_ns)
    return robots[0], schedule


RECORDING_STOPPED_TOPIC = "/recording/stopped"
"""The message a recording ends with when it stopped before its run (a limit of ``[record]``)."""
RECORDING_STOPPED_SCHEMA = {
    "title": "invent.RecordingStopped",
    "type": "object",
    "properties": {
        "reason": {"type": "string"},
        "journal": {"type": "string"},
        "stopped_at_s": {"type": ["number", "null"], "description": "the simulation time of the last sample kept"},
    },
}


RECORDING_ROTATED_TOPIC = "/recording/rotated"
"""The message the last file of a recording that kept the newest (``record.keep``) ends with."""
RECORDING_ROTATED_SCHEMA = {
    "title": "invent.RecordingRotated",
    "type": "object",
    "properties": {
        "dropped_files": {"type": "array", "items": {"type": "string"}, "description": "removed, oldest first"},
        "dropped_mb": {"type": "number", "description": "what they held"},
        "from_s": {"type": ["number", "null"], "description": "the simulation time of the first sample kept"},
        "to_s": {"type": ["number", "null"], "description": "the simulation time of the last sample kept"},
    },
}


_NOT_SPANNED = LATCHED_SUFFIXES + ALWAYS_KEPT
"""What a file of a rotated recording (or a journal's) begins with, from before its span."""


@dataclass
class _Part:
    path: Path
    message_bytes: int = 0
    first_stamp_ns: int | None = None
    first_data_ns: int | None = None
    """The first stamp of a key kept whole (not :data:`LATCHED_SUFFIXES` nor ``ALWAYS_KEPT``):
    where the span the file covers begins."""


class SplitWriter:
    """An :class:`McapWriter` that goes on in a new file at ``record.split_size`` or every
    ``record.split_duration`` of simulation time (sizes are of the messages, uncompressed: a file is
    smaller, by its chunks' compression). With ``record.keep = "until_full"`` it says when
    ``record.max_size`` is written (:attr:`full`); with ``"newest"`` it splits at
    ``record.rotation_size`` too, begins each file with the last sample of each latched key (so
    that each is readable alone), removes the oldest files while they hold more than ``max_size``,
    and at :meth:`close` names those left ``<stem>.mcap``, ``<stem>_1.mcap``, ... in order."""

    def __init__(self, output: Path, record: RecordConfig, declared: Sequence[str] = ()) -> None:
        """``declared``: the channels each file holds from its start (:class:`McapWriter`)."""
        self._output = output
        self._declared = declared
        self._newest = record.keeps_newest
        split_mb = record.rotation_size if self._newest else record.split_size
        self._split_bytes = None if split_mb is None else split_mb * MB
        self._split_ns = (
            None if record.split_duration is None else round(record.split_duration * NANOSECONDS_PER_SECOND)
        )
        self._max_bytes = None if record.max_size is None else record.max_size * MB
        self._kept = [_Part(output)]
        self._numbered = 1
        self.dropped: list[_Part] = []
        self._latched: dict[str, tuple[bytes, int, int | None]] = {}
        self._writer = McapWriter(output, declared)
        self.latest_stamp_ns: int | None = None

    @property
    def parts(self) -> list[Path]:
        return [part.path for part in self._kept]

    @property
    def messages(self) -> int:
        return self._writer.messages

    @property
    def full(self) -> bool:
        if self._newest or self._max_bytes is None:
            return False
        return sum(part.message_bytes for part in self._kept[:-1]) + self._writer.message_bytes >= self._max_bytes

    @property
    def first_stamp_ns(self) -> int | None:
        """Where the span the recording covers begins (its first file's :attr:`_Part.first_data_ns`)."""
        return self._kept[0].first_data_ns

    def _next_part(self, stamp_ns: int | None) -> None:
        """Before a message stamped ``stamp_ns``: a new file if this one is full or its time is up."""
        current = self._kept[-1]
        if stamp_ns is not None:
            self.latest_stamp_ns = stamp_ns if self.latest_stamp_ns is None else max(self.latest_stamp_ns, stamp_ns)
            if current.first_stamp_ns is None:
                current.first_stamp_ns = stamp_ns
        by_size = self._split_bytes is not None and self._writer.message_bytes >= self._split_bytes
        by_time = (
            self._split_ns is not None
            and stamp_ns is not None
            and current.first_stamp_ns is not None
            and stamp_ns >= current.first_stamp_ns + self._split_ns
        )
        if by_size or by_time:
            self._writer.close()
            current.message_bytes = self._writer.message_bytes
            self._kept.append(_Part(part_path(self._output, self._numbered), first_stamp_ns=stamp_ns))
            self._numbered += 1
            self._writer = McapWriter(self._kept[-1].path, self._declared)
            if self._newest:
                self._drop_oldest()
                for key, (payload, log_time_ns, publish_time_ns) in self._latched.items():
                    self._writer.write_sample(key, payload, log_time_ns, publish_time_ns)

    def _drop_oldest(self) -> None:
        """Remove the oldest whole files while the closed ones hold more than ``max_size`` with room
        for the one begun."""
        assert self._max_bytes is not None and self._split_bytes is not None  # RecordConfig checks it
        while (
            len(self._kept) > 1 and sum(p.message_bytes for p in self._kept[:-1]) + self._split_bytes > self._max_bytes
        ):
            oldest = self._kept.pop(0)
            oldest.path.unlink()
            self.dropped.append(oldest)

    def write_sample(self, key: str, payload: bytes, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        self._next_part(publish_time_ns)
        self._writer.write_sample(key, payload, log_time_ns, publish_time_ns)
        if key.endswith(_NOT_SPANNED):
            if self._newest:
                self._latched[key] = (payload, log_time_ns, publish_time_ns)
        elif self._kept[-1].first_data_ns is None:
            self._kept[-1].first_data_ns = publish_time_ns

    def write_json(self, topic: str, value: Any, schema: dict[str, Any], stamp_ns: int, log_time_ns: int) -> None:
        self._writer.write_json(topic, value, schema, stamp_ns, log_time_ns)

    def write_foxglove(self, topic: str, message: Any, stamp_ns: int, log_time_ns: int) -> None:
        self._writer.write_foxglove(topic, message, stamp_ns, log_time_ns)

    def close(self) -> None:
        """The last file closed, and, when older ones were removed, those left named from ``<stem>.mcap`` on."""
        self._writer.close()
        if self.dropped:
            for number, part in enumerate(self._kept):
                renamed = part_path(self._output, number)
                part.path.rename(renamed)
                part.path = renamed
