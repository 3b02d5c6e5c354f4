"""The motor's state file: what a motor keeps across restarts, so a stopped robot stays stopped
until someone clears it (docs/motor.md, docs/protocol.md section 8.5). Pure: no zenoh."""

from __future__ import annotations

import os
from pathlib import Path

import msgspec

from schemas.messages import PDGains

STATE_HOME_VARIABLE = "XDG_STATE_HOME"
STATE_DIRECTORY = "invent-zenoh"
STATE_FILE = "motor.json"


class SavedState(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What a motor keeps across restarts (``--state FILE``): a stopped robot stays stopped until
    someone clears it, and gains set at run time stay set."""

    stopped: bool
    finished: bool
    gains: PDGains


def default_state_path(robot: str) -> Path:
    """``$XDG_STATE_HOME/invent-zenoh/<robot>/motor.json`` (default ``~/.local/state/...``)."""
    base = os.environ.get(STATE_HOME_VARIABLE) or Path.home() / ".local" / "state"
    return Path(base) / STATE_DIRECTORY / robot / STATE_FILE


class StateFile:
    """The motor's state file: read once at start, rewritten (atomically) after every method call."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def load(self) -> SavedState | None:
        """The saved state; None when there is no file. Raises ValueError when it cannot be read."""
        try:
            return msgspec.json.decode(self.path.read_bytes(), type=SavedState)
        except FileNotFoundError:
            return None
        except (OSError, msgspec.DecodeError) as error:
            raise ValueError(str(error)) from None

    def save(self, state: SavedState) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        partial_path = self.path.with_name(self.path.name + ".partial")
        with partial_path.open("wb") as file:
            file.write(msgspec.json.encode(state))
            file.flush()
            os.fsync(file.fileno())
        os.replace(partial_path, self.path)
