"""The least time any sampled, jerk-limited trajectory needs along a polyline kept within G64 P.

`bench/linuxcnc_compare.py` compares our cycle times with LinuxCNC 2.9's, which has no jerk
limit. Where LinuxCNC is faster than any trajectory that holds our jerk limit could be, the
issue asks for that bound beside the figure. Its closed-form bound (`jerk_bound_s`) counts
the ramps at rest but no corner, so on a square or a zigzag it cannot tell whether LinuxCNC's
time is within a jerk-limited planner's reach. This one counts the corners, exactly for the
problem it states:

    a trajectory sampled every servo period dt, from rest at the first point to rest at the
    last, whose per-axis backward differences keep |v| <= V, |a| <= A and |j| <= J, whose
    path speed keeps |v| <= F (the feed), and whose every sample lies within P of the
    programmed polyline.

No planner that holds those limits, ours or any other, takes fewer periods. It is the optimum
of that problem, found by linear programming, not an estimate; relaxed where that is cheaper
(so it stays a bound): the feed's circle is the polygon around it, the neighbourhood of a leg
is the rectangle around its capsule, and the problem is cut into windows whose times add up.

Windows: one around each corner and each end of the polyline, reaching along its legs half as
far again as the feed's ramp to rest takes (at most half of each leg), and the straight stretches
between them. A window's time is counted from the first sample past its starting cut to the
first sample past its ending cut, so consecutive windows share a sample and the periods add up
to the whole; its starting state is free (any speed, acceleration), which can only make it
shorter than in the whole trajectory. A straight stretch between two cuts takes at least its
length over F dt, less one period. In a corner's window the samples up to some index k lie near
the incoming leg (the first among them) and those after near the outgoing leg (the last among
them), none more than P behind the window's starting cut (a trajectory going back along the
path further is not considered: both planners only go forward); the least number of periods N is found by bisection on N (taking a window that can be run
in N periods to be runnable in N + 1), each N feasible when some k is. The k are searched by
branch and bound: for a range of k the samples in it need only lie in a polygon around both
legs' rectangles (the support function of their union), which is feasible whenever any k in
the range is; a range found infeasible is dropped, a feasible one halved, down to one k. A
programme neither of HiGHS's methods decides counts as feasible (the bound can only come out
lower). The windows hold every sample only where no other leg comes near (`check_apart`).

Solved with scipy's HiGHS (`scipy.optimize.linprog`), positions in units of J dt^3 so that the
jerk constraint reads |third difference| <= 1. From the repository root (the zigzag and square
programs of the LinuxCNC comparison, each corner's cost over cruising it):

    .venv/bin/python bench/corner_bound.py
"""

from __future__ import annotations

import math
import multiprocessing
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import Bounds, LinearConstraint, linprog, milp

FEED_SIDES = 16  # the feed's circle as a polygon around it (|v| may reach F / cos(pi / 16), 2 % over, between
# its sides; along each leg of a window it is exact: the leg's direction is one more side)
HULL_DIRECTIONS = 16  # directions of the polygon around both legs' rectangles in a range of k
SLACK = 1e-6  # limits widened by this share: a solver's rounding never makes a feasible N infeasible


@dataclass(frozen=True)
class Limits:
    """The problem's limits: the servo period, per-axis velocity, acceleration and jerk, the path
    feed and the G64 P tolerance (mm, s)."""

    dt: float
    v_axis: tuple[float, float]
    a_axis: tuple[float, float]
    j_axis: tuple[float, float]
    feed: float
    tolerance: float


@dataclass(frozen=True)
class Window:
    """A stretch of the polyline: from `start` to `end` through `corner` (None: a straight stretch),
    starting at rest at `start` or past the cut there, ending at rest at `end` or past the cut."""

    start: tuple[float, float]
    corner: tuple[float, float] | None
    end: tuple[float, float]
    rest_start: bool
    rest_end: bool

    @property
    def length_mm(self) -> float:
        return math.dist(self.start, self.corner or self.end) + (math.dist(self.corner, self.end) if self.corner else 0.0)


