"""Pre-flight: a program starts only on a homed machine and only when every move stays within travel
(within each axis' `soft_limit_tolerance_mm` of its ends).

The check runs on the interpreted program before any setpoint is made, and a refusal names
the first offending source line, the axis and the values, so the operator can fix the
program (or the work offset) rather than discover it at the soft limit mid-cut.
"""

from __future__ import annotations

import math

import numpy as np

from gcode.arcs import arc_bounds, sweep
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
    lo, hi = _segment_bounds(segments)
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


def _segment_bounds(segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-segment (min, max) XYZ, arcs' extreme points included."""
    start, end = segments["start"], segments["end"]
    lo, hi = np.minimum(start, end), np.maximum(start, end)
    dwell = segments["kind"] == DWELL
    lo[dwell], hi[dwell] = start[dwell], start[dwell]
    for k in np.flatnonzero(segments["kind"] == ARC):
        (x0, y0, _), (x1, y1, _) = start[k], end[k]
        cx, cy = segments["center"][k]
        r = math.hypot(x0 - cx, y0 - cy)
        swept = sweep(x0, y0, x1, y1, cx, cy, bool(segments["cw"][k]), int(segments["turns"][k]))
        bx0, by0, bx1, by1 = arc_bounds(x0, y0, cx, cy, r, math.atan2(y0 - cy, x0 - cx), swept)
        lo[k, 0], lo[k, 1], hi[k, 0], hi[k, 1] = bx0, by0, bx1, by1
    return lo, hi
