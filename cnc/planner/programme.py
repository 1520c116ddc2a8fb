"""Corners passed by a programmed connection: the samples through a gentle corner solved for at once.

Where two long straight moves meet at speed and turn gently (a polyline's 30 to 90 degree turns at
200 to 500 mm/s), neither an overlap (`overlap.py`) nor a connection of Ruckig's (`connection.py`)
passes the corner well: each axis's own time-optimal motion leaves the band of width 2 P around the
lines, so the planner keeps the corner short and slow. The jerk-limited optimum does something
else: it first drifts to the outside of the band, then crosses it through the corner, braking no
more than that needs (`bench/corner_programmed.py`, docs/benchmarks.md "Corners solved as linear
programmes"). A programmed connection finds such a path directly.

Between the same two samples a connection may join (the last section's sample n_a - p, the next
one's sample j, the widest window, `connection.corner_window`), it looks for the fewest servo
periods m and a path of m - 1 samples such that

- each axis keeps its velocity, acceleration and jerk limit, on the backward differences of the
  joined samples as the drives see them;
- every sample lies within P of one of the two programmed lines: the first ones of the incoming
  line, the rest of the outgoing one;
- the path speed keeps the corner's cap (`overlap._speed_cap`), in a polygon inscribed in its
  circle, sides facing the corner's directions (`FAN_DEG`).

The path is a uniform cubic spline of `SPAN`-period intervals through the two joins, its control
points the unknowns (about m / 2 of them, not 2 m). A difference of the samples of such a spline
is a weighted mean of its derivative between them, and each derivative lies in the hull of its
control polygon, so the limits and the speed are kept on the control polygon (a few rows an
interval); the differences across the joins, where the sections' own samples take part, and the
tolerance are kept on the samples themselves. For a given m that is a linear programme, solved by
HiGHS (`scipy.optimize.milp` without integers); m by bisection, from the straight line at the cap
to `[planner] corner_programme_ms`, the switch between the lines where the last feasible programme
put it (at first: the share of the window before the corner); at most `PROGRAMMES` programmes a
corner and `ITERATIONS` simplex iterations per row and column a programme (one that reaches them is
infeasible), counts, so that every solve of the same corner ends alike and none runs for ever. Each limit is kept
`LP_MARGIN` inside the connection's own check, which checks the result again
(`connection._Search.keeps_rules`) before it counts.

A corner is programmed only where

- both sides are single straight moves (lines or rapids), long enough that the window is the
  widest whatever the corner before took of the last one (`window`): then the programme depends on
  the two sections alone, not on the corners before it, and it can be solved ahead;
- a connection is searched there at all (`CornerOverlap.plan`: the axis limits, not P or the feed,
  held the overlap short).

`CornerOverlap.plan` takes it where it saves more than the overlap and the connection. Solving a
corner takes tens of milliseconds (about 7 programmes of 4-6 ms), more than the FIFO's slack, so
the planner's worker thread solves the corners ahead of the motion, on sections of its own
(`ProgrammeBook.solve_ahead`), and the refill takes the result; a corner the worker has not
reached is left undecided while the refill can wait, and passed by the planner's own plan if the
worker is still not there when it must be decided (the refill never solves one: a FIFO run dry
trips the servo), as is one the motion reaches replanned since it was solved (a hold, a resume,
an override change). Without a worker (tests, benches) a corner is solved where it is needed. The
program's timing (`steps.ProgramTiming`) solves every one where it meets it: the same programmes
from the same samples, so the planned cycle time stays the run's. A corner met again (a nest's parts, the same lead-in after each rapid) is taken
from the first one, moved there and checked again (`ProgrammeMemo`, one per walk of the
program). Under way a programmed connection is committed like any connection: a hold, a stop or
an override change made during one acts when it ends, at most `corner_programme_ms` later (the
servo's own stop on a fault does not wait: it brakes along the queued samples, `cnc/brake.py`).
"""

from __future__ import annotations

import math
import threading
from typing import TYPE_CHECKING

import numpy as np