def windows(points: list[tuple[float, float]], reach_mm: float = math.inf) -> list[Window]:
    """The polyline cut into windows: one around each corner and each end, reaching `reach_mm`
    along its legs (at most half of each), and the straight stretches between them."""
    pts = [p for k, p in enumerate(points) if k == 0 or math.dist(p, points[k - 1]) > 0.0]
    if len(pts) < 2:
        return []
    if len(pts) == 2 and math.dist(*pts) <= 2.0 * reach_mm:
        return [Window(pts[0], None, pts[1], True, True)]

    def along(a: tuple[float, float], b: tuple[float, float], d: float) -> tuple[float, float]:
        f = d / math.dist(a, b)
        return (a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]))

    # the cuts on each leg: one in the middle of a short leg, two at `reach_mm` from its ends on a long one
    cuts = []
    for a, b in zip(pts, pts[1:]):
        length = math.dist(a, b)
        cuts.append([along(a, b, length / 2.0)] if length <= 2.0 * reach_mm
                    else [along(a, b, reach_mm), along(a, b, length - reach_mm)])
    out = [Window(pts[0], None, cuts[0][0], True, False)]
    for k in range(len(pts) - 1):
        if len(cuts[k]) == 2:
            out.append(Window(cuts[k][0], None, cuts[k][1], False, False))
        if k + 1 < len(pts) - 1:
            out.append(Window(cuts[k][-1], pts[k + 1], cuts[k + 1][0], False, False))
    out.append(Window(cuts[-1][-1], None, pts[-1], False, True))
    return out


def check_apart(points: list[tuple[float, float]], limits: Limits) -> None:
    """The windows hold a trajectory's samples near their own two legs; that is all of them only
    where no other leg of the polyline comes within 2 P + F dt (a sample cannot be near it
    without having travelled there). ValueError where one does. One exception: a closed
    polyline's first and last legs meet where it starts and ends at rest; a sample of the last
    window near the first leg would be a detour past the end and back to rest there (and so for
    the first window), which we take not to be quicker than stopping: assumed, not proved."""
    pts = [p for k, p in enumerate(points) if k == 0 or math.dist(p, points[k - 1]) > 0.0]
    gap = 2.0 * limits.tolerance + limits.feed * limits.dt * 1.1
    segments = list(zip(pts, pts[1:]))
    closed = len(segments) > 2 and math.dist(pts[0], pts[-1]) == 0.0
    for i, (a, b) in enumerate(segments):
        for k in range(i + 2, len(segments)):
            if closed and (i, k) == (0, len(segments) - 1):
                continue
            c, d = segments[k]
            near = min(_to_segment(a, c, d), _to_segment(b, c, d), _to_segment(c, a, b), _to_segment(d, a, b))
            if near <= gap or _cross(a, b, c, d):
                raise ValueError(f"corner bound: legs {i + 1} and {k + 1} of the polyline come within {near:.3f} mm "
                                 f"of each other (2 P + F dt = {gap:.3f} mm): the windows do not hold the trajectory")


def _to_segment(p, a, b) -> float:  # noqa: ANN001 - points as pairs
    ab = (b[0] - a[0], b[1] - a[1])
    t = max(0.0, min(1.0, ((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1]) / (ab[0] ** 2 + ab[1] ** 2)))
    return math.dist(p, (a[0] + t * ab[0], a[1] + t * ab[1]))


def _cross(a, b, c, d) -> bool:  # noqa: ANN001 - points as pairs
    side = lambda p, q, r: (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])  # noqa: E731
    return side(a, b, c) * side(a, b, d) < 0.0 and side(c, d, a) * side(c, d, b) < 0.0


