"""The parameter reference of docs/configuration.md is the section types, rendered: the page fails
here when it and the types differ, and every field says what it is. Plain and fast: no zenoh."""

from __future__ import annotations

import pytest

from services.config import SECTIONS, SEED_NAMES
from services.config.reference import MARKER, PAGE, field_docs, page, parameters, render


def test_the_page_holds_the_reference_the_types_render():
    current = PAGE.read_text()
    assert MARKER in current, f"{PAGE} lost its marker line: run `python -m services.config.reference`"
    assert page(current) == current, f"{PAGE} differs from the types: run `python -m services.config.reference`"


@pytest.mark.parametrize("name", SECTIONS)
def test_every_field_of_every_section_has_a_docstring(name: str):
    section = SECTIONS[name]
    docs = field_docs(section)
    assert [field for field in section.__struct_fields__ if not docs.get(field, "").strip()] == []
    assert (section.__doc__ or "").strip(), f"[{name}] has no docstring"


def test_the_reference_shows_every_field_with_its_type_bounds_default_and_unit():
    rendered = render()
    for name, section in SECTIONS.items():
        assert f"### `[{name}]`" in rendered
        assert [parameter.key for parameter in parameters(name, section)] == [
            f"`{field}`" for field in section.__struct_fields__
        ]
    motor = {parameter.key: parameter for parameter in parameters("motor", SECTIONS["motor"])}
    assert motor["`p_gain_l`"][1:5] == ("float", "≥ 0", "`5.0`", "N·m/rad")
    assert motor["`max_vx`"][1:5] == ('float or `"none"` (off)', "> 0", "`1.0`", "m/s")
    assert motor["`target_angle`"].bounds == 'one of `"seed"`, `"integrated"`'
    rt = {parameter.key: parameter for parameter in parameters("rt", SECTIONS["rt"])}
    assert rt["`priority`"].bounds == "≥ 1; ≤ 99"
    assert rt["`cpus`"].type == "array of integer or string"


def test_a_field_the_seeds_had_says_its_seed_name():
    rendered = render()
    for seed_name, key in SEED_NAMES.items():
        section, field = key.split(".")
        table = rendered.partition(f"### `[{section}]`")[2].partition("###")[0]
        row = next(line for line in table.splitlines() if line.startswith(f"| `{field}` |"))
        assert row.endswith(f"The seed's `{seed_name}`. |"), key


def test_an_inherited_field_takes_its_docstring_from_the_section_it_is_declared_in():
    assert field_docs(SECTIONS["odometry"])["initial_x"] == field_docs(SECTIONS["localization"])["initial_x"]
    assert "initial_x" in field_docs(SECTIONS["odometry"]) and "rho_border" in field_docs(SECTIONS["odometry"])


def test_the_page_keeps_its_hand_written_part_above_the_marker():
    current = PAGE.read_text()
    hand_written = current.partition(MARKER)[0]
    assert hand_written.startswith("# Configuration: the robot description")
    edited = hand_written + MARKER + "\nA line written by hand below the marker\n"
    assert page(edited) == current
    assert page(hand_written) == current
