"""The wire contract of invent-zenoh: message types, codec and key space (docs/protocol.md sections 1-2)."""

from schemas.codec import ENCODING, MESSAGE_TYPES, BadInput, BadMessage, decode, encode
from schemas.keys import Keys, Service, schema_for_key
from schemas.messages import BumpEvent, NoArguments, PDGains, Time, TimedDoubleSeq, TimedPosition, TimedVelocity
from schemas.topics import Method, MethodFamily, Topic

__all__ = [
    "ENCODING",
    "MESSAGE_TYPES",
    "BadInput",
    "BadMessage",
    "BumpEvent",
    "Keys",
    "Method",
    "MethodFamily",
    "NoArguments",
    "PDGains",
    "Service",
    "Time",
    "TimedDoubleSeq",
    "TimedPosition",
    "TimedVelocity",
    "Topic",
    "decode",
    "encode",
    "schema_for_key",
]
