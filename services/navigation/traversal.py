"""The cells a segment crosses on a grid (pure: numpy): Amanatides–Woo's traversal, vectorised over the
segments and their crossings of the grid lines. The costmap's raytrace (costmap.py) and the map
builder's (services/mapping/occupancy.py) both trace their rays with it."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

CORNER_TOLERANCE = 1e-9
"""A segment passing within this (in cells) of a grid corner counts as touching the cells on both
sides of it: the traversal is conservative where rounding could go either way."""

Floats = npt.NDArray[np.float64]
Indices = npt.NDArray[np.intp]


def _axis_crossings(
    along: Floats, across: Floats, delta_along: Floats, delta_across: Floats, first: Indices, last: Indices
) -> tuple[Indices, Indices, Indices]:
    """The crossings of the grid lines normal to one axis: ``(segment, entered, across)``, the cell
    index entered along that axis and the one across it (both, near a corner)."""
    count = np.abs(last - first)
    total = int(count.sum())
    if total == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty, empty
    # each segment's values repeated once per crossing (sequential copies, cheaper than gathers)
    which = np.repeat(np.arange(count.size), count)
    backward = delta_along < 0.0
    step = np.arange(1, total + 1) - np.repeat(np.cumsum(count) - count, count)  # 1, 2, ... along each segment
    entered = np.repeat(first, count) + step * np.repeat(np.where(backward, -1, 1), count)
    line = (entered + np.repeat(backward, count)).astype(np.float64)  # backward: the line above the cell entered
    t = (line - np.repeat(along, count)) / np.repeat(delta_along, count)
    at = np.repeat(across, count) + t * np.repeat(delta_across, count)
    low = np.floor(at - CORNER_TOLERANCE).astype(np.intp)
    high = np.floor(at + CORNER_TOLERANCE).astype(np.intp)
    corner = low != high
    return (
        np.concatenate((which, which[corner])),
        np.concatenate((entered, entered[corner])),
        np.concatenate((high, low[corner])),
    )


def crossed_cells(u0: Floats, v0: Floats, u1: Floats, v1: Floats) -> tuple[Indices, Indices, Indices]:
    """Every cell each segment (``u0``, ``v0``) → (``u1``, ``v1``) crosses, the coordinates in cells from
    the grid's origin: ``(segment, col, row)``, an entry a cell crossed (a cell may repeat). Exact
    (Amanatides–Woo's traversal, vectorised over the segments and their crossings of the grid lines):
    the start cell, then the cell entered at each crossing of a vertical or horizontal grid line; a
    crossing within :data:`CORNER_TOLERANCE` of a corner also counts the cells on both sides of it.
    No bounds are checked: the caller keeps the segments on its grid."""
    c0, r0 = np.floor(u0).astype(np.intp), np.floor(v0).astype(np.intp)
    c1, r1 = np.floor(u1).astype(np.intp), np.floor(v1).astype(np.intp)
    du, dv = u1 - u0, v1 - v0
    x_segment, x_col, x_row = _axis_crossings(u0, v0, du, dv, c0, c1)
    y_segment, y_row, y_col = _axis_crossings(v0, u0, dv, du, r0, r1)
    return (
        np.concatenate((np.arange(u0.shape[0]), x_segment, y_segment)),
        np.concatenate((c0, x_col, y_col)),
        np.concatenate((r0, x_row, y_row)),
    )