from gcode.canon import LINE, RAPID

from .connection import JOIN_SAMPLES, CornerPlan, _Corner, _Search, corner_window

from .sections import Section
from .stream import SectionStream

if TYPE_CHECKING:  # (overlap.py imports this module)
    from scipy import sparse

    from .overlap import CornerOverlap


def load_solver() -> tuple:
    """HiGHS through scipy (`milp`, `LinearConstraint`), imported when first needed: scipy's
    optimiser takes a third of a second to import, which `waterjet check` of a program without a
    programmed corner need not pay. The planner process loads it at its start (`process.py`), so
    that the worker's first corner is not late for it.

    scipy's `milp` hands options it does not know itself to HiGHS as they are, saying so in a
    warning each call: the one it is given here (`ITERATIONS`) is meant, so that warning is not
    shown."""
    import warnings

    from scipy.optimize import LinearConstraint, milp

    warnings.filterwarnings("ignore", message=UNKNOWN_OPTION_WARNING, category=RuntimeWarning)
    return milp, LinearConstraint


SPAN = 4  # servo periods per interval of the spline
LP_MARGIN = 1e-6  # each limit kept this share inside its check's (`connection._Search.keeps_rules`)
SPEED_SIDES = 8  # corners of the speed's polygon all round, besides those along the joins' steps and between
TURN_STEP_DEG = 10.0  # ... which are this far apart at most
FAN_DEG = 45.0  # sides of the speed's polygon kept: those facing within this of the corner's directions
PROGRAMMES = 16  # linear programmes at most per corner (a count: every solve of the corner ends alike)
ITERATIONS = 10  # simplex iterations at most per programme, times its rows and columns: a badly scaled one
# (a slow axis's jerk at a fast servo period: coefficients down to 1e-10) can make HiGHS's simplex cycle for
# ever; one that reaches the limit counts as infeasible, alike in every solve (a count, not a time). The
# programmes of the tests take at most 1.9 times their rows and columns
UNKNOWN_OPTION_WARNING = r"Unrecognized options detected: \{'simplex_iteration_limit'\}"
KEY_MM = 1e-9  # corners whose samples agree to this, relative to the corner, are the same corner (`ProgrammeMemo`)
MEMO_SIZE = 4096  # corners a memo remembers (the oldest forgotten first)


def window(corners: "CornerOverlap", a: SectionStream, b: SectionStream) -> tuple[_Corner, int, int] | None:
    """The widest window a connection at the corner a -> b may join (`connection.corner_window`),
    where that corner may be programmed: two single straight moves, the last long enough that no
    corner before it can narrow the window (so the programme depends on a and b alone). `a` is
    planned to its end."""
    if corners.programme_samples < 1 or not (_straight(a.section) and _straight(b.section)):
        return None
    reach = corners.connection_reach
    longest_summed = max(corners.max_samples, reach + JOIN_SAMPLES)  # the most a corner before takes of a
    if a.k_end is None or int(a.k_end) - longest_summed - corners.context - 2 < reach:
        return None
    found = corner_window(corners, a, b, longest_summed)
    if found is None:
        return None
    corner, most_p, most_j = found
    if most_p != reach or most_j != reach or len(corner.near) != 2:
        return None
    return found


def _straight(section: Section) -> bool:
    return len(section.elements) == 1 and section.elements[0].kind in (LINE, RAPID)


def programmed_plan(corners: "CornerOverlap", corner: _Corner, p: int, j: int, memo: "ProgrammeMemo") -> CornerPlan | None:
    """The programmed connection from the last section's sample n_a - p to the next one's sample j
    that takes the fewest periods (at most `corners.programme_samples` + 1), if one keeps every rule;
    None where none does. A corner `memo` has met before is not solved again."""
    if any(e.kind not in (LINE, RAPID) or e.length_mm <= 0.0 for e in corner.near):
        return None
    origin = corner.tail[-1].copy()
    key = _key(corners, corner, p, j)
    known = memo.get(key)
    if known is not None:
        m, relative = known
        if relative is None:
            return None
        path = relative + origin
        if _Search(corners, corner).keeps_rules(p, j, path):
            return CornerPlan(p + j - m, p, j - 1, path)
    plan = _solved(corners, corner, p, j)
    memo.put(key, (0, None) if plan is None else (p + j - plan.saved, plan.path - origin))
    return plan


