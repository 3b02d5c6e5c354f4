"""The robot model's proportions that viewers draw too (without importing PyBullet)."""

CASTER_RADIUS_FRACTION = 0.5
"""Caster sphere radius as a fraction of the smaller wheel radius."""
CASTER_REACH_FRACTION = 0.7
"""Distance of each caster from the axle centre along x, as a fraction of the body radius."""
