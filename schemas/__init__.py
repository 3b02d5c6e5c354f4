"""The wire contract of invent-zenoh: message types, codec and key space (SPEC sections 1-2)."""

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
    "NoArguments",
    "PDGains",
    "Keys",
    "Method",
    "MethodFamily",
    "Service",
    "Topic",
    "Time",
    "TimedDoubleSeq",
    "TimedPosition",
    "TimedVelocity",
    "decode",
    "encode",
    "schema_for_key",
]