def reach_for(limits: Limits) -> float:
    """How far along its legs a corner's window reaches: half as far again as the slowest axis
    takes to stop from the feed (the ramp a corner may need on either side), and at least 5 P."""
    a, j = min(limits.a_axis), min(limits.j_axis)
    v = limits.feed
    ramp_s = 2.0 * math.sqrt(v / j) if v <= a * a / j else v / a + a / j
    return max(1.5 * v * ramp_s, 5.0 * limits.tolerance)


def polyline_bound_ticks(points: list[tuple[float, float]], limits: Limits, workers: int = 1) -> int:
    """Servo periods no jerk-limited trajectory along `points` (rest to rest, within P) beats;
    the windows' programmes solved in `workers` processes."""
    check_apart(points, limits)
    if workers > 1:
        presolve([points], limits, workers)
    return sum(window_ticks(w, limits) for w in windows(points, reach_for(limits)))


def presolve(polylines: list[list[tuple[float, float]]], limits: Limits, workers: int) -> None:
    """Solve the corner and end windows of all these polylines in `workers` processes at once
    (the longest first), so that `polyline_bound_ticks` then finds every one of them solved."""
    reach = reach_for(limits)
    shapes = {_canonical(w, limits) for points in polylines for w in windows(points, reach)
              if w.corner is not None or w.rest_start or w.rest_end}
    todo = sorted((w for w in shapes if (w, limits) not in _SOLVED), key=lambda w: -w.length_mm)
    if not todo:
        return
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as pool:
        for w, ticks in zip(todo, pool.map(_window_ticks, todo, [limits] * len(todo))):
            _SOLVED[(w, limits)] = ticks


def window_ticks(w: Window, limits: Limits) -> int:
    """The least periods of one window: a straight stretch between two cuts by its length (every
    period covers at most F dt of it), the others by bisection on N, each N feasible when some k
    is. Windows equal but for where they lie (and, with the same limits on both axes, for a
    quarter turn or a mirror, which leave the axes' limits and the feed's polygon as they are)
    are solved once."""
    if w.corner is None and not w.rest_start and not w.rest_end:
        return max(0, math.floor(w.length_mm / (limits.feed * limits.dt * (1.0 + SLACK))) - 1)
    return _window_ticks(_canonical(w, limits), limits)


def _canonical(w: Window, limits: Limits) -> Window:
    origin = w.corner if w.corner is not None else w.start
    points = [(p[0] - origin[0], p[1] - origin[1]) for p in (w.start, w.corner or w.start, w.end)]
    square = limits.v_axis[0] == limits.v_axis[1] and limits.a_axis[0] == limits.a_axis[1] \
        and limits.j_axis[0] == limits.j_axis[1] and FEED_SIDES % 4 == 0
    maps = [lambda x, y: (x, y)]
    if square:
        maps = [lambda x, y, s=s, t=t, swap=swap: ((t * y, s * x) if swap else (s * x, t * y))
                for s in (1, -1) for t in (1, -1) for swap in (False, True)]
    candidates = [tuple((round(a, 9) + 0.0, round(b, 9) + 0.0) for a, b in (f(*p) for p in points)) for f in maps]
    start, corner, end = min(candidates)
    return Window(start, corner if w.corner is not None else None, end, w.rest_start, w.rest_end)


_HINTS: dict[Window, int] = {}  # the k of the last feasible programme of each window: tried first


_SOLVED: dict[tuple[Window, Limits], int] = {}  # windows solved, here or by a pool's processes


def _window_ticks(w: Window, limits: Limits) -> int:
    if (w, limits) not in _SOLVED:
        _SOLVED[(w, limits)] = _least_ticks(w, limits)
    return _SOLVED[(w, limits)]


def _least_ticks(w: Window, limits: Limits) -> int:
    step = limits.feed * limits.dt / math.cos(math.pi / FEED_SIDES)
    lo = max(1, math.floor((w.length_mm - 20.0 * limits.tolerance) / step) - 2)  # cannot be done in fewer: too far
    if _feasible(w, limits, lo):
        return lo
    hi = lo + 8
    while not _feasible(w, limits, hi):
        lo, hi = hi, hi + 2 * (hi - lo)
    while hi - lo > 1:  # lo infeasible, hi feasible
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if _feasible(w, limits, mid) else (mid, hi)
    return hi


