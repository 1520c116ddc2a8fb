"""One section's motion, streamed one servo period at a time, with override, hold and resume.

Planning looks ahead over a window of path long enough to stop from the fastest speed
(several braking distances): the raw profile (`profile.py`) is planned over the window as
if the motion had to stop at its end, and only its first part is committed, so what is
committed never depends on that assumed stop. Samples are then taken from the committed
pieces at the servo period and pass through the two moving averages (`limits.py` says why):
over the arc length (jerk along the path) and over the axis positions (curvature steps).

A change of feed override, or a hold, replans from the last sample made: the raw profile
continues from that sample's position, speed and acceleration history, and the averages'
memories carry on, so the setpoints stay continuous to the jerk. A hold is an override of
zero that also takes in rapids; the head stops on the path and resumes from exactly there.
"""

from __future__ import annotations

import math

import numpy as np

from dataclasses import dataclass

from .profile import Pieces, Zones, braking_distance, plan
from .sections import REST_SAMPLES, Section
from .smoothing import MovingAverage

@dataclass
class WindowJob:
    """One look-ahead window to plan: a pure computation from the committed end state, so it may
    run away from the stream (the planner's worker thread) and be accepted afterwards."""

    stream: "SectionStream"
    generation: int
    start: tuple[float, float, float, float, float]  # s, v, last acceleration, cruised since, time
    end_mm: float
    holding: bool
    override: float
    rapid_override: float
    over_feed: bool
    pieces: Pieces | None = None

    def compute(self) -> None:
        s, v, a_prev, cruised, t0 = self.start
        zones = self.stream.zones(s, self.end_mm, self.holding, self.override, self.rapid_override, self.over_feed)
        self.pieces = plan(zones, s, v, a_prev, 0.0, self.stream.plateau_s, t0, cruised)


WINDOWS_PER_COMMIT = 2.0  # the window reaches this many commit lengths beyond what is committed


