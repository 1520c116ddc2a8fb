"""Measuring motion: per-axis peaks from setpoints, and how far points stray from the programmed path.

The planner's limits are derived, not assumed to hold; tests, `waterjet simulate` and the
benchmarks measure them here. Velocity, acceleration and jerk are backward differences of
the positions (what a drive sees tick by tick). The distance of a point to the programmed
geometry is taken to the program segments near the one the point is tagged with (its
setpoint's segment), lines and arcs exactly (an arc whose end lies a hair off its start's radius as the spiral it is
run as), so a contour that passes near itself does not
hide a deviation.
"""

from __future__ import annotations

import math

import numpy as np

from gcode.canon import ARC, DWELL

from .path import elements_from_program


def peaks(positions: np.ndarray, dt: float) -> dict[str, np.ndarray]:
    """Largest |velocity|, |acceleration| and |jerk| per axis of positions (n, k) sampled every dt."""
    p = np.asarray(positions, dtype=float)
    v = np.diff(p, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    top = lambda x: np.abs(x).max(axis=0) if len(x) else np.zeros(p.shape[1])  # noqa: E731
    return {"velocity": top(v), "acceleration": top(a), "jerk": top(j)}


class ProgrammedPath:
    """The program's geometry as arrays, for distances from many points at once."""

    def __init__(self, segments: np.ndarray) -> None:
        elements = [e for e in elements_from_program(segments) if e.kind != DWELL]
        self.elements = elements
        n = len(elements)
        self.by_segment = np.full(len(segments) + 1, -1, dtype=np.int64)
        for i, e in enumerate(elements):
            self.by_segment[e.segment] = i
        # a segment without an element (dwell, zero length) maps to the element before it
        last = 0
        for k in range(len(self.by_segment)):
            if self.by_segment[k] < 0:
                self.by_segment[k] = last
            else:
                last = self.by_segment[k]
        self.start = np.array([e.start[:2] for e in elements]).reshape(n, 2)
        self.end = np.array([e.end[:2] for e in elements]).reshape(n, 2)
        self.arc = np.array([e.kind == ARC for e in elements], dtype=bool)
        self.center = np.array([e.center if e.kind == ARC else (0.0, 0.0) for e in elements]).reshape(n, 2)
        self.radius = np.where(self.arc, np.hypot(*(self.start - self.center).T), 0.0)
        self.radius_end = np.where(self.arc, np.hypot(*(self.end - self.center).T), 0.0)
        self.a0 = np.arctan2(self.start[:, 1] - self.center[:, 1], self.start[:, 0] - self.center[:, 0])
        self.sweep = np.array([e.sweep_rad if e.kind == ARC else 0.0 for e in elements])

    def distance(self, points: np.ndarray, segment: np.ndarray, window: int = 8) -> np.ndarray:
        """Distance of each XY point to the nearest programmed element within `window` elements
        of the one its segment tag names."""
        pts = np.asarray(points, dtype=float)[:, :2]
        base = self.by_segment[np.clip(np.asarray(segment, dtype=np.int64), 0, len(self.by_segment) - 1)]
        best = np.full(len(pts), np.inf)
        n = len(self.elements)
        for d in range(-window, window + 1):
            k = np.clip(base + d, 0, n - 1)
            best = np.minimum(best, self._to(pts, k))
        return best

    def _to(self, pts: np.ndarray, k: np.ndarray) -> np.ndarray:
        a, b = self.start[k], self.end[k]
        ab = b - a
        denom = (ab * ab).sum(axis=1)
        t = np.clip(((pts - a) * ab).sum(axis=1) / np.where(denom > 0, denom, 1.0), 0.0, 1.0)
        line = np.hypot(*(pts - a - t[:, None] * ab).T)
        arc = self.arc[k]
        if not arc.any():
            return line
        c, a0, sw = self.center[k], self.a0[k], self.sweep[k]
        rel = pts - c
        ang = np.arctan2(rel[:, 1], rel[:, 0])
        along = np.mod((ang - a0) * np.where(sw >= 0, 1.0, -1.0), 2.0 * math.pi)
        full = np.abs(sw) >= 2.0 * math.pi - 1e-9
        on = full | (along <= np.abs(sw))
        # an arc whose end lies off its start's radius is a spiral between the two (as it is run);
        # on an arc of more than one turn the point may be on any of them: the nearest counts
        span = np.where(np.abs(sw) > 0, np.abs(sw), 1.0)
        dist = np.hypot(rel[:, 0], rel[:, 1])
        radial = np.full(len(pts), np.inf)
        for turn in range(int(np.abs(sw).max() // (2.0 * math.pi)) + 1 if len(sw) else 1):
            angle = along + 2.0 * math.pi * turn
            reach = (angle <= np.abs(sw)) | (turn == 0)
            frac = np.where(np.abs(sw) > 0, np.minimum(angle / span, 1.0), 0.0)
            r = self.radius[k] + frac * (self.radius_end[k] - self.radius[k])
            radial = np.where(reach, np.minimum(radial, np.abs(dist - r)), radial)
        ends = np.minimum(np.hypot(*(pts - a).T), np.hypot(*(pts - b).T))
        return np.where(arc, np.where(on, radial, ends), line)

