"""Corners the head need not stop at: the next section starts while the last one still slows down.

A section ends at rest wherever the path turns sharper than a kink and no blend is worth it
(`sections.py`: a jerk-limited blend within P / 2 of a sharp corner crawls), and wherever a rapid
meets a feed move. The head brakes to the corner, the averages settle, and the next section starts
from rest. Where nothing has to happen at the corner (two sections one after the other: no jet or
output switching, no dwell, no program stop between them) and the corner has a tolerance
(G64 P > 0), the next section may start k servo periods before the last one has come to rest,
the two motions added, as a motion planner superposes two moves: the head leaves the corner while
it still arrives there.

The sum is checked, not assumed. k is the largest overlap, up to `[planner] corner_overlap_ms`,
for which

- every axis keeps its velocity, acceleration and jerk limits (backward differences of the summed
  positions and of the samples either side of them, as the drives see them), and
- every summed sample keeps the faster of the two moves' feeds (under the override), and under a
  cutting job (`quality.py`) the cutting model's cap of the corner (`sections._overlap_cap`: the
  head turns at speed, so the jet lags as at a corner), and
- every summed sample lies within P of the elements of the two sections near the corner (the
  programmed ones: a section ends and starts there without a blend; where the planner moved the
  corner outward, `sections._move_stop_corners`, or folded a small arc into it,
  `sections._fold_small_arcs` and `_fold_small_turns`, the elements as programmed, so that the sum
  may use the band on both sides of the programmed corner, or of the arc).

The check is made on positions computed from the profile's pieces (`SectionStream.positions`), not
on streamed samples, so the runner and the program's timing (`steps.ProgramTiming`) make the same
choice from the same pieces; the streamed samples differ from them only by rounding (1e-12 mm),
far inside the margin the check keeps. Overlaps save the comparison nest of `bench/
linuxcnc_compare.py` 7.7 s of its 205 s (`bench/overlap_estimate.py`, docs/benchmarks.md).

Where a connection (`connection.py`: both axes planned in time from the last section's braking
to the next one's speed-up) passes the corner sooner, `CornerOverlap.plan` takes it instead; where
two long straight moves meet, also a programmed connection (`programme.py`: the samples through the
corner solved for as a linear programme).

Under way, an overlap's samples are committed: a hold, a stop or an override change made during
one acts from the next section's first sample after it, at most `corner_overlap_ms` of that
section's motion from rest, a lead like the setpoint FIFO's own. (The last section is then
braking to rest at the corner anyway, as hard as a hold would brake it.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import MachineConfig
from . import programme
from .connection import CornerPlan, connection_plan, overlap_plan
from .path import Element, distance_to_programmed
from .sections import Section, flat, overlap_may_apply
from .stream import SectionStream

CONTEXT = 4  # samples either side of an overlap whose differences are checked too (a third difference spans 4)
CONNECTION_REACH = 1.2  # a connection leaves and joins the sections up to this many times its longest before and after the corner
LIMIT_MARGIN = 1e-7  # the summed samples keep each limit to within this share (the streamed ones differ by rounding)


@dataclass(frozen=True)
class CornerOverlap:
    """How far the next section may start before the last one comes to rest, and the limits the sum keeps."""

    dt: float
    max_samples: int  # the longest overlap, in servo periods (0: every corner is a stop)
    velocity: np.ndarray  # per axis X, Y, Z (inf for an axis the machine lacks), mm/s
    accel: np.ndarray  # mm/s^2
    jerk: np.ndarray  # mm/s^3
    connection_samples: int = 0  # the longest connection (`connection.py`), in servo periods (0: none)
    programme_samples: int = 0  # the longest programmed connection (`programme.py`), in servo periods (0: none)

    @classmethod
    def of(cls, config: MachineConfig) -> "CornerOverlap":
        """The machine file's overlap (`[planner] corner_overlap_ms`) and axis limits."""
        def limit(key: str) -> np.ndarray:
            return np.array([getattr(config.axis[a], key) if a in config.axis else np.inf for a in "xyz"])

        dt = config.timing.period_s
        return cls(dt, int(round(config.planner.corner_overlap_ms / 1000.0 / dt)),
                   limit("max_velocity_mm_s"), limit("max_accel_mm_s2"), limit("max_jerk_mm_s3"),
                   int(round(config.planner.corner_connection_ms / 1000.0 / dt)),
                   int(round(config.planner.corner_programme_ms / 1000.0 / dt)))

    @property
    def context(self) -> int:
        """Samples either side of a corner's own whose differences are checked with them."""
        return CONTEXT

    @property
    def connection_reach(self) -> int:
        """How far before a section's end a connection may leave it, and after the next one's
        start join it, in servo periods: a connection may replace more samples than it makes."""
        return int(round(CONNECTION_REACH * self.connection_samples))

    def plan(self, a: SectionStream, b: SectionStream, a_summed: int = 0, book: "programme.ProgrammeBook | None" = None,
             index: int = -1) -> CornerPlan:
        """How the corner from a into b is passed: a stop, an overlap (`samples`) or, where it saves
        more, a connection (`connection.py`) or a programmed one (`programme.py`: from `book`, the
        corner after step `index`; without one, solved here). `a` planned to its end,
        `a_summed` as for `samples`.

        A connection is searched for only where the axis limits or the overlap's cap
        (`corner_overlap_ms`), not P or the feed, hold the overlap short (where the two motions'
        jerks add on an axis: a turn back, a turn so gentle that both push the same way): where P
        holds it, the connection's samples must keep P as well, and none was found to save more (the
        comparison nest's 177 right angles and 45 degree turns, docs/benchmarks.md), while the
        search costs several milliseconds a corner."""
        samples, could_grow = self._overlap(a, b, a_summed)
        best = overlap_plan(samples)
        if self.connection_samples < 1 or not could_grow:
            return best
        best = connection_plan(self, a, b, a_summed, best.saved) or best
        found = programme.window(self, a, b)
        if found is not None:
            corner, p, j = found
            programmed = (book or programme.ProgrammeBook()).plan(self, index, corner, p, j)
            if programmed is not None and programmed.saved > best.saved:
                best = programmed
        return best

    def overlap_held(self, a: SectionStream, b: SectionStream, a_summed: int = 0) -> tuple[int, bool]:
        """The longest overlap (`samples`) and whether the axis limits or its cap, not P or the
        feed, held it short (where `plan` searches connections)."""
        return self._overlap(a, b, a_summed)

    def applies(self, a: Section, b: Section) -> bool:
        """Whether the corner from section a into section b, next to each other, may be overlapped:
        a tolerance there, the same outputs on both sides, and a flat corner (the check measures
        the deviation in XY)."""
        return self.max_samples >= 1 and overlap_may_apply(a.elements[-1], b.elements[0])

    def samples(self, a: SectionStream, b: SectionStream, a_summed: int = 0) -> int:
        """How many samples of b may be added to a's last ones (0: a stop at the corner). `a` must be
        planned to its end (`final`); b's first window is planned here if it is not yet.
        `a_summed`: how many of a's first samples were added to the last ones of the section before
        it (an overlap at its start): the samples checked here keep clear of them, so that no sample
        is the sum of three motions and every one of a's checked is a's own."""
        return self._overlap(a, b, a_summed)[0]

    def _overlap(self, a: SectionStream, b: SectionStream, a_summed: int) -> tuple[int, bool]:
        """`samples`, and whether a longer one could have passed the corner sooner: the corner
        qualifies and the axis limits (on the longest overlap checked, or a section too short for
        any) or the cap held it, rather than P or the feed."""
        if not a.final or a.k_end is None or not self.applies(a.section, b.section):
            return 0, False
        n_a = a.k_end
        most = min(self.max_samples, n_a - a_summed - CONTEXT - 1)
        b.plan_until(most + CONTEXT)  # planned this far, a section that ends sooner is planned to its end
        if b.final and b.k_end is not None:  # a short one: its samples, all of them, and its rest after
            most = min(most, b.k_end - CONTEXT - 1)
        if most < 1:
            return 0, True
        corner = np.asarray(a.section.end, dtype=float)
        tail, a_from, _ = a.positions(n_a - most - CONTEXT, n_a)
        head, _, b_to = b.positions(1, most + CONTEXT)
        near = _near_corner(a.section, a_from, b.section, b_to)
        if not all(flat(e) for e in near):
            return 0, False
        tolerance = min(e.tolerance_mm for e in near)
        summed = _candidates(tail - corner, head - corner, most)  # (most, width, 3), row k - 1: overlap k
        fits = self.within_limits(summed)
        held_by_limits = not fits[-1]
        cap = _speed_cap(a, b)
        if math.isfinite(cap):
            fits &= _within_speed(summed, cap, self.dt)
        kept = np.flatnonzero(fits) + 1
        if not len(kept):
            return 0, held_by_limits
        # within P: the longest overlap the limits allow first (the common answer), then the others at once
        for ks in (kept[-1:], kept[:-1]):
            ok = _within_p(summed[ks - 1], ks, corner, near, tolerance) if len(ks) else ks
            if ok.any():
                k = int(ks[np.flatnonzero(ok)[-1]])
                return k, held_by_limits or k >= self.max_samples
        return 0, held_by_limits

    def within_limits(self, summed: np.ndarray) -> np.ndarray:
        """Per candidate (rows of samples): every axis within its velocity, acceleration and jerk
        limit on backward differences."""
        v = np.diff(summed, axis=1) / self.dt
        acc = np.diff(v, axis=1) / self.dt
        jerk = np.diff(acc, axis=1) / self.dt
        margin = 1.0 + LIMIT_MARGIN
        return ((np.abs(v) <= self.velocity * margin).all(axis=(1, 2))
                & (np.abs(acc) <= self.accel * margin).all(axis=(1, 2))
                & (np.abs(jerk) <= self.jerk * margin).all(axis=(1, 2)))