# -- the linear programme ------------------------------------------------------------------------
def _frame(w: Window) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray, float, float]]]:
    """The window's origin and its legs, each as (direction u, normal n, along-from, along-to)
    relative to the origin (the corner, or the start of a straight window)."""
    origin = np.array(w.corner if w.corner is not None else w.start, dtype=float)
    legs = []
    ends = [w.start, w.corner, w.end] if w.corner is not None else [w.start, w.end]
    for a, b in zip(ends, ends[1:]):
        a, b = np.array(a, dtype=float) - origin, np.array(b, dtype=float) - origin
        u = (b - a) / np.linalg.norm(b - a)
        n = np.array([-u[1], u[0]])
        legs.append((u, n, float(u @ a), float(u @ b)))
    return origin, legs


def _feasible(w: Window, limits: Limits, n_periods: int) -> bool:
    origin, legs = _frame(w)
    if w.corner is None:
        return _solve(w, limits, n_periods, origin, legs, None)
    hint = _HINTS.get(w)
    if hint is not None:  # where the last feasible one switched legs, and next to it: one programme each
        for k in (hint, hint + 1, hint - 1):
            if 0 <= k <= n_periods - 1 and _solve(w, limits, n_periods, origin, legs, (k, k)):
                _HINTS[w] = k
                return True
    # k: the last sample near the incoming leg; the first sample is near it and the last near the
    # outgoing one (else the cuts' conditions could be met by a sample near the other leg: past a
    # sharp corner the outgoing leg runs back along the incoming one)
    stack = [(0, n_periods - 1)]
    while stack:
        k1, k2 = stack.pop()
        if not _solve(w, limits, n_periods, origin, legs, (k1, k2)):
            continue
        if k1 == k2:
            _HINTS[w] = k1
            return True
        mid = (k1 + k2) // 2
        stack += [(mid + 1, k2), (k1, mid)]  # the earlier half first
    return False


