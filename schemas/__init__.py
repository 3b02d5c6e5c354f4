"""The wire contract of invent-zenoh: message types, codec and key space (docs/protocol.md sections 1-2)."""

from schemas.codec import ENCODING, BadInput, BadMessage, decode, encode
from schemas.keys import Keys, Method, MethodFamily, Service, Topic, schema_for_key
from schemas.messages import (
    MESSAGE_TYPES,
    BumpEvent,
    NoArguments,
    PDGains,
    Time,
    TimedDoubleSeq,
    TimedPosition,
    TimedVelocity,
)

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
