"""A robot description's tables written back as TOML (``invent calibrate umbmark -o``)."""

from __future__ import annotations

import json
from typing import Any

from services.config.fields import NONE
from services.errors import ConfigError


def description_toml(raw: dict[str, Any]) -> str:
    """TOML text of a robot description's tables (:func:`~services.config.loading.read_description`):
    its top-level values, then one ``[section]`` per table, keys in their order; a None is written
    :data:`~services.config.fields.NONE`."""
    scalars = {name: value for name, value in raw.items() if not isinstance(value, dict)}
    lines = [f"{name} = {toml_value(value)}" for name, value in scalars.items()]
    for name, table in raw.items():
        if isinstance(table, dict):
            lines += ["", f"[{name}]", *(f"{key} = {toml_value(value)}" for key, value in table.items())]
    return "\n".join(lines).lstrip("\n") + "\n"


def toml_value(value: Any) -> str:
    """``value`` as TOML writes it (None as :data:`~services.config.fields.NONE`); ConfigError for
    what a robot description cannot hold."""
    if value is None:
        return json.dumps(NONE)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)  # a float's repr reads back as the same float (TOML takes 1e-05 and 0.1)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(item) for item in value) + "]"
    raise ConfigError(f"cannot write {value!r} ({type(value).__name__}) in a robot description")
