"""msgspec JSON codec: one strict, typed decoder per message type.

Payloads are published with zenoh encoding ``application/json`` so that zenoh tooling
(``z_sub``, the zenohd REST plugin, curl) shows them as text.
"""

from __future__ import annotations

from typing import TypeVar

import msgspec

from schemas import messages, navigation

ENCODING = "application/json"

MessageT = TypeVar("MessageT", bound=msgspec.Struct)


class BadInput(ValueError):
    """Input a service drops and counts (docs/protocol.md section 8); the message is the reason."""


class BadMessage(BadInput):
    """A payload that does not decode into the expected message type."""


MESSAGE_TYPES: tuple[type[msgspec.Struct], ...] = (
    messages.Time,
    messages.TimedDoubleSeq,
    messages.TimedVelocity,
    messages.TimedPosition,
    messages.BumpEvent,
    messages.LaserScan,
    messages.ImuSample,
    messages.PDGains,
    messages.NoArguments,
    messages.Obstacle,
    messages.SimWorld,
    messages.PlannedPath,
    messages.RunSummary,
    messages.ServiceRestart,
    messages.MotorStateReport,
    messages.ScenarioOutcome,
    messages.SetOdometry,
    messages.SetOdometryReply,
    navigation.GoalRequest,
    navigation.GoalReply,
    navigation.CancelRequest,
    navigation.CancelReply,
    navigation.GoalTarget,
    navigation.GoalFeedback,
    navigation.OccupancyGrid,
    navigation.GoalPlan,
    navigation.InitialPose,
    navigation.LocalizationReply,
    navigation.ParticleCloud,
)
"""Every message type of the contract (schemas/messages.py, schemas/navigation.py): a decoder each, made at import."""

_encoder = msgspec.json.Encoder()
_decoders: dict[type, msgspec.json.Decoder] = {t: msgspec.json.Decoder(t) for t in MESSAGE_TYPES}


def encode(message: msgspec.Struct) -> bytes:
    return _encoder.encode(message)


def decode(message_type: type[MessageT], payload: bytes) -> MessageT:
    """Decode ``payload`` as ``message_type`` (one of the project's, or a user service's own
    msgspec Struct: its decoder made once); raise BadMessage with msgspec's reason, for a string
    that is not UTF-8 too."""
    decoder = _decoders.get(message_type)
    if decoder is None:
        decoder = _decoders[message_type] = msgspec.json.Decoder(message_type)
    try:
        return decoder.decode(payload)
    except msgspec.ValidationError as error:
        raise BadMessage(str(error)) from None
    except msgspec.DecodeError as error:
        if "UTF-8" in str(error):  # msgspec 0.23 says so in a DecodeError, for a key that is not UTF-8
            raise BadMessage(f"not UTF-8: {error}") from None
        raise BadMessage(f"not JSON: {error}") from None
    except UnicodeDecodeError as error:  # what msgspec raises for a string that is not UTF-8 (0.22: keys too)
        raise BadMessage(f"not UTF-8: {error}") from None