class SectionStream:
    """Samples of one section's motion, from rest at its start to rest at its end."""

    def __init__(self, section: Section, override: float = 1.0, rapid_override: float = 1.0) -> None:
        self.section = section
        lim = section.limits
        sm = lim.smoothing
        self.dt = sm.dt
        self.plateau_s = sm.plateau_s
        self.reach_s = sm.extension_s
        self.length = section.length_mm
        v_top = lim.v_max_any
        a_low = float(lim.accel.min())
        self.brake_mm = braking_distance(v_top, a_low, self.plateau_s) + 2.0 * v_top * self.reach_s + 1.0
        self.commit_mm = WINDOWS_PER_COMMIT * self.brake_mm
        self.window_mm = self.commit_mm + 2.0 * self.brake_mm
        self.override, self.rapid_override = override, rapid_override
        # planned with the accelerations of a motion that may run over its feeds from the first
        # override above 100 % on (`SectionLimits.accel_for`); sticky for the section
        self.over_feed = override > 1.0
        self._raise: tuple[int, float] | None = None  # (sample, override): a raise over 100 % still to apply
        self.holding = False
        self.generation = 0  # +1 at every replan: a window planned before it is stale
        self.pieces = Pieces.empty()
        self.final = False  # the committed pieces reach the end of the section
        self.k = 0  # samples made so far; sample k is at time k * dt
        self.n_path, self.n_axis = sm.n_path, sm.n_axis
        self._ma_path: MovingAverage | None = None  # made at the first sample (`planned_samples` needs none)
        self._ma_axis: MovingAverage | None = None
        self.centre_lag = (sm.n_axis - 1) // 2
        self.s_recent = np.zeros(self.centre_lag)
        self.k_end: int | None = None

    @property
    def ma_path(self) -> MovingAverage:
        """The average over the arc length, from rest at the section's start."""
        if self._ma_path is None:
            self._ma_path = MovingAverage(self.n_path, 0.0)
        return self._ma_path

    @property
    def ma_axis(self) -> MovingAverage:
        """The average over the axis positions, from rest at the section's start."""
        if self._ma_axis is None:
            self._ma_axis = MovingAverage(self.n_axis, self.section.path.points(np.zeros(1))[0])
        return self._ma_axis

    # -- what the outside asks --------------------------------------------------------------
    @property
    def done(self) -> bool:
        """Every sample of the section has been made (the last one at rest at its end)."""
        return self.k_end is not None and self.k >= self.k_end

    @property
    def stopping(self) -> bool:
        """Held, or the feed override at zero: the motion comes to rest and stays there."""
        return self.holding or self.override <= 0.0

    @property
    def at_rest(self) -> bool:
        """Stopping and come to rest: the raw motion stopped, both averages have caught up, and
        `REST_SAMPLES` samples at rest have been made after (as at a section's end), so that a
        resume or a raised override right away never meets the stop in one third difference."""
        if not self.stopping or not self.pieces_end_at_rest():
            return False
        if len(self.pieces) and self.k < self._settled_k():
            return False
        s_stop = self.pieces.end_state()[0] if len(self.pieces) else 0.0
        return self.ma_path.converged(s_stop) and self.ma_axis.converged(self.section.path.points(np.array([s_stop]))[0], 1e-12)

    def pieces_end_at_rest(self) -> bool:
        return len(self.pieces) == 0 or abs(self.pieces.end_state()[1]) < 1e-9

    def set_override(self, feed: float, rapid: float) -> None:
        """New feed and rapid override ratios (0..2 and 0..1), taking effect from the next sample.

        A section planned for its feeds (no override above 100 % since it began) brakes on its
        curves harder than one that may run over them (`SectionLimits.accel_for`). The first raise
        over 100 % in it therefore takes effect in steps: up to 100 % at once; then, at the next
        sample, the section is planned again with the accelerations of a motion over its feeds
        where that can still stop in time (braking at the lower acceleration near its end or a
        slower stretch may not: it is tried again every `raise_after_samples`); and the rest of the
        raise once the averages no longer mix in a sample of the motion planned before, whose arc
        kept its turning within the jerk budget only up to its feed. (Replanned, a section planned
        to its end has its corner overlap decided again, as at any override change.) A section that
        ends first leaves the raise to the next one, which starts with it."""
        if feed > 1.0 and (not self.over_feed or self._raise is not None):
            self._raise = (self._raise[0] if self._raise is not None else self.k, feed)
            feed = 1.0
        else:
            self._raise = None
        self.override, self.rapid_override = feed, rapid
        if not self.holding:
            self._replan()

    def leave_raise(self) -> None:
        """Take no further step of a raise over 100 % (`set_override`) in this section: its last
        samples are committed to a corner (`runner.py`), and the next section starts with the raise."""
        self._raise = None

    def raise_after_samples(self) -> int:
        """How long the rest of a first raise over 100 % waits after the section is planned for it
        (`set_override`): until no average mixes in a sample of the motion planned before
        (`Smoothing.extension_s`)."""
        return self.n_path + self.n_axis + 3

    def _raise_due(self) -> None:
        """The next step of a raise over 100 % (`set_override`) whose sample has come."""
        if self._raise is None or self.k < self._raise[0] or self.holding:
            return
        feed = self._raise[1]
        if not self.over_feed:
            if self._stops_in_time_over_feed():
                self.over_feed = True
                self._replan()
            self._raise = (self.k + self.raise_after_samples(), feed)  # the rest, or another try
            return
        self._raise = None
        self.override = feed
        self._replan()

    def _stops_in_time_over_feed(self) -> bool:
        """Whether the motion from the last sample made, planned with the accelerations of a
        motion over its feeds, still comes to rest within its window (`plan` assumes a stop at a
        window's end: from a speed the lower acceleration cannot brake in time, it does not)."""
        start = self._state_at_last_sample()
        job = WindowJob(self, self.generation, start, min(start[0] + self.window_mm, self.length),
                        self.holding, self.override, self.rapid_override, True)
        job.compute()
        return not len(job.pieces) or abs(job.pieces.end_state()[1]) < 1e-9

    def hold(self) -> None:
        """Decelerate along the path to a stop, as hard as the limits allow."""
        self.holding = True
        self._replan()

    def resume(self) -> None:
        """Continue from where the hold stopped (or is stopping)."""
        self.holding = False
        self._replan()

    def take(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The next n samples (fewer at the end, or while held at rest): positions (m, 3) and the
        arc length of each (where the head is on the section, for flags and progress)."""
        self._raise_due()
        due = self._raise[0] if self._raise is not None else None
        if due is not None and self.k < due < self.k + n:  # a raise's next step comes due among them
            y, s = self.take(due - self.k)
            if self.k < due:
                return y, s  # fewer came (the end, or held at rest)
            y_rest, s_rest = self.take(n - len(s))
            return np.concatenate((y, y_rest)), np.concatenate((s, s_rest))
        self._cover((self.k + n) * self.dt)
        if self.k_end is not None:
            n = min(n, self.k_end - self.k)
        if n <= 0:
            return np.zeros((0, 3)), np.zeros(0)
        t = (self.k + 1 + np.arange(n)) * self.dt
        if self.stopping and self.k * self.dt >= self.pieces.t_end and self.at_rest:
            return np.zeros((0, 3)), np.zeros(0)
        s_raw = self._raw(t)
        s_path = self.ma_path.push(s_raw)
        q = self.section.path.points(s_path)
        y = self.ma_axis.push(q)
        joined = np.concatenate((self.s_recent, s_path))
        centre = joined[: len(s_path)] if self.centre_lag else s_path
        self.s_recent = joined[len(joined) - self.centre_lag:] if self.centre_lag else self.s_recent
        self.k += n
        return y, centre

    def window_job(self, lead_s: float) -> WindowJob | None:
        """The next window to plan ahead so that committed motion reaches `lead_s` past the last
        sample made (None when it does, or when nothing may be planned ahead now). Planned
        ahead, a window is not planned while the FIFO drains, in `take`."""
        if self.stopping or self.final or (len(self.pieces) and self.pieces.t_end >= self.k * self.dt + lead_s):
            return None
        return self._job()

    def accept(self, job: WindowJob) -> bool:
        """Commit a window planned ahead, unless a replan or another commit made it stale."""
        if job.generation != self.generation or job.start != self._plan_start() or self.final:
            return False
        self._take_window(job)
        return True

    def plan_until(self, k: int) -> None:
        """Commit the pieces sample k needs (`take` does so for its samples), so that whether they
        reach the section's end (`final`) is known before they are taken."""
        self._cover(k * self.dt)

    def positions(self, first: int, last: int) -> tuple[np.ndarray, float, float]:
        """Samples first..last (1 is the first `take` gives) computed from the pieces, not streamed:
        the same averages over the raw arc length and the axis positions (to rounding), without
        their memories, so any stretch can be had at any time (`overlap.py` checks a corner's
        samples so). Plans ahead as far as they need. Also the lowest and highest raw arc length
        they come from."""
        self._cover(last * self.dt)
        first_raw = first - self.n_path - self.n_axis + 2  # the earliest raw sample the averages reach
        t = np.maximum(np.arange(first_raw, last + 1), 0) * self.dt
        s_raw = self._raw(t)
        s_path = _window_means(s_raw, self.n_path)
        q = self.section.path.points(s_path)
        return _window_means(q - q[0], self.n_axis) + q[0], float(s_raw[0]), float(s_raw[-1])

    def planned_samples(self) -> int:
        """Plan the whole section without sampling it; how many samples it takes (what `take` will give)."""
        self._cover(math.inf)
        return self.k_end

    # -- planning ---------------------------------------------------------------------------
    def _cover(self, t: float) -> None:
        """Commit pieces until they reach time t or the end of the section."""
        while not self.final and (not len(self.pieces) or self.pieces.t_end < t):
            if self.stopping and (not len(self.pieces) or self.pieces_end_at_rest()):
                return  # held (or at 0 % before it began): at rest, and staying there until resumed
            s, v, a_prev, cruised, t0 = self._plan_start()
            self._commit(s, v, a_prev, cruised, t0)

    def _plan_start(self) -> tuple[float, float, float, float, float]:
        if not len(self.pieces):
            return 0.0, 0.0, 0.0, 0.0, 0.0
        s, v, _ = self.pieces.end_state()
        a_prev, cruised = self._history(self.pieces.t_end)
        return s, v, a_prev, cruised, self.pieces.t_end

    def _history(self, t: float) -> tuple[float, float]:
        """The last non-zero acceleration before time t and how long the motion has cruised since."""
        p = self.pieces
        for i in range(len(p) - 1, -1, -1):
            if p.t0[i] >= t:
                continue
            if p.a[i] != 0.0:
                end = min(p.t0[i] + p.duration[i], t)
                return float(p.a[i]), max(t - end, 0.0)
        return 0.0, 0.0

    def _job(self, start: tuple | None = None) -> WindowJob:
        start = start or self._plan_start()
        end = min(start[0] + self.window_mm, self.length)
        return WindowJob(self, self.generation, start, end, self.holding, self.override, self.rapid_override,
                         self.over_feed)

    def _commit(self, s: float, v: float, a_prev: float, cruised: float, t0: float) -> None:
        job = self._job((s, v, a_prev, cruised, t0))
        job.compute()
        self._take_window(job)

    def _take_window(self, job: WindowJob) -> None:
        """Commit a planned window: all of it at the end of the section or when stopping, else its first part."""
        pieces, (s, v, _, _, _), end = job.pieces, job.start, job.end_mm
        reaches_end = end >= self.length - 1e-9
        if not reaches_end and not self.stopping:
            pieces = pieces.until(_time_at(pieces, s + self.commit_mm))
        if not len(pieces):
            if v <= 1e-9 and s >= self.length - 1e-9 and not self.stopping:
                self._end_here()  # come to rest at the very end (a stop at 0 % that ended there): done
                return
            if self.stopping and v <= 1e-9:
                return  # at rest, and to stay there
            raise RuntimeError(f"section planning made no progress at s={s:.6f} mm (v={v:.6f} mm/s)")
        self.pieces = self.pieces.append(pieces)
        s_last, v_last, _ = self.pieces.end_state()
        if reaches_end and s_last >= self.length - 1e-9 and v_last <= 1e-9:
            self._end_here()
        else:
            self.final = False

    def _end_here(self) -> None:
        """The committed pieces end at rest at the section's end: the samples after them settle there."""
        self.final = True
        self.k_end = max(self._settled_k(), self.k)

    def _settled_k(self) -> int:
        """The sample by which motion that ends with the committed pieces has settled: both averages
        caught up, and `REST_SAMPLES` samples at rest made after."""
        return int(math.ceil(self.pieces.t_end / self.dt - 1e-9)) + self.n_path + self.n_axis - 2 + REST_SAMPLES

    def _replan(self) -> None:
        """Drop what is committed after the last sample made and plan again from there."""
        self.generation += 1
        t = self.k * self.dt
        if self.done or (len(self.pieces) and t >= self.pieces.t_end and self.final):
            return
        s, v, a_prev, cruised, _ = self._state_at_last_sample()
        if len(self.pieces):
            self.pieces = self.pieces.until(t)
        self.final, self.k_end = False, None
        if self.stopping and v <= 1e-9:
            return  # already at rest
        self._commit(s, v, a_prev, cruised, t)

    def _state_at_last_sample(self) -> tuple[float, float, float, float, float]:
        """Where a plan from the last sample made starts: arc length, speed, the last acceleration
        and the cruise since it (`_history_at`), and the time."""
        t = self.k * self.dt
        if not len(self.pieces):
            return 0.0, 0.0, 0.0, 0.0, t
        s_arr, v_arr, _ = self.pieces.state_at(np.array([t]))
        return (float(s_arr[0]), float(v_arr[0]), *self._history_at(t), t)

    def _history_at(self, t: float) -> tuple[float, float]:
        """Like `_history`, but the piece running at t counts as under way."""
        p = self.pieces
        k = min(max(int(np.searchsorted(p.t0, t, side="right") - 1), 0), len(p) - 1)
        if p.a[k] != 0.0 and p.t0[k] < t < p.t0[k] + p.duration[k]:
            return float(p.a[k]), 0.0
        return self._history(t)

    def zones(self, lo: float, hi: float, holding: bool, override: float, rapid_override: float,
              over_feed: bool) -> Zones:
        """Caps and accelerations over [lo, hi] under these controls: a slice of the whole section's
        (`Section.zones`). Safe from another thread (the arrays are never changed)."""
        return _slice(self.section.zones(holding, override, rapid_override, over_feed), lo, hi)

    def _raw(self, t: np.ndarray) -> np.ndarray:
        """Raw arc length at times t (held at the end of the committed pieces beyond them)."""
        if not len(self.pieces):
            return np.zeros(len(t))
        s, _, _ = self.pieces.state_at(t)
        if self.final:
            s = np.where(t >= self.pieces.t_end, self.length, s)
        return np.minimum(s, self.length)


def _window_means(x: np.ndarray, n: int) -> np.ndarray:
    """Means of every n consecutive rows of x (len(x) - n + 1 of them)."""
    c = np.cumsum(x, axis=0)
    out = c[n - 1:].copy()
    out[1:] -= c[:len(x) - n]
    return out / n


def _slice(zones: Zones, lo: float, hi: float) -> Zones:
    """The zones over [lo, hi] (the first and last cut there)."""
    e = zones.edges
    i0 = min(max(int(np.searchsorted(e, lo, side="right") - 1), 0), len(zones.hard) - 1)
    i1 = min(max(int(np.searchsorted(e, hi, side="left")), i0 + 1), len(zones.hard))
    edges = e[i0:i1 + 1].copy()
    edges[0], edges[-1] = lo, hi
    return Zones(edges, zones.hard[i0:i1], zones.soft[i0:i1], zones.accel[i0:i1])


def _time_at(pieces: Pieces, s: float) -> float:
    """When the pieces reach arc length s (the end when they never do)."""
    ends = pieces.s0 + pieces.v0 * pieces.duration + pieces.a * pieces.duration**2 / 2.0
    k = int(np.searchsorted(ends, s, side="left"))
    if k >= len(pieces):
        return pieces.t_end
    ds = s - pieces.s0[k]
    v0, a = pieces.v0[k], pieces.a[k]
    disc = max(v0 * v0 + 2.0 * a * ds, 0.0)
    tau = 2.0 * ds / (v0 + math.sqrt(disc)) if v0 + math.sqrt(disc) > 0 else 0.0
    return float(pieces.t0[k] + min(max(tau, 0.0), pieces.duration[k]))