def _speed_cap(a: SectionStream, b: SectionStream) -> float:
    """The fastest the head may pass the corner a -> b in an overlap: the faster of the two moves'
    feeds under their override (the sum of one still arriving and the other already at its feed
    would otherwise pass over it, by a per cent at a slow feed), and under a cutting job the model's
    cap of the corner (`sections._overlap_cap`). inf next to a rapid: its own speed rules there."""
    la, lb = a.section.limits, b.section.limits
    if la.rapid[-1] or lb.rapid[0]:
        return a.section.end_cap_mm_s
    feed = max(float(la.v_feed[-1]) * a.override, float(lb.v_feed[0]) * b.override)
    return min(feed, a.section.end_cap_mm_s)


def _within_speed(summed: np.ndarray, cap_mm_s: float, dt: float) -> np.ndarray:
    """Per candidate (rows of `_candidates`, overlap k = row + 1): the path speed of every summed
    sample (the overlap's, where the head turns) within `cap_mm_s` (`_speed_cap`)."""
    most = summed.shape[1] - 2 * CONTEXT - 1
    block = summed[:, CONTEXT:most + CONTEXT + 1, :2]  # a sample before the columns any overlap sums, then those
    speed = np.hypot(*np.moveaxis(np.diff(block, axis=1), 2, 0)) / dt  # (most, most): into each summed column
    ks = np.arange(1, most + 1)
    summed_here = np.arange(most)[None, :] >= (most - ks)[:, None]
    return (np.where(summed_here, speed, 0.0) <= cap_mm_s * (1.0 + LIMIT_MARGIN)).all(axis=1)


