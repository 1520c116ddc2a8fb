"""Arc geometry in the XY plane: centre from the R form, radius checks, sweep, length and bounds.

Angles are measured counter-clockwise from +X. The sweep of an arc is its signed angle
(negative clockwise) including extra full turns; a start point equal to the end point is a
full circle.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import GCodeError
from .modal import INCH_MM

FULL_CIRCLE_EPS_MM = 1e-9
FULL_TURN_EPS_RAD = 1e-12  # an end this close to the start, as an angle, closes a full turn

# LinuxCNC's arc tolerances (rs274ngc interp_internal.hh, 2.9), so that a program LinuxCNC runs
# runs here and one it refuses is refused: CAM posts round coordinates to 3-4 decimals, and a
# semicircle in R form or a small arc in I/J form then misses its radius by that rounding.
RADIUS_TOLERANCE_MM = 0.00005 * INCH_MM  # R form: how far the radius may fall short of half the chord
# ... taken a hair wider (relative 1e-9): a G20 semicircle written to 4 decimals falls short by
# exactly 0.00005 inch, and there rounding alone decides LinuxCNC's comparison either way
R_FORM_SLACK_MM = RADIUS_TOLERANCE_MM * (1.0 + 1e-9)
SPIRAL_TOLERANCE_MM = 2 * 0.01 * math.sqrt(2.0)  # I/J form: end radius - start radius, in a G21 program
SPIRAL_TOLERANCE_INCH_MM = 2 * 0.001 * math.sqrt(2.0) * INCH_MM  # the same in a G20 program
SPIRAL_RELATIVE_TOLERANCE = 0.001  # ... beyond the absolute one only when also this large a share


def centre_from_radius(x0: float, y0: float, x1: float, y1: float, r: float, cw: bool) -> tuple[float, float]:
    """Centre of the arc of radius |r| from (x0, y0) to (x1, y1); r < 0 asks for the arc over 180 degrees."""
    dx, dy = x1 - x0, y1 - y0
    chord = math.hypot(dx, dy)
    if chord < FULL_CIRCLE_EPS_MM:
        raise GCodeError("a full circle cannot be programmed with R: use I and J", code="arc-radius-format")
    half = chord / 2.0
    radius = abs(r)
    if half - radius > R_FORM_SLACK_MM:
        raise GCodeError(
            f"arc radius {radius:.4f} mm is too small to reach the end point {chord:.4f} mm away",
            code="arc-radius-too-small",
        )
    h = math.sqrt(max(radius * radius - half * half, 0.0))
    mx, my = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    ux, uy = -dy / chord, dx / chord  # left normal of the chord
    # CCW short arc: centre on the left of the chord; CW short arc: on the right; R < 0 swaps
    side = 1.0 if (not cw) == (r > 0) else -1.0
    return mx + side * h * ux, my + side * h * uy


def spiral_error(r_start: float, r_end: float, inch: bool) -> bool:
    """Do an I/J arc's radii to its start and end differ by more than LinuxCNC allows? Never beyond
    100 times the absolute tolerance; beyond the absolute tolerance only when also over the
    relative one. The absolute tolerance is the program's units' (G20: 0.0028 inch, G21: 0.028 mm)."""
    tolerance = SPIRAL_TOLERANCE_INCH_MM if inch else SPIRAL_TOLERANCE_MM
    err = abs(r_start - r_end)
    return err > 100.0 * tolerance or (err > tolerance and err > SPIRAL_RELATIVE_TOLERANCE * max(r_start, r_end))


def sweep(x0: float, y0: float, x1: float, y1: float, cx: float, cy: float, cw: bool, turns: int) -> float:
    """Signed swept angle (rad) from start to end around the centre, with `turns` extra full turns."""
    a0 = math.atan2(y0 - cy, x0 - cx)
    a1 = math.atan2(y1 - cy, x1 - cx)
    if cw:
        d = a0 - a1
        if d <= FULL_TURN_EPS_RAD:
            d += 2.0 * math.pi
        return -(d + 2.0 * math.pi * turns)
    d = a1 - a0
    if d <= FULL_TURN_EPS_RAD:
        d += 2.0 * math.pi
    return d + 2.0 * math.pi * turns


def sweeps(x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray, cx: np.ndarray, cy: np.ndarray,
           cw: np.ndarray, turns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`sweep` of many arcs at once, and each arc's start angle (for its bounds)."""
    a0, a1 = np.arctan2(y0 - cy, x0 - cx), np.arctan2(y1 - cy, x1 - cx)
    d = np.where(cw, a0 - a1, a1 - a0)
    d = np.where(d <= FULL_TURN_EPS_RAD, d + 2.0 * math.pi, d) + 2.0 * math.pi * turns
    return np.where(cw, -d, d), a0


def arc_length(radius: float, swept: float, dz: float = 0.0) -> float:
    planar = abs(radius * swept)
    return math.hypot(planar, dz) if dz else planar


def arc_bounds(
    x0: float, y0: float, cx: float, cy: float, radius: float, start_angle: float, swept: float
) -> tuple[float, float, float, float]:
    """(xmin, ymin, xmax, ymax) of the arc, extremes included where the arc passes them."""
    a_end = start_angle + swept
    xs = [x0, cx + radius * math.cos(a_end)]
    ys = [y0, cy + radius * math.sin(a_end)]
    if abs(swept) >= 2.0 * math.pi - 1e-12:
        return cx - radius, cy - radius, cx + radius, cy + radius
    lo, hi = (start_angle, a_end) if swept >= 0 else (a_end, start_angle)
    for k, (px, py) in enumerate(((1, 0), (0, 1), (-1, 0), (0, -1))):
        ang = k * math.pi / 2.0
        # does [lo, hi] contain ang + 2 pi n for some n?
        n = math.ceil((lo - ang) / (2.0 * math.pi))
        if ang + 2.0 * math.pi * n <= hi:
            xs.append(cx + px * radius)
            ys.append(cy + py * radius)
    return min(xs), min(ys), max(xs), max(ys)
