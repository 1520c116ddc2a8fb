"""A stretch of path as numpy arrays: where the head is at any arc length, many points at once.

The planner moves along a section by its arc length s (mm from the section's start). This
module turns the section's elements (lines and arcs, corner blends included) into columns
so that thousands of samples s map to positions in a few vectorised operations:

    line:  p(s) = start + (s - s0) u
    arc:   p(s) = centre + r (cos a, sin a),  a = a0 + (s - s0) / L * sweep,  z linear in s

Programmed arcs are never exactly round (the end point lies a few um off the start's
radius, within the interpreter's tolerance), so r goes linearly from the start's radius to
the end's, as LinuxCNC does: every element ends exactly where the next one starts.

Signed curvature (1/r, positive counter-clockwise, 0 on lines) and the tangent directions
at both ends of each element are kept for the kinematic limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gcode.canon import ARC

from .path import Element


@dataclass(frozen=True)
class PathArrays:
    """Columns of a chain of motion elements, indexed by element."""

    arc: np.ndarray  # bool: arc (else straight)
    start: np.ndarray  # (n, 3) mm
    end: np.ndarray  # (n, 3)
    center: np.ndarray  # (n, 2), arcs only
    radius: np.ndarray  # (n,), arcs only: radius at the start
    radius_end: np.ndarray  # (n,), arcs only: radius at the end
    angle0: np.ndarray  # start angle of arcs, rad
    sweep: np.ndarray  # signed swept angle of arcs, rad
    length: np.ndarray  # (n,) mm
    s0: np.ndarray  # (n + 1,) arc length at each element's start; s0[-1] is the total
    direction: np.ndarray  # (n, 3) unit direction of straight elements
    curvature: np.ndarray  # (n,) signed XY curvature, 1/mm
    tangent_in: np.ndarray  # (n, 2) XY unit tangent at each element's start
    tangent_out: np.ndarray  # (n, 2) XY unit tangent at each element's end

    @property
    def total_mm(self) -> float:
        return float(self.s0[-1])

    def __len__(self) -> int:
        return len(self.length)

    @classmethod
    def of(cls, elements: list[Element]) -> "PathArrays":
        n = len(elements)
        # one row of numbers per element, converted at once (a section is made from a few elements,
        # where each conversion of its own would cost more than the numbers)
        rows = np.array([
            (*e.start, *e.end, *(e.center if e.kind == ARC else (0.0, 0.0)), e.sweep_rad if e.kind == ARC else 0.0,
             e.length_mm, *e.direction_at_start(), *e.direction_at_end(), e.kind == ARC)
            for e in elements
        ], dtype=float).reshape(n, 15)
        start, end, center = rows[:, 0:3], rows[:, 3:6], rows[:, 6:8]
        sweep, length = rows[:, 8], rows[:, 9]
        tangent_in, tangent_out = rows[:, 10:12], rows[:, 12:14]
        arc = rows[:, 14] != 0.0
        radius = np.where(arc, np.hypot(start[:, 0] - center[:, 0], start[:, 1] - center[:, 1]), 0.0)
        radius_end = np.where(arc, np.hypot(end[:, 0] - center[:, 0], end[:, 1] - center[:, 1]), 0.0)
        angle0 = np.where(arc, np.arctan2(start[:, 1] - center[:, 1], start[:, 0] - center[:, 0]), 0.0)
        chord = end - start
        norm = np.linalg.norm(chord, axis=1)
        direction = np.where(~arc[:, None] & (norm[:, None] > 0), chord / np.where(norm > 0, norm, 1.0)[:, None], 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            curvature = np.where(arc, np.sign(sweep) / np.where(radius > 0, radius, 1.0), 0.0)
        s0 = np.concatenate(([0.0], np.cumsum(length)))
        return cls(arc, start, end, center, radius, radius_end, angle0, sweep, length, s0, direction, curvature, tangent_in, tangent_out)

    def index_at(self, s: np.ndarray) -> np.ndarray:
        """Index of the element each arc length lies on (ends clamp to the first or last element)."""
        k = np.searchsorted(self.s0, s, side="right") - 1
        return np.clip(k, 0, len(self.length) - 1)

    def points(self, s: np.ndarray, index: np.ndarray | None = None) -> np.ndarray:
        """Positions (m, 3) at arc lengths `s` (m,), clamped to the path."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.total_mm)
        k = self.index_at(s) if index is None else index
        along = s - self.s0[k]
        out = self.start[k] + along[:, None] * self.direction[k]
        arcs = self.arc[k]
        if arcs.any():
            ka, la = k[arcs], along[arcs]
            frac = np.where(self.length[ka] > 0, la / self.length[ka], 0.0)
            ang = self.angle0[ka] + frac * self.sweep[ka]
            r = self.radius[ka] + frac * (self.radius_end[ka] - self.radius[ka])
            out[arcs, 0] = self.center[ka, 0] + r * np.cos(ang)
            out[arcs, 1] = self.center[ka, 1] + r * np.sin(ang)
            out[arcs, 2] = self.start[ka, 2] + frac * (self.end[ka, 2] - self.start[ka, 2])
        return out

    def kink_angles(self) -> np.ndarray:
        """Turn of the tangent at each junction between consecutive elements (n - 1,), rad."""
        if len(self.length) < 2:
            return np.zeros(0)
        a, b = self.tangent_out[:-1], self.tangent_in[1:]
        cos = np.clip((a * b).sum(axis=1), -1.0, 1.0)
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        return np.abs(np.arctan2(cross, cos))

