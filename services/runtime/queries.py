"""How a node answers a query on one of its queryables, on the service thread (``Node.queryable``)."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import msgspec
import zenoh

from schemas.codec import ENCODING, BadInput
from services.runtime.logs import BadInputCounter


def answer(
    query: zenoh.Query,
    key: str,
    handler: Callable[[bytes], Any],
    bad_inputs: BadInputCounter,
    internal_error: Callable[[str, Exception], None],
) -> None:
    """``handler(payload)``'s reply to ``query`` (JSON-encoded; None: no reply); a ``reply_err``
    naming the reason for BadInput (counted in ``bad_inputs``) and for a bug (``internal_error``,
    never raised). The query is finalized right after, so the caller's ``get`` returns at once."""
    try:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            reply = handler(payload)
        except BadInput as error:
            bad_inputs.record(key, str(error))
            query.reply_err(json.dumps({"error": str(error)}), encoding=zenoh.Encoding(ENCODING))
            return
        except Exception as error:  # noqa: BLE001 (a bug must not kill the service; it is logged and counted)
            internal_error(key, error)
            query.reply_err(json.dumps({"error": f"internal error: {error}"}), encoding=zenoh.Encoding(ENCODING))
            return
        if reply is not None:
            query.reply(key, msgspec.json.encode(reply), encoding=zenoh.Encoding(ENCODING))
    finally:
        query.drop()