def _solve(w: Window, limits: Limits, n_periods: int, origin: np.ndarray, legs: list, ks: tuple[int, int] | None) -> bool:
    """Whether the window can be run in `n_periods` with the samples up to k near the incoming leg
    for some k in `ks` (None: a straight window). Samples: three at rest before a rest start (or
    the first past the cut), the motion, three at rest after a rest end."""
    dt, tol = limits.dt, limits.tolerance
    unit = min(limits.j_axis) * dt ** 3  # mm: positions in these units make the jerk bound 1
    widen = 1.0 + SLACK
    pre = 2 if w.rest_start else 0
    post = 2 if w.rest_end else 0
    m = pre + n_periods + 1 + post  # samples
    first, last = pre, pre + n_periods  # the window's first and last counted sample
    blocks: list[tuple[sparse.spmatrix, np.ndarray, np.ndarray]] = []  # (rows over the 2m variables, lower, upper)

    def diffs(order: int, axis: int) -> sparse.spmatrix:
        """Backward differences of `order` of one axis's samples, one row per sample from `order` on."""
        d = sparse.eye(m, format="csr")
        for _ in range(order):
            d = (d[1:] - d[:-1])
        out = sparse.lil_matrix((d.shape[0], 2 * m))
        out[:, axis::2] = d
        return out.tocsr()

    for order, per_axis in ((1, limits.v_axis), (2, limits.a_axis), (3, limits.j_axis)):
        for axis in (0, 1):
            bound = per_axis[axis] * dt ** order / unit * widen
            d = diffs(order, axis)
            blocks.append((d, np.full(d.shape[0], -bound), np.full(d.shape[0], bound)))
    # the feed: a polygon around its circle, exact along each leg of the window
    angles = 2 * np.pi * np.arange(FEED_SIDES) / FEED_SIDES
    directions = np.vstack([np.column_stack([np.cos(angles), np.sin(angles)]), *[leg[0][None, :] for leg in legs]])
    dx, dy = diffs(1, 0), diffs(1, 1)
    feed = limits.feed * dt / unit * widen
    for c, sn in directions:
        blocks.append((c * dx + sn * dy, np.full(dx.shape[0], -np.inf), np.full(dx.shape[0], feed)))
    # where the samples may lie (relative to the origin, in units)
    s_tol = tol / unit
    step = limits.feed * dt / math.cos(math.pi / FEED_SIDES) / unit * widen

    def leg_box(leg: int) -> tuple[np.ndarray, np.ndarray, float, float]:
        """The rectangle around a leg's capsule within the window: from P behind the starting cut
        (a trajectory that goes back along the path further than that is not considered; both
        planners go forward) to the corner, from the corner to a period past the ending cut (no
        sample of the window but its last is past that cut)."""
        u, n, a, b = legs[leg]
        a_lo = a / unit - s_tol if leg == 0 else -s_tol
        b_hi = b / unit + step if leg == len(legs) - 1 else s_tol
        return u, n, a_lo, b_hi

    def rows_of(samples: np.ndarray, d: np.ndarray) -> sparse.spmatrix:
        """One row per sample: d . p_t."""
        r = np.repeat(np.arange(len(samples)), 2)
        c = np.column_stack([2 * samples, 2 * samples + 1]).ravel()
        v = np.tile(d, len(samples))
        return sparse.csr_matrix((v, (r, c)), shape=(len(samples), 2 * m))

    def near(samples: np.ndarray, leg: int) -> None:
        if not len(samples):
            return
        u, n, a_lo, b_hi = leg_box(leg)
        k = len(samples)
        blocks.append((rows_of(samples, n), np.full(k, -s_tol), np.full(k, s_tol)))
        blocks.append((rows_of(samples, u), np.full(k, a_lo), np.full(k, b_hi)))

    def near_either(samples: np.ndarray) -> None:
        """The support function of both legs' rectangles, in HULL_DIRECTIONS directions."""
        if not len(samples):
            return
        corners = []
        for leg in range(len(legs)):
            u, n, a_lo, b_hi = leg_box(leg)
            corners += [u * x + n * y for x in (a_lo, b_hi) for y in (-s_tol, s_tol)]
        corners = np.array(corners)
        for k in range(HULL_DIRECTIONS):
            d = np.array([math.cos(2 * math.pi * k / HULL_DIRECTIONS), math.sin(2 * math.pi * k / HULL_DIRECTIONS)])
            blocks.append((rows_of(samples, d), np.full(len(samples), -np.inf), np.full(len(samples), float((corners @ d).max()))))

    counted = np.arange(first, last + 1)
    if ks is None:
        near(counted, 0)
    else:
        near(counted[counted <= ks[0]], 0)
        near(counted[counted > ks[1]], 1)
        near_either(counted[(counted > ks[0]) & (counted <= ks[1])])
    # the ends: at rest at the polyline's ends, or past the cuts
    bounds = np.full((2 * m, 2), [-np.inf, np.inf])
    start = (np.array(w.start) - origin) / unit
    end = (np.array(w.end) - origin) / unit
    if w.rest_start:
        for t in range(0, first + 1):
            bounds[2 * t], bounds[2 * t + 1] = start[0], start[1]
    else:
        u, _, a, _ = legs[0]
        blocks.append((rows_of(np.array([first]), u), np.array([a / unit]), np.array([a / unit + step])))
    if w.rest_end:
        for t in range(last, m):
            bounds[2 * t], bounds[2 * t + 1] = end[0], end[1]
    else:
        u, _, _, b = legs[-1]
        blocks.append((rows_of(np.array([last]), u), np.array([b / unit]), np.array([np.inf])))
    a_all = sparse.vstack([b[0] for b in blocks]).tocsr()
    lo_b = np.concatenate([b[1] for b in blocks])
    hi_b = np.concatenate([b[2] for b in blocks])
    upper, lower = np.isfinite(hi_b), np.isfinite(lo_b)
    a_ub = sparse.vstack([a_all[upper], -a_all[lower]]).tocsr()
    b_ub = np.concatenate([hi_b[upper], -lo_b[lower]])
    for method in ("highs-ds", "highs-ipm"):
        result = linprog(np.zeros(2 * m), A_ub=a_ub, b_ub=b_ub, bounds=bounds, method=method)
        if result.status in (0, 2):
            return result.status == 0
    print(f"corner bound: undecided, counted as feasible (the bound can only come out lower): {w}, N {n_periods}, "
          f"k in {ks}: {result.message}", file=sys.stderr)
    return True


