"""Kinematic limits along the path: how fast, how hard and how jerky each element may be run.

The machine file limits each axis. Along a straight element of direction u, axis i sees
the fraction |u_i| of the path's velocity, acceleration and jerk, so the path may go as far
as the tightest axis allows: min_i limit_i / |u_i|. On an arc the direction turns through
every angle it sweeps, so the tightest axis limit applies in full, and part of it is spent
on turning: a share s of the acceleration holds the centripetal v^2/R (v <= sqrt(s a R)),
and a share s of the jerk holds its rotation v^3/R^2 (v <= (s j R^2)^(1/3)); the rest,
(1 - s), is left to speed up and slow down along the arc. The programmed feed caps
everything but rapids.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gcode.canon import ARC, DWELL

from ..config import MachineConfig
from .path import Element

AXES = ("x", "y", "z")


@dataclass(frozen=True, slots=True)
class Limits:
    """Largest path velocity (mm/s), acceleration (mm/s^2) and jerk (mm/s^3) along an element."""

    velocity: float
    acceleration: float
    jerk: float


class LimitCalculator:
    """Element limits for one machine."""

    def __init__(self, config: MachineConfig) -> None:
        self.share = config.planner.arc_normal_share
        self.v = {a: c.max_velocity_mm_s for a, c in config.axis.items()}
        self.a = {a: c.max_accel_mm_s2 for a, c in config.axis.items()}
        self.j = {a: c.max_jerk_mm_s3 for a, c in config.axis.items()}

    def of(self, e: Element) -> Limits:
        if e.kind == DWELL:
            return Limits(0.0, min(self.a.values()), min(self.j.values()))
        if e.kind == ARC:
            return self._arc(e)
        return self._straight(e)

    def _straight(self, e: Element) -> Limits:
        d = [e.end[i] - e.start[i] for i in range(3)]
        n = math.sqrt(sum(c * c for c in d))
        v = a = j = math.inf
        for i, axis in enumerate(AXES):
            u = abs(d[i]) / n
            if u <= 1e-12:
                continue
            if axis not in self.v:
                raise ValueError(f"line {e.line}: the move runs along {axis.upper()}, an axis the machine lacks")
            v = min(v, self.v[axis] / u)
            a = min(a, self.a[axis] / u)
            j = min(j, self.j[axis] / u)
        return Limits(min(v, e.feed_mm_s), a, j)

    def _arc(self, e: Element) -> Limits:
        cx, cy = e.center
        radius = math.hypot(e.start[0] - cx, e.start[1] - cy)
        v_axis = min(self.v["x"], self.v["y"])
        a_axis = min(self.a["x"], self.a["y"])
        j_axis = min(self.j["x"], self.j["y"])
        v_turn = math.sqrt(self.share * a_axis * radius)
        v_jerk = (self.share * j_axis * radius * radius) ** (1.0 / 3.0)
        velocity = min(v_axis, v_turn, v_jerk, e.feed_mm_s)
        return Limits(velocity, (1.0 - self.share) * a_axis, (1.0 - self.share) * j_axis)
