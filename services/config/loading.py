"""Loading the robot description: the file, then ``--set`` overrides, typed and strict (msgspec).

An unknown key, a wrong type or a value out of range raises :class:`~services.errors.ConfigError`
naming the field, and the CLI exits with code 2. :func:`convert_toml` reads the other TOML files
(a world, a scenario, a fleet) as strictly.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from services.config.description import SECTIONS, Config
from services.config.fields import NONE, Section, optional_fields
from services.errors import ConfigError


def _build(raw: dict[str, Any]) -> Config:
    _read_nones(raw)
    try:
        return msgspec.convert(raw, Config)
    except msgspec.ValidationError as error:
        message = str(error).replace("$.", "")
        field = message.rpartition(" - at `")[2].rstrip("`").split(".")
        if len(field) == 2 and field[1] in optional_fields(SECTIONS.get(field[0], Section)):
            message += f' (write "{NONE}" to turn it off)'
        raise ConfigError(message) from None


def _read_nones(raw: dict[str, Any]) -> None:
    """Every optional parameter written :data:`NONE` becomes None (in place)."""
    for section, section_type in SECTIONS.items():
        table = raw.get(section)
        if not isinstance(table, dict):
            continue
        for name in optional_fields(section_type):
            value = table.get(name)
            if isinstance(value, str) and value.strip().lower() == NONE:
                table[name] = None


StructT = TypeVar("StructT", bound=msgspec.Struct)


def convert_toml(text: str, struct_type: type[StructT], what: str) -> StructT:
    """A ``struct_type`` from TOML text (a world, scenario or fleet file), strictly: ConfigError
    starting with ``what`` (the file) and naming the offending field otherwise."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{what}: {error}") from None
    try:
        return msgspec.convert(raw, struct_type)
    except msgspec.ValidationError as error:
        raise ConfigError(f"{what}: {str(error).replace('$.', '')}") from None


def parse_override(text: str) -> tuple[str, Any]:
    """``"motor.p_gain_l=3"`` -> ("motor.p_gain_l", 3): the dotted key :func:`apply_overrides` takes.
    The value is read as TOML, else as a string."""
    path, sep, value_text = text.partition("=")
    if not sep or not path.strip():
        raise ConfigError(f"override {text!r} must be SECTION.KEY=VALUE")
    try:
        value = tomllib.loads(f"v = {value_text.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = value_text.strip()
    return path.strip(), value


def load_config(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> Config:
    """Load the robot description, then apply ``overrides`` ({"motor.p_gain_l": 3.0, ...}).

    Override values of None are skipped, so unset command-line flags keep the file's value.
    """
    return config_from_description(read_description(path, overrides))


def config_from_description(raw: dict[str, Any]) -> Config:
    """The typed robot description of the tables ``raw`` (as :func:`read_description` gives them);
    ConfigError naming the field. ``raw`` is not changed."""
    return _build(copy.deepcopy(raw))


def read_description(path: str | Path | None = None, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """The robot description's tables as written: the file (none: empty), then ``overrides``
    (None values skipped), unchecked and without defaults: what
    :func:`~services.config.writing.description_toml` writes back."""
    raw: dict[str, Any] = {}
    if path is not None:
        try:
            raw = tomllib.loads(Path(path).read_text())
        except OSError as error:
            raise ConfigError(f"config file {path}: {error.strerror}") from None
        except tomllib.TOMLDecodeError as error:
            raise ConfigError(f"config file {path}: {error}") from None
    return apply_overrides(raw, overrides or {})


def apply_overrides(raw: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``raw`` (tables as written) with each of ``overrides`` ({"motor.p_gain_l": 3.0, ...}) set in
    place, None values skipped; ConfigError when a key's section is not a table."""
    for dotted, value in overrides.items():
        if value is None:
            continue
        *sections, field = dotted.split(".")
        table = raw
        for section in sections:
            table = table.setdefault(section, {})
            if not isinstance(table, dict):
                raise ConfigError(f"`{dotted}`: `{section}` is not a table")
        table[field] = value
    return raw