# -- stretches of several legs, each at its own feed (a mixed-integer programme) --------------------
def stretch_ticks(points: list[tuple[float, float]], feeds: list[float], limits: Limits) -> int:
    """Servo periods no jerk-limited trajectory beats over a stretch of straight legs between two
    cuts, each leg at its own feed (`math.inf` for a rapid: its axes' speeds rule): from the first
    sample past the cut at `points[0]` to the first past the cut at `points[-1]`, the states at
    both cuts free (so it is a bound wherever the stretch lies in a longer trajectory).

    The windows above have one corner and one feed; a stretch such as a lead-out, the rapid to the
    next part and its lead-in (a rapid's ramps far longer than the leads, and its two corners
    within a ramp of each other) is one problem, not windows whose free cuts would let each half
    run at the top speed the other cannot reach. The same problem as the windows' (the axes'
    limits on backward differences, each sample within P of its leg, the feed's polygon), with the
    leg a sample lies near chosen by binaries (monotone: the legs in order) instead of by branch
    and bound, and a sample's speed kept to the feed of the leg it lies near. Same assumptions:
    forward only (no sample more than P behind the first cut), legs that come near each other
    refused (`check_apart`), a stretch runnable in N periods taken to be runnable in N + 1."""
    if len(feeds) != len(points) - 1:
        raise ValueError(f"stretch bound: {len(points) - 1} legs but {len(feeds)} feeds")
    top = [f if math.isfinite(f) else math.hypot(*limits.v_axis) for f in feeds]
    check_apart(list(points), Limits(limits.dt, limits.v_axis, limits.a_axis, limits.j_axis, max(top), limits.tolerance))
    length = sum(math.dist(a, b) for a, b in zip(points, points[1:]))
    step = max(top) * limits.dt / math.cos(math.pi / FEED_SIDES)
    lo = max(1, math.floor((length - 20.0 * limits.tolerance) / step) - 2)
    if _stretch_feasible(points, feeds, limits, lo):
        return lo
    hi = lo + 8
    while not _stretch_feasible(points, feeds, limits, hi):
        lo, hi = hi, hi + 2 * (hi - lo)
    while hi - lo > 1:  # lo infeasible, hi feasible
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if _stretch_feasible(points, feeds, limits, mid) else (mid, hi)
    return hi


def _stretch_feasible(points: list[tuple[float, float]], feeds: list[float], limits: Limits, n_periods: int) -> bool:
    """Whether the stretch can be run in `n_periods` (`stretch_solution`; a programme the solver
    leaves undecided counts as feasible: the bound can only come out lower)."""
    feasible, _ = stretch_solution(points, feeds, limits, n_periods)
    return feasible


