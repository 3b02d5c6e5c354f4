"""The parameter reference of docs/configuration.md, rendered from the section types.

Every field of every section: its type, bounds, default and unit, read from the type
(``msgspec.inspect``: the bounds of ``msgspec.Meta``, the unit its ``extra``), and its meaning, the
docstring under the field in the source (read with ``ast``). The page's hand-written part ends at
:data:`MARKER`; everything below it is this module's. ``python -m services.config.reference``
rewrites it; tests/test_configuration_reference.py fails when the page and the types differ.
"""

from __future__ import annotations

import ast
import inspect
import itertools
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

import msgspec

from services.config.description import SECTIONS, SEED_NAMES
from services.config.fields import Section
from services.config.writing import toml_value

MARKER = (
    "<!-- Everything below is generated from the section types by `python -m services.config.reference`: "
    "edit the types and their docstrings, then run it. -->"
)
INTRODUCTION = (
    "Generated from the section types (`services/config/sections.py`, `sensors.py`, `navigation.py`, `run_sections.py`): each "
    "field's type, bounds, default and unit from its type, its meaning from the docstring under it; "
    "`python -m services.config.reference` rewrites it, and `tests/test_configuration_reference.py` "
    'fails while it and the types differ. An optional parameter takes `"none"` to turn it off.'
)
PAGE = Path(__file__).resolve().parents[2] / "docs" / "configuration.md"
"""The page the reference is rendered into (of the source tree this module is in)."""

_INSPECT: Any = msgspec.inspect  # its types are not in msgspec's stubs


class Parameter(NamedTuple):
    """One field of a section as the reference shows it (each part Markdown)."""

    key: str
    type: str
    bounds: str
    default: str
    unit: str
    doc: str


def field_docs(section: type[msgspec.Struct]) -> dict[str, str]:
    """The docstring under each field of ``section`` and of the sections it extends, by field name,
    as written (``inspect.cleandoc``); a field without one is missing."""
    docs: dict[str, str] = {}
    for cls in reversed(section.__mro__):
        if isinstance(cls, type) and issubclass(cls, Section) and cls is not Section:
            docs.update(_class_field_docs(cls))
    return docs


def _class_field_docs(cls: type) -> Iterator[tuple[str, str]]:
    tree = ast.parse(inspect.getsource(cls))
    body = tree.body[0].body if isinstance(tree.body[0], ast.ClassDef) else []
    for statement, following in itertools.pairwise(body):
        if (
            isinstance(statement, ast.AnnAssign)
            and isinstance(statement.target, ast.Name)
            and isinstance(following, ast.Expr)
            and isinstance(following.value, ast.Constant)
            and isinstance(following.value.value, str)
        ):
            yield statement.target.id, inspect.cleandoc(following.value.value)


def parameters(name: str, section: type[msgspec.Struct]) -> list[Parameter]:
    """Every field of ``section`` (the table ``name``), in its order; a parameter the seeds had
    says its seed name (:data:`~services.config.description.SEED_NAMES`)."""
    docs = field_docs(section)
    seed_names = {key: seed_name for seed_name, key in SEED_NAMES.items()}
    found = []
    for field in _INSPECT.type_info(section).fields:
        type_text, bounds, unit = _describe(field.type)
        seed_name = seed_names.get(f"{name}.{field.name}")
        seed = f" The seed's `{seed_name}`." if seed_name else ""
        found.append(
            Parameter(
                key=f"`{field.name}`",
                type=type_text,
                bounds="; ".join(bounds),
                default=f"`{toml_value(field.default)}`",
                unit=unit or "—",
                doc=_markdown(docs.get(field.name, "")) + seed,
            )
        )
    return found


def _describe(kind: Any) -> tuple[str, list[str], str]:
    """(TOML type, bounds, unit) of a msgspec type."""
    if isinstance(kind, _INSPECT.Metadata):
        type_text, bounds, unit = _describe(kind.type)
        return type_text, bounds, (kind.extra or {}).get("unit", unit)
    if isinstance(kind, _INSPECT.UnionType):
        members = [member for member in kind.types if not isinstance(member, _INSPECT.NoneType)]
        described = [_describe(member) for member in members]
        type_text = " or ".join(type_text for type_text, _, _ in described)
        bounds = [bound for _, member_bounds, _ in described for bound in member_bounds]
        if len(members) < len(kind.types):
            type_text += ' or `"none"` (off)'
        return type_text, bounds, next((unit for _, _, unit in described if unit), "")
    if isinstance(kind, _INSPECT.TupleType | _INSPECT.VarTupleType):
        items = kind.item_types if isinstance(kind, _INSPECT.TupleType) else (kind.item_type,)
        item_text, item_bounds, unit = _describe(items[0])
        count = f"{len(items)} " if isinstance(kind, _INSPECT.TupleType) else ""
        return f"array of {count}{item_text}", [f"each {bound}" for bound in item_bounds], unit
    if isinstance(kind, _INSPECT.EnumType | _INSPECT.LiteralType):
        values = [member.value for member in kind.cls] if isinstance(kind, _INSPECT.EnumType) else kind.values
        return "string", ["one of " + ", ".join(f'`"{value}"`' for value in values)], ""
    if isinstance(kind, _INSPECT.StrType):
        return "string", [f"matches `{kind.pattern}`"] if kind.pattern else [], ""
    names = {_INSPECT.FloatType: "float", _INSPECT.IntType: "integer", _INSPECT.BoolType: "boolean"}
    type_text = next(name for cls, name in names.items() if isinstance(kind, cls))
    limits = (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤"))
    bounds = [f"{sign} {getattr(kind, name):g}" for name, sign in limits if getattr(kind, name, None) is not None]
    return type_text, bounds, ""


def _markdown(doc: str) -> str:
    """A docstring as one line of a Markdown table cell: RST literals and roles as Markdown code."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", " ".join(doc.split()))
    return text.replace("``", "`").replace("|", "\\|")


def render() -> str:
    """The generated part of docs/configuration.md: :data:`MARKER`, then a table per section."""
    lines = [
        MARKER,
        "",
        "## Reference: every parameter",
        "",
        INTRODUCTION,
    ]
    for name, section in SECTIONS.items():
        lines += ["", f"### `[{name}]`", "", _markdown(inspect.cleandoc(section.__doc__ or "")), ""]
        lines += ["| key | type | bounds | default | unit | meaning |", "|---|---|---|---|---|---|"]
        lines += ["| " + " | ".join(parameter) + " |" for parameter in parameters(name, section)]
    return "\n".join(lines) + "\n"


def page(current: str) -> str:
    """``current`` (the page's text) with everything from :data:`MARKER` on rendered anew (appended
    if the page has no marker yet)."""
    hand_written = current.partition(MARKER)[0]
    return hand_written.rstrip("\n") + "\n\n" + render()


if __name__ == "__main__":
    PAGE.write_text(page(PAGE.read_text()))
    print(f"wrote {PAGE}", file=sys.stderr)
