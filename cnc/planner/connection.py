"""Corners passed by a connection: both axes planned in time through the corner, not two motions added.

An overlap (`overlap.py`) passes a stop corner by adding the next section's start to the last
one's braking: two straight motions, each from or to rest. Where the path turns back (a lead-out
into a rapid, a zigzag's sharp turn) the two motions' jerks add on the axis both use, and the sum
must stay short. The jerk-limited optimum of such a stretch (`bench/nest_stretches.py`,
`bench/corner_bound.py`) turns while it brakes instead: each axis's velocity planned in time.

A connection does that with the machine's own axis limits. It leaves the last section at one of its
samples while it still brakes (its position, velocity and acceleration there), and joins the next
one at one of its samples while it speeds up, by the time-optimal, time-synchronised motion of the
axes between those two states (Ruckig: each axis within its velocity, acceleration and a share of
its jerk, `JERK_SHARE`, the rest left for the joins, whose states are read off samples). The
samples between are the connection's; the two sections' samples it replaces are dropped. Which
samples to join is searched on a grid of both sections' last and first samples, the fastest first
(`_candidates`), and a connection counts only where

- every axis keeps its velocity, acceleration and jerk limits on backward differences of the joined
  samples (`CONTEXT` of each section's on either side), as the drives see them;
- every sample of it lies within P of the elements of the two sections near the corner (as the
  overlap's check: the programmed elements where the planner moved or folded the corner);
- its path speed keeps the overlap's cap (`overlap._speed_cap`): the faster of the two moves'
  feeds under their override, next to a rapid the rapid's own speed (as two motions added pass
  there, and LinuxCNC's blends), and under a cutting job the model's cap of the corner;
- it lasts at most `[planner] corner_connection_ms`: its samples are committed as an overlap's are,
  with the next section's first `JOIN_SAMPLES` after it (`CornerPlan.committed_next`), so a hold,
  a stop or an override change made during one acts from the next section's sample after those:
  its replan then continues from samples that are all its own (replanned from the connection's
  last, the third difference across the join passed the jerk limit by 70 %, found by
  `tests/test_planner_connection.py`).

`CornerOverlap.plan` takes it where it passes the corner sooner than the overlap. The runner and
the program's timing make the same choice from the same pieces (`SectionStream.positions`).
Measured on the comparison nest (`bench/linuxcnc_compare.py`): docs/benchmarks.md, "Corners
passed by a connection".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from ruckig import InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

from .path import Element, distance_to_programmed

if TYPE_CHECKING:  # (overlap.py imports this module)
    from .overlap import CornerOverlap
    from .stream import SectionStream

JERK_SHARE = 0.9  # of each axis's jerk a connection may use: the rest covers its joins to the sections' samples
COARSE = 4  # grid step, in samples, of the first search; then every sample around its best
REFINE = 3  # samples either side of the coarse best searched one by one
CHECKED = 12  # the fastest candidates of a search checked in turn (a later one is slower than any of them)
JOIN_SAMPLES = 4  # the next section's samples after a connection committed with it (a third difference spans 4)
FIRST = 3  # a connection leaves the last section no later than 3 samples before its end, joins the next no sooner


@dataclass(frozen=True)
class CornerPlan:
    """How a corner between two sections is passed.

    `saved`: servo periods fewer than a stop at the corner (0: a stop). An overlap adds the last
    section's final `last_samples` samples and the next one's first `next_samples` (the same
    number); a connection replaces them by its own `path` (positions X, Y, Z, one per period)."""

    saved: int
    last_samples: int
    next_samples: int
    path: np.ndarray | None = None

    @property
    def is_connection(self) -> bool:
        return self.path is not None

    @property
    def committed_next(self) -> int:
        """The next section's first samples given with the corner's, before the operator's controls
        act on it: after a connection also `JOIN_SAMPLES` of its own, so that a replan (a hold, an
        override) continues from samples that are all the next section's, its differences with them."""
        return self.next_samples + (JOIN_SAMPLES if self.is_connection else 0)


