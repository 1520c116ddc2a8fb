"""Pre-flight: a program starts only on a homed machine and only when every move stays within travel
(within each axis' `soft_limit_tolerance_mm` of its ends).

The check runs on the interpreted program before any setpoint is made, and a refusal names
the first offending source line, the axis and the values, so the operator can fix the
program (or the work offset) rather than discover it at the soft limit mid-cut.
"""

from __future__ import annotations

import math

import numpy as np

from gcode.arcs import sweeps
from gcode.canon import ARC, DWELL

from ..config import MachineConfig

AXES = ("x", "y", "z")


class PreflightError(ValueError):
    """The program may not start; the message says why, with line and axis."""

    def __init__(self, message: str, line: int | None = None, axis: str | None = None) -> None:
        super().__init__(message)
        self.line, self.axis = line, axis


def preflight(segments: np.ndarray, config: MachineConfig, homed: dict[str, bool], program: str = "program") -> None:
    """Raise PreflightError unless every axis is homed and every segment stays within travel."""
    missing = [a.upper() for a in config.axis_names if not homed.get(a, False)]
    if missing:
        raise PreflightError(
            f"{program} cannot start: axis {', '.join(missing)} not homed (home the machine first)",
            axis=missing[0].lower(),
        )
    if not len(segments):
        return
    lo, hi = segment_bounds(segments)
    for i, axis in enumerate(AXES):
        a = config.axis.get(axis)
        if a is None:
            used = (np.abs(lo[:, i]) > 0) | (np.abs(hi[:, i]) > 0)
            if used.any():
                k = int(np.flatnonzero(used)[0])
                raise PreflightError(
                    f"{program}:{int(segments['line'][k])}: moves along {axis.upper()}, an axis this machine does not have",
                    line=int(segments["line"][k]), axis=axis,
                )
            continue
        # within soft_limit_tolerance_mm of an end counts as on it: the servo clamps such setpoints
        # onto the end (a program parking at X0 rounds to -1e-14; a park overshoots by micrometres)
        tol = a.soft_limit_tolerance_mm + 1e-9
        below = lo[:, i] < a.travel_min_mm - tol
        above = hi[:, i] > a.travel_max_mm + tol
        bad = below | above
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            value = lo[k, i] if below[k] else hi[k, i]
            raise PreflightError(
                f"{program}:{int(segments['line'][k])}: {axis.upper()} reaches {value:.3f} mm, outside the travel "
                f"{a.travel_min_mm:g} to {a.travel_max_mm:g} mm",
                line=int(segments["line"][k]), axis=axis,
            )


def segment_bounds(segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-segment (min, max) XYZ, arcs' extreme points included (all arcs at once: a million-line
    program is checked again at every start; a restart's bounds)."""
    start, end = segments["start"], segments["end"]
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    dwell = segments["kind"] == DWELL
    lo[dwell], hi[dwell] = start[dwell], start[dwell]
    arcs = np.flatnonzero(segments["kind"] == ARC)
    if len(arcs):
        lo[arcs, :2], hi[arcs, :2] = _arc_bounds(segments[arcs])
    return lo, hi


def _arc_bounds(arcs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) XY of each arc: its ends and the quadrant points (0, 90, 180, 270 degrees) its
    sweep passes (`gcode.arcs.arc_bounds`, for many arcs)."""
    x0, y0 = arcs["start"][:, 0], arcs["start"][:, 1]
    x1, y1 = arcs["end"][:, 0], arcs["end"][:, 1]
    cx, cy = arcs["center"][:, 0], arcs["center"][:, 1]
    r = np.hypot(x0 - cx, y0 - cy)
    swept, a0 = sweeps(x0, y0, x1, y1, cx, cy, arcs["cw"], arcs["turns"])
    a_end = a0 + swept
    lo_ang, hi_ang = np.minimum(a0, a_end), np.maximum(a0, a_end)
    xs = [x0, cx + r * np.cos(a_end)]
    ys = [y0, cy + r * np.sin(a_end)]
    full = np.abs(swept) >= 2.0 * math.pi - 1e-12
    for k, (px, py) in enumerate(((1, 0), (0, 1), (-1, 0), (0, -1))):
        ang = k * math.pi / 2.0
        n = np.ceil((lo_ang - ang) / (2.0 * math.pi))
        passes = full | (ang + 2.0 * math.pi * n <= hi_ang)
        xs.append(np.where(passes, cx + px * r, x0))
        ys.append(np.where(passes, cy + py * r, y0))
    xs, ys = np.stack(xs), np.stack(ys)
    return np.stack((xs.min(axis=0), ys.min(axis=0)), axis=1), np.stack((xs.max(axis=0), ys.max(axis=0)), axis=1)
