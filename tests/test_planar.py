"""The shared planar helpers: wrap_angle into (-pi, pi]."""

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.planar import wrap_angle


@pytest.mark.parametrize(
    ("angle", "wrapped"),
    [
        (0.0, 0.0),
        (1.0, 1.0),
        (-1.0, -1.0),
        (math.pi, math.pi),
        (-math.pi, math.pi),
        (3.0 * math.pi, math.pi),
        (-1.5 * math.pi, 0.5 * math.pi),
        (2.0 * math.pi + 0.25, 0.25),
        (-2.0 * math.pi - 0.25, -0.25),
    ],
)
def test_wrap_angle_maps_into_the_half_open_interval(angle: float, wrapped: float) -> None:
    assert wrap_angle(angle) == pytest.approx(wrapped, abs=1e-12)


@given(st.floats(min_value=-1e6, max_value=1e6))
def test_wrap_angle_keeps_direction_and_lands_in_interval(angle: float) -> None:
    wrapped = wrap_angle(angle)
    assert -math.pi < wrapped <= math.pi
    assert math.cos(wrapped) == pytest.approx(math.cos(angle), abs=1e-9)
    assert math.sin(wrapped) == pytest.approx(math.sin(angle), abs=1e-9)