STOP = CornerPlan(0, 0, 0)


def overlap_plan(samples: int) -> CornerPlan:
    """The plan of an overlap of `samples` (`CornerOverlap.samples`)."""
    return CornerPlan(samples, samples, samples) if samples > 0 else STOP


@dataclass
class _Corner:
    """What a search at one corner reads: both sections' samples near it and what they must keep."""

    tail: np.ndarray  # the last section's samples n_a - len + 1 .. n_a (its last: at rest at the corner)
    head: np.ndarray  # the next one's samples 0 .. len - 1 (0: at rest at the corner)
    near: list[Element]  # the elements it keeps within P of (`overlap._near_corner`)
    tolerance_mm: float
    cap_mm_s: float  # the path speed the connection keeps (`overlap._speed_cap`)


def connection_plan(corners: "CornerOverlap", a: "SectionStream", b: "SectionStream", a_summed: int,
                    beat: int) -> CornerPlan | None:
    """The connection that passes the corner a -> b soonest, if it saves more than `beat` periods.
    `a` is planned to its end and the corner qualifies (`CornerOverlap.applies`); `a_summed` of a's
    first samples belong to the corner before it."""
    window = corner_window(corners, a, b, a_summed)
    if window is None:
        return None
    corner, most_p, most_j = window
    search = _Search(corners, corner)
    best = search.best(range(FIRST, most_p + 1, COARSE), range(FIRST, most_j + 1, COARSE), beat)
    if best is None:
        return None
    p0, j0 = best.last_samples, best.next_samples + 1
    around = search.best(range(max(FIRST, p0 - REFINE), min(most_p, p0 + REFINE) + 1),
                         range(max(FIRST, j0 - REFINE), min(most_j, j0 + REFINE) + 1), best.saved)
    return around or best


def corner_window(corners: "CornerOverlap", a: "SectionStream", b: "SectionStream",
                  a_summed: int) -> tuple[_Corner, int, int] | None:
    """What a connection at the corner a -> b may join: both sections' samples as far as it reaches
    (`CornerOverlap.connection_reach`), and how far that is before a's end and after b's start
    (`most_p`, `most_j`); None where it cannot be passed by one (too short, or not flat)."""
    from .overlap import _near_corner, _speed_cap, flat
    reach = corners.connection_reach
    n_a = int(a.k_end)
    most_p = min(reach, n_a - a_summed - corners.context - 2)
    b.plan_until(reach + corners.context + 2)
    most_j = reach if not (b.final and b.k_end is not None) else min(reach, int(b.k_end) - corners.context - 2)
    if most_p < FIRST or most_j < FIRST:
        return None
    first = n_a - most_p - corners.context - 1  # tail[t] is a's sample first + t
    tail, a_from, _ = a.positions(first, n_a)
    head, _, b_to = b.positions(0, most_j + corners.context + 1)
    near = _near_corner(a.section, a_from, b.section, b_to)
    if not all(flat(e) for e in near):
        return None
    return _Corner(tail, head, near, min(e.tolerance_mm for e in near), _speed_cap(a, b)), most_p, most_j