def stretch_solution(points: list[tuple[float, float]], feeds: list[float], limits: Limits,
                     n_periods: int) -> tuple[bool, np.ndarray | None]:
    """Whether the stretch can be run in `n_periods`, and one such trajectory's samples (mm, an
    (N + 1, 2) array; None where it cannot or the solver left it undecided).

    Samples t = 0..N, positions in units of J dt^3 relative to the first point, and per switch i
    (between legs i - 1 and i) a binary s_i(t), 1 once sample t is past it: sample t lies near leg
    i where s_i(t) = 1 and s_(i+1)(t) = 0, each leg's rows lifted by a large M elsewhere."""
    dt, tol = limits.dt, limits.tolerance
    unit = min(limits.j_axis) * dt ** 3
    widen = 1.0 + SLACK
    origin = np.array(points[0], dtype=float)
    legs = []  # (u, n, along-from, along-to, across) in units, relative to the origin
    for a, b in zip(points, points[1:]):
        a_, b_ = (np.array(a, dtype=float) - origin) / unit, (np.array(b, dtype=float) - origin) / unit
        u = (b_ - a_) / np.linalg.norm(b_ - a_)
        n = np.array([-u[1], u[0]])
        legs.append((u, n, float(u @ a_), float(u @ b_), float(n @ a_)))
    n_legs, m = len(legs), n_periods + 1
    n_x = 2 * m
    n_var = n_x + (n_legs - 1) * m

    def switch(i: int, t: np.ndarray) -> np.ndarray:  # the variable of s_i(t), i = 1 .. n_legs - 1
        return n_x + (i - 1) * m + t

    def step_of(feed: float) -> float:
        top = feed if math.isfinite(feed) else math.hypot(*limits.v_axis)
        return top * dt / math.cos(math.pi / FEED_SIDES) / unit * widen

    s_tol = tol / unit
    reach = max(np.linalg.norm((np.array(p, dtype=float) - origin) / unit) for p in points) + s_tol + step_of(feeds[-1])
    big = 4.0 * reach  # no sample near its leg is further than `reach` from the origin
    big_v = 4.0 * math.hypot(*limits.v_axis) * dt / unit
    rows: list[sparse.spmatrix] = []
    lows: list[np.ndarray] = []
    highs: list[np.ndarray] = []

    def add(entries: list, low: np.ndarray | float, high: np.ndarray | float, count: int) -> None:
        """`count` rows low <= sum of coefficient * variable <= high, over `entries`: pairs of
        (variables, coefficients), each an array of one value per row or a scalar."""
        r = np.concatenate([np.arange(count)] * len(entries))
        c = np.concatenate([np.broadcast_to(var, (count,)) for var, _ in entries])
        v = np.concatenate([np.broadcast_to(coef, (count,)).astype(float) for _, coef in entries])
        rows.append(sparse.csr_matrix((v, (r, c)), shape=(count, n_var)))
        lows.append(np.broadcast_to(low, (count,)).astype(float))
        highs.append(np.broadcast_to(high, (count,)).astype(float))

    t = np.arange(m)
    for axis in (0, 1):  # the axes' limits: backward differences of order 1, 2, 3
        for order, per_axis in ((1, limits.v_axis), (2, limits.a_axis), (3, limits.j_axis)):
            bound = per_axis[axis] * dt ** order / unit * widen
            tt = t[order:]
            coefs = [math.comb(order, k) * (-1) ** k for k in range(order + 1)]
            add([(2 * (tt - k) + axis, np.full(len(tt), c)) for k, c in enumerate(coefs)], -bound, bound, len(tt))
    for i in range(1, n_legs):  # the legs in order: s_i(t) <= s_i(t + 1), s_(i+1)(t) <= s_i(t)
        add([(switch(i, t[:-1]), 1.0), (switch(i, t[1:]), -1.0)], -np.inf, 0.0, m - 1)
        if i + 1 < n_legs:
            add([(switch(i + 1, t), 1.0), (switch(i, t), -1.0)], -np.inf, 0.0, m)

    def relaxed(i: int, scale: float) -> tuple[list[tuple[np.ndarray, float]], float]:
        """Terms that lift a row of leg i by `scale` where sample t is not near it, and the constant part."""
        terms, const = [], 0.0
        if i > 0:
            terms.append((switch(i, t), -scale))  # + scale (1 - s_i)
            const += scale
        if i + 1 < n_legs:
            terms.append((switch(i + 1, t), scale))
        return terms, const

    angles = 2.0 * np.pi * np.arange(FEED_SIDES) / FEED_SIDES
    directions = [np.array([math.cos(q), math.sin(q)]) for q in angles]
    for i, (u, n, a, b, c) in enumerate(legs):
        b_hi = b + (step_of(feeds[-1]) if i == n_legs - 1 else s_tol)
        terms, const = relaxed(i, big)
        for d, low, high in ((n, c - s_tol, c + s_tol), (u, a - s_tol, b_hi)):
            p = [(2 * t, d[0]), (2 * t + 1, d[1])]
            add(p + [(var, -coef) for var, coef in terms], -np.inf, high + const, m)  # d.p <= high + lift
            add(p + terms, low - const, np.inf, m)  # d.p >= low - lift
        if math.isfinite(feeds[i]):  # the speed into a sample near leg i within its feed's polygon
            feed = feeds[i] * dt / unit * widen
            terms_v, const_v = relaxed(i, big_v)
            tt = t[1:]
            for d in [*directions, u]:
                add([(2 * tt, d[0]), (2 * tt + 1, d[1]), (2 * tt - 2, -d[0]), (2 * tt - 1, -d[1]),
                     *[(var[1:], -coef) for var, coef in terms_v]], -np.inf, feed + const_v, m - 1)
    # the cuts: the first sample within a period past the first, the last past the last
    u0, u1 = legs[0][0], legs[-1][0]
    add([(np.array([0]), u0[0]), (np.array([1]), u0[1])], legs[0][2], legs[0][2] + step_of(feeds[0]), 1)
    add([(np.array([2 * (m - 1)]), u1[0]), (np.array([2 * (m - 1) + 1]), u1[1])], legs[-1][3], np.inf, 1)
    lower, upper = np.full(n_var, -np.inf), np.full(n_var, np.inf)
    lower[n_x:], upper[n_x:] = 0.0, 1.0
    for i in range(1, n_legs):  # the first sample is near the first leg, the last near the last
        upper[switch(i, 0)], lower[switch(i, m - 1)] = 0.0, 1.0
    integrality = np.zeros(n_var)
    integrality[n_x:] = 1
    result = milp(np.zeros(n_var), constraints=LinearConstraint(sparse.vstack(rows).tocsr(), np.concatenate(lows),
                                                                np.concatenate(highs)),
                  integrality=integrality, bounds=Bounds(lower, upper))
    if result.status == 0:  # a feasible point found
        return True, result.x[:n_x].reshape(m, 2) * unit + origin
    if result.status == 2:  # infeasible
        return False, None
    print(f"stretch bound: undecided, counted as feasible (the bound can only come out lower): {points}, "
          f"N {n_periods}: {result.message}", file=sys.stderr)
    return True, None


def main() -> int:
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import linuxcnc_compare as lc
    from cnc.config import load_machine

    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    print(f"{'program':<28}{'window':>8}{'ticks':>8}{'cruise':>8}{'corner cost ms':>16}")
    for shape, points, origin in (("square 100", lc._square, (200.0, 200.0)), ("zigzag", lc._zigzag, (600.0, 400.0))):
        for feed in lc.CORNER_FEEDS:
            for p in lc.CORNER_TOLERANCES_MM:
                limits = lc.corner_limits(config, feed, p)
                total = 0
                polyline_bound_ticks(points(origin), limits, workers=len(os.sched_getaffinity(0)))  # every window, in parallel
                for k, w in enumerate(windows(points(origin), reach_for(limits))):
                    ticks = window_ticks(w, limits)
                    total += ticks
                    cruise = w.length_mm / limits.feed / limits.dt
                    print(f"{f'{shape} F{feed} P{p:g}':<28}{k:>8}{ticks:>8}{cruise:>8.0f}{ticks - cruise:>16.1f}")
                print(f"{f'{shape} F{feed} P{p:g}':<28}{'all':>8}{total:>8}  = {total * limits.dt:.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