class ProgrammeMemo:
    """The corners one walk of a program has solved (the run's, or its timing's), by what their
    programme depends on to `KEY_MM` (`_key`): a nest's parts meet the same corners again and again.
    Each walk keeps its own and meets the corners in the program's order, so the run and its timing
    take a corner met again from the same first one."""

    def __init__(self) -> None:
        self._known: dict[bytes, tuple[int, np.ndarray | None]] = {}
        self._lock = threading.Lock()  # the planner's worker and its refill may both solve

    def get(self, key: bytes) -> tuple[int, np.ndarray | None] | None:
        with self._lock:
            return self._known.get(key)

    def put(self, key: bytes, value: tuple[int, np.ndarray | None]) -> None:
        with self._lock:
            self._known[key] = value
            while len(self._known) > MEMO_SIZE:
                del self._known[next(iter(self._known))]  # the oldest


def _key(corners: "CornerOverlap", corner: _Corner, p: int, j: int) -> bytes:
    """What a corner's programme depends on, relative to the corner and to `KEY_MM`: the joined
    samples, the lines, the cap and P, the limits and the window."""
    origin = corner.tail[-1]
    lines = np.array([[*e.start[:3], *e.end[:3]] for e in corner.near]) - np.tile(origin, 2)
    numbers = np.concatenate((corner.tail.ravel() - np.tile(origin, len(corner.tail)),
                              corner.head.ravel() - np.tile(origin, len(corner.head)), lines.ravel()))
    limits = (corner.cap_mm_s, corner.tolerance_mm, p, j, corners.dt, corners.programme_samples,
              *corners.velocity, *corners.accel, *corners.jerk)
    return np.round(numbers / KEY_MM).astype(np.int64).tobytes() + np.array(limits, dtype=float).tobytes()


def _solved(corners: "CornerOverlap", corner: _Corner, p: int, j: int) -> CornerPlan | None:
    problem = _Programme(corners, corner, len(corner.tail) - 1 - p, j)
    found = fewest(problem, problem.fewest_periods(), min(corners.programme_samples + 1, p + j - 1), PROGRAMMES)
    if found is None:
        return None
    m, path = found
    if not _Search(corners, corner).keeps_rules(p, j, path):
        return None
    return CornerPlan(p + j - m, p, j - 1, path)  # a connection of m periods saves p + j - m


def fewest(problem, lo: int, hi: int, most: int) -> tuple[int, np.ndarray] | None:  # noqa: ANN001 - has solve(m), count
    """The fewest periods m in lo..hi for which `problem.solve(m)` finds a path, and that path, by
    bisection (hi first: None where even it has none), until `problem.count` reaches `most`."""
    if hi < lo:
        return None
    best = problem.solve(hi)
    if best is None:
        return None
    while hi > lo and problem.count < most:  # hi feasible; lo - 1 infeasible
        mid = (lo + hi) // 2
        path = problem.solve(mid)
        if path is not None:
            hi, best = mid, path
        else:
            lo = mid + 1
    return hi, best


def fewest_periods(corners: "CornerOverlap", corner: _Corner, before: np.ndarray, after: np.ndarray) -> int:
    """No connection from the sample `before[-1]` to `after[0]` (X, Y) takes fewer periods: the
    straight line between them at the corner's cap, or at the axes' velocities."""
    gap = after[0] - before[-1]
    steps = [abs(gap[a]) / (corners.velocity[a] * corners.dt) for a in range(2)]
    if math.isfinite(corner.cap_mm_s):
        steps.append(float(np.hypot(*gap)) / (corner.cap_mm_s * corners.dt))
    return max(2, math.ceil(max(steps) - 1e-9))