class _Search:
    """Connections at one corner: their durations on a grid of joins, then checks, fastest first."""

    def __init__(self, corners: "CornerOverlap", corner: _Corner) -> None:
        self.corners = corners
        self.corner = corner
        self.dt = corners.dt
        self.axes = [i for i in range(2) if math.isfinite(corners.velocity[i])]
        n = len(self.axes)
        self.n_tail = len(corner.tail) - 1  # tail[n_tail - p]: the last section's sample n_a - p
        self.tail_states = self._states(corner.tail)
        self.head_states = self._states(corner.head)
        self.ruckig = Ruckig(n)
        self.input = InputParameter(n)
        self.input.max_velocity = [float(corners.velocity[i]) for i in self.axes]
        self.input.max_acceleration = [float(corners.accel[i]) for i in self.axes]
        self.input.max_jerk = [float(corners.jerk[i]) * JERK_SHARE for i in self.axes]
        self.input.synchronization = Synchronization.Time
        self.trajectory = Trajectory(n)

    def best(self, ps: range, js: range, beat: int) -> CornerPlan | None:
        """The soonest connection leaving the last section p samples before its end and joining the
        next at its sample j, p in ps and j in js, that saves more than `beat` periods."""
        found = []
        for p in ps:
            start = self.tail_states[self.n_tail - p]
            for j in js:
                if p + j - 1 <= beat:  # even a connection of one period would save no more
                    continue
                duration = self._duration(start, self.head_states[j])
                if duration is None:
                    continue
                m = math.ceil(duration / self.dt - 1e-9)
                if p + j - m > beat and m - 1 <= self.corners.connection_samples:
                    found.append((-(p + j - m), p, j, m))
        found.sort()
        for _, p, j, m in found[:CHECKED]:
            path = self._samples(p, j, m)
            if path is not None:
                return CornerPlan(p + j - m, p, j - 1, path)
        return None

    def _states(self, samples: np.ndarray) -> list:
        """Position, velocity and acceleration at each sample but the first and last, from its
        neighbours (central differences), per axis connected; None at those two."""
        y = samples[:, self.axes]
        v = (y[2:] - y[:-2]) / (2.0 * self.dt)
        a = (y[2:] - 2.0 * y[1:-1] + y[:-2]) / self.dt ** 2
        return [None, *zip(y[1:-1].tolist(), v.tolist(), a.tolist()), None]

    def _duration(self, start: tuple, end: tuple, minimum: float | None = None) -> float | None:
        """How long the time-optimal connection from one state to the other takes (at least
        `minimum`); it is left in `self.trajectory`. None where there is none (a state a hair over
        a limit, read off the samples)."""
        inp = self.input
        inp.current_position, inp.current_velocity, inp.current_acceleration = start
        inp.target_position, inp.target_velocity, inp.target_acceleration = end
        inp.minimum_duration = minimum
        try:
            result = self.ruckig.calculate(inp, self.trajectory)
        except RuckigError:
            return None
        return self.trajectory.duration if result in (Result.Working, Result.Finished) else None

    def _samples(self, p: int, j: int, m: int) -> np.ndarray | None:
        """The connection's m - 1 samples between the last section's sample n_a - p and the next
        one's sample j, taking m periods, if it keeps every rule (the module's docstring)."""
        c = self.corner
        i = self.n_tail - p
        duration = self._duration(self.tail_states[i], self.head_states[j], m * self.dt)
        if duration is None or math.ceil(duration / self.dt - 1e-9) != m:
            return None
        path = np.repeat(c.tail[-1:], m - 1, axis=0)  # Z (and any axis not connected) as at the corner
        at = self.trajectory.at_time
        path[:, self.axes] = [at(q * self.dt)[0] for q in range(1, m)] if m > 1 else path[:, self.axes]
        return path if self.keeps_rules(p, j, path) else None

    def keeps_rules(self, p: int, j: int, path: np.ndarray) -> bool:
        """Whether the samples `path` between the last section's sample n_a - p and the next one's
        sample j keep every rule of a connection (the module's docstring)."""
        c = self.corner
        i = self.n_tail - p
        k = self.corners.context
        joined = np.concatenate((c.tail[max(0, i - k):i + 1], path, c.head[j:j + k + 1]))
        if not self.corners.within_limits(joined[None])[0]:
            return False
        if not len(path):
            return True
        if (distance_to_programmed(path[:, :2], c.near) > c.tolerance_mm).any():
            return False
        if math.isfinite(c.cap_mm_s):
            into = np.concatenate((c.tail[i:i + 1, :2], path[:, :2], c.head[j:j + 1, :2]))
            speed = np.hypot(*np.diff(into, axis=0).T) / self.dt  # into each of the path's samples and into the join
            if (speed > c.cap_mm_s * (1.0 + 1e-7)).any():
                return False
        return True