def _within_p(summed: np.ndarray, ks: np.ndarray, corner: np.ndarray, near: list[Element], tolerance: float) -> np.ndarray:
    """Per candidate (rows of `_candidates` for the overlaps `ks`): every summed sample within P
    of the corner's elements. Overlap k sums A's last k samples, i = -k + 1 .. 0: columns
    most + CONTEXT - k + 1 .. most + CONTEXT."""
    most = summed.shape[1] - 2 * CONTEXT - 1
    block = summed[:, CONTEXT + 1:most + CONTEXT + 1, :2] + corner[:2]  # the columns any overlap sums
    distance = distance_to_programmed(block.reshape(-1, 2), near).reshape(len(ks), most)
    summed_here = np.arange(most)[None, :] >= (most - ks)[:, None]
    return (np.where(summed_here, distance, 0.0) <= tolerance).all(axis=1)


def _candidates(tail: np.ndarray, head: np.ndarray, most: int) -> np.ndarray:
    """Positions (relative to the corner) of every overlap k = 1..most, side by side.

    `tail`: the last section's samples i = -(most + CONTEXT) .. 0 (0: its last, at rest at the
    corner); `head`: the next one's samples j = 1 .. most + CONTEXT (j = 0 is its start, at rest
    at the corner). Overlap k puts sample j of the next section at i = j - k, added to the last
    one's there: row k - 1 holds i = -(most + CONTEXT) .. CONTEXT."""
    width = most + 2 * CONTEXT + 1
    a = np.concatenate((tail, np.zeros((CONTEXT, 3))))
    b = np.concatenate((np.zeros((most + CONTEXT + 1, 3)), head))  # b[j + most + CONTEXT], j >= -(most + CONTEXT)
    index = np.arange(width)[None, :] + np.arange(1, most + 1)[:, None]
    return a[None, :, :] + b[index]


def _near_corner(a: Section, a_from_mm: float, b: Section, b_to_mm: float) -> list[Element]:
    """The elements of a from arc length a_from_mm on and of b up to b_to_mm: where the samples
    checked can be."""
    ends = a.path.s0[1:]
    tail = [e for e, s1 in zip(a.elements, ends) if s1 >= a_from_mm - 1e-9]
    head = [e for e, s0 in zip(b.elements, b.path.s0[:-1]) if s0 <= b_to_mm + 1e-9]
    near: list[Element] = []
    for e in tail + head:  # a corner moved outward or folded is measured against the programmed elements
        near += [p for p in e.programmed or (e,) if not any(p is q for q in near)]
    return near