def speed_sides(step_in: np.ndarray, step_out: np.ndarray, fan_deg: float = 180.0) -> list[tuple[float, float]]:
    """The sides (from and to angle, radians) of a polygon inscribed in the speed's circle, with
    corners all round (`SPEED_SIDES`) and along both joins' steps and between them (every
    `TURN_STEP_DEG` at most, the shorter way round); only those facing within `fan_deg` of the
    two steps' directions or of the way between them."""
    q_in, q_out = (math.atan2(d[1], d[0]) % (2.0 * math.pi) for d in (step_in, step_out))
    turn = (q_out - q_in + math.pi) % (2.0 * math.pi) - math.pi  # signed, the shorter way round
    fine = max(1, math.ceil(abs(turn) / math.radians(TURN_STEP_DEG)))
    corners_at = sorted({2.0 * math.pi * q / SPEED_SIDES for q in range(SPEED_SIDES)}
                        | {(q_in + turn * q / fine) % (2.0 * math.pi) for q in range(fine + 1)})
    fan = math.radians(fan_deg)
    sides = []
    for q0, q1 in zip(corners_at, corners_at[1:] + [corners_at[0] + 2.0 * math.pi]):
        mid = (q0 + q1) / 2.0
        facing = min(abs((mid - r + math.pi) % (2.0 * math.pi) - math.pi) for r in (q_in, q_out, q_in + turn / 2.0))
        if q1 - q0 > 1e-12 and facing <= fan:
            sides.append((q0, q1))
    return sides


def _basis(m: int, intervals: int) -> np.ndarray:
    """The uniform cubic B-spline's `intervals` + 3 basis functions over [0, m dt] cut into
    `intervals` equal intervals, at the times 0, dt, ..., m dt: (m + 1, intervals + 3)."""
    t = np.arange(m + 1) * intervals / m  # in intervals
    i = np.minimum(np.floor(t).astype(int), intervals - 1)
    u = t - i
    b = np.zeros((m + 1, intervals + 3))
    rows = np.arange(m + 1)
    b[rows, i] = (1.0 - u) ** 3 / 6.0
    b[rows, i + 1] = (3.0 * u ** 3 - 6.0 * u ** 2 + 4.0) / 6.0
    b[rows, i + 2] = (-3.0 * u ** 3 + 3.0 * u ** 2 + 3.0 * u + 1.0) / 6.0
    b[rows, i + 3] = u ** 3 / 6.0
    return b


def _differences(order: int, count: int, width: int) -> np.ndarray:
    """`count` rows of the order-th forward difference over `width` columns."""
    out = np.zeros((count, width))
    rows = np.arange(count)
    for q in range(order + 1):
        out[rows, rows + q] = math.comb(order, q) * (-1) ** (order - q)
    return out


class _Programme:
    """The linear programmes of one corner's window, for any number of periods m."""

    def __init__(self, corners: "CornerOverlap", corner: _Corner, i: int, j: int) -> None:
        self.corners, self.corner = corners, corner
        self.dt = corners.dt
        ctx = corners.context
        self.origin = corner.tail[-1, :2].copy()  # the corner: the numbers near zero
        self.before = corner.tail[max(0, i - ctx):i + 1, :2] - self.origin
        self.after = corner.head[j:j + ctx + 1, :2] - self.origin
        self.normals = []  # (normal, offset) of each programmed line, relative to the origin
        for e in corner.near:
            s, t = np.array(e.start[:2]) - self.origin, np.array(e.end[:2]) - self.origin
            u = (t - s) / np.linalg.norm(t - s)
            n = np.array([-u[1], u[0]])
            self.normals.append((n, float(n @ s)))
        self.share = (len(corner.tail) - 1 - i) / (len(corner.tail) - 1 - i + j)  # of the window before the corner
        self.count = 0  # programmes solved

    def fewest_periods(self) -> int:
        return fewest_periods(self.corners, self.corner, self.before, self.after)

    def solve(self, m: int) -> np.ndarray | None:
        """The connection's m - 1 samples (X, Y, Z) if the programme for m periods is feasible with
        the switch between the lines where the last feasible one had it; else None."""
        self.count += 1
        n = m - 1
        k = min(max(round(self.share * n), 0), n)
        a, low, high, samples = self._rows(m, k)
        milp, constraint = load_solver()
        result = milp(np.zeros(a.shape[1]), constraints=constraint(a, low, high), bounds=(-np.inf, np.inf),
                      options={"simplex_iteration_limit": int(ITERATIONS * sum(a.shape))})
        if result.status != 0:  # infeasible, or the iteration limit reached
            return None
        self.share = k / n if n else 0.0
        nc = samples.shape[1]
        path = np.repeat(self.corner.tail[-1:], n, axis=0)  # Z as at the corner (the corner is flat)
        path[:, 0] = samples @ result.x[:nc] + self.origin[0]
        path[:, 1] = samples @ result.x[nc:] + self.origin[1]
        return path

    def _rows(self, m: int, k: int) -> tuple[sparse.csr_matrix, np.ndarray, np.ndarray, np.ndarray]:
        """The programme for m periods, samples before k near the incoming line: its rows over the
        control points (X's, then Y's), their bounds, and the unknown samples' basis rows."""
        n = m - 1
        intervals = max(1, round(m / SPAN))
        basis = _basis(m, intervals)
        h = m * self.dt / intervals
        nc = intervals + 3
        nb, na = len(self.before), len(self.after)
        margin = 1.0 - LP_MARGIN
        blocks: list[np.ndarray] = []
        lows: list[np.ndarray] = []
        highs: list[np.ndarray] = []

        def add(rows: np.ndarray, low, high) -> None:  # noqa: ANN001 - bounds: numbers or arrays
            blocks.append(rows)
            lows.append(np.broadcast_to(np.asarray(low, dtype=float), len(rows)))
            highs.append(np.broadcast_to(np.asarray(high, dtype=float), len(rows)))

        def on_axis(rows: np.ndarray, axis: int) -> np.ndarray:
            out = np.zeros((len(rows), 2 * nc))
            out[:, axis * nc:(axis + 1) * nc] = rows
            return out

        # the sequence of joined samples: the last section's, the unknowns', the next one's
        total = nb + n + na
        seq_rows = np.zeros((total, nc))
        seq_rows[nb:nb + n] = basis[1:m]
        for axis in range(2):
            fixed = np.concatenate((self.before[:, axis], np.zeros(n), self.after[:, axis]))
            ends = np.array([self.before[-1, axis], self.after[0, axis]])
            add(on_axis(basis[[0, m]], axis), ends, ends)  # the spline through both joins
            for order, limit in ((1, self.corners.velocity[axis]), (2, self.corners.accel[axis]),
                                 (3, self.corners.jerk[axis])):
                if not math.isfinite(limit):
                    continue
                # the spline's own derivative, on its control polygon (accelerations at the knots,
                # the jerk of each interval)
                count = {1: nc - 1, 2: intervals + 1, 3: intervals}[order]
                bound = limit * h ** order * margin
                add(on_axis(_differences(order, count, nc), axis), -bound, bound)
                # the differences across the joins, where the sections' own samples take part
                ends_at = [t for t in (*range(nb, nb + order - 1), *range(nb + n + 1, nb + n + order))
                           if order <= t < total]
                if ends_at:
                    d = _differences(order, total - order, total)[[t - order for t in ends_at]]
                    step = limit * self.dt ** order * margin
                    const = d @ fixed
                    add(on_axis(d @ seq_rows, axis), -step - const, step - const)
        cap = self.corner.cap_mm_s
        if math.isfinite(cap):
            diff = _differences(1, nc - 1, nc)
            for q0, q1 in speed_sides(self.before[-1] - self.before[-2], self.after[1] - self.after[0], FAN_DEG):
                mid = (q0 + q1) / 2.0
                reach = cap * h * margin * math.cos((q1 - q0) / 2.0)  # on differences of control points
                add(np.hstack((math.cos(mid) * diff, math.sin(mid) * diff)), -np.inf, reach)
        tol = self.corner.tolerance_mm * margin
        samples = basis[1:m]
        for (normal, offset), rows in ((self.normals[0], samples[:k]), (self.normals[1], samples[k:])):
            if len(rows):
                add(np.hstack((normal[0] * rows, normal[1] * rows)), offset - tol, offset + tol)
        from scipy import sparse  # loaded with the solver (`load_solver`)

        a = sparse.csr_matrix(np.vstack(blocks))
        return a, np.concatenate(lows), np.concatenate(highs), samples


class ProgrammeBook:
    """Programmed connections solved ahead of the motion, by corner (the index of the step before
    it): the override and the window each was solved for, and its plan (None: the corner has none).
    The planner's worker fills it (`solve_ahead`); the refill reads it (`plan`)."""

    def __init__(self) -> None:
        self._solved: dict[int, tuple[float, np.ndarray, np.ndarray, CornerPlan | None]] = {}
        self._lock = threading.Lock()
        self.memo = ProgrammeMemo()
        self.solves_late = True  # a corner not solved ahead is solved where it is needed (no worker: tests, timing)
        self.solved_here = 0  # corners solved where they were needed (figures for tests and benches)
        self.late = 0  # corners the worker had not solved when needed, passed by the planner's own plan

    def plan(self, corners: "CornerOverlap", index: int, corner: _Corner, p: int, j: int) -> CornerPlan | None:
        """The programmed connection of the corner after step `index` for this window: the one
        solved ahead for the same samples; None where it was solved for other samples (the motion
        was replanned since: a hold, a resume, an override change), and the planner's own plan
        passes the corner. One not solved ahead is solved now where `solves_late`; where a worker
        solves them (`solves_late` False) the refill never does (tens of milliseconds against the
        FIFO's slack of 20: a FIFO run dry trips the servo), and the planner's own plan passes it."""
        with self._lock:
            known = self._solved.get(index)
        if known is None:
            if not self.solves_late:
                self.late += 1
                return None
            self.solved_here += 1
            return programmed_plan(corners, corner, p, j, self.memo)
        _, tail, head, plan = known
        return plan if np.array_equal(tail, corner.tail) and np.array_equal(head, corner.head) else None

    def solved(self, index: int, override: float) -> bool:
        """Whether the corner after step `index` is solved for this override."""
        with self._lock:
            known = self._solved.get(index)
        return known is not None and known[0] == override

    def solve_ahead(self, corners: "CornerOverlap", index: int, a: Section, b: Section, override: float) -> bool:
        """Solve the corner between the steps `index` and `index + 1` (sections a and b) on
        sections planned here, as the run plans them at `override`. Whether there was a programme
        to solve (a qualifying corner), not merely a corner to mark."""
        plan: CornerPlan | None = None
        tail = head = np.zeros((0, 3))
        solved = False
        if override > 0.0 and corners.applies(a, b) and _straight(a) and _straight(b):
            sa, sb = SectionStream(a, override, min(override, 1.0)), SectionStream(b, override, min(override, 1.0))
            sa.planned_samples()
            _, could_grow = corners.overlap_held(sa, sb)
            found = window(corners, sa, sb) if could_grow else None
            if found is not None:
                corner, p, j = found
                tail, head = corner.tail, corner.head
                plan = programmed_plan(corners, corner, p, j, self.memo)
                solved = True
        with self._lock:
            self._solved[index] = (override, tail, head, plan)
        return solved

    def mark(self, index: int, override: float) -> None:
        """Note that there is no corner after step `index` to solve (a pause follows, or precedes)."""
        with self._lock:
            self._solved[index] = (override, np.zeros((0, 3)), np.zeros((0, 3)), None)

    def forget_before(self, index: int) -> None:
        """Drop the corners before step `index`: the head has passed them."""
        with self._lock:
            for i in [i for i in self._solved if i < index]:
                del self._solved[i]
