"""The raw speed profile along a stretch of path: acceleration-limited, time-optimal under caps.

The path ahead is cut into zones, each with a speed cap (mm/s) and an acceleration limit
(mm/s^2). The profile is the classic look-ahead one: a forward pass (how fast one can be,
accelerating from the current state) and a backward pass (how fast one may be and still
meet every cap ahead and stop at the end); within a zone v^2 is linear in s between
junctions, so each zone is at most an acceleration, a cruise and a deceleration piece.

Two rules make the moving average that follows (N samples, `stream.py`) jerk-limited:
the acceleration never flips from +A to -A (or back) without a cruise of `plateau_s` in
between (a peak without one is lowered until it has one; a valley without one holds its
low speed longer), so the average of the raw acceleration changes by at most A per N
samples; and a plan that starts against the acceleration it was made under begins with
such a cruise (from rest: standing still, for what is left of the plateau since it stopped),
or, where the end of the stretch leaves no room for one, does not turn at all.

Caps come in two kinds. Hard caps are physical (axis limits, curvature, jerk) and always
hold. Soft caps are the programmed feed times the override: when the override drops below
the current speed, the profile decelerates as hard as it may until it is under them,
rather than jumping (it is allowed above a soft cap while doing so). A cap of zero (feed moves
at an override of 0) ends the plan at rest: what lies beyond it is not reached.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EPS_MM = 1e-9
EPS_V = 1e-9
STILL_MM_S = 1e-6  # a speed this low is standing still: never cruise at it
# Plateaus are checked to within this share of their length (positions kilometres along a
# section carry rounding of 1e-9 mm); the plateau already has two samples of margin
# (`stream.py`), so the jerk bound does not notice. A fix aims this much longer, so that
# the estimate it is made from never leaves a sliver for another round to fix.
PLATEAU_SLACK = 1e-6
PLATEAU_AIM = 1e-3


@dataclass
class Zones:
    """A stretch of path cut into zones: edges (m + 1,), and per zone caps and acceleration."""

    edges: np.ndarray
    hard: np.ndarray
    soft: np.ndarray
    accel: np.ndarray


@dataclass
class Pieces:
    """Raw motion as pieces of constant acceleration, in time order."""

    t0: np.ndarray  # start time of each piece, s (from the section's start)
    s0: np.ndarray  # arc length at its start, mm
    v0: np.ndarray  # speed at its start, mm/s
    a: np.ndarray  # acceleration, mm/s^2
    duration: np.ndarray  # s

    @classmethod
    def empty(cls) -> "Pieces":
        z = np.zeros(0)
        return cls(z, z.copy(), z.copy(), z.copy(), z.copy())

    @property
    def t_end(self) -> float:
        return float(self.t0[-1] + self.duration[-1]) if len(self.t0) else 0.0

    def end_state(self) -> tuple[float, float, float]:
        """(s, v, a) at the end of the last piece."""
        d, a = self.duration[-1], self.a[-1]
        return float(self.s0[-1] + self.v0[-1] * d + a * d * d / 2.0), float(self.v0[-1] + a * d), float(a)

    def __len__(self) -> int:
        return len(self.t0)

    def append(self, other: "Pieces") -> "Pieces":
        return Pieces(*(np.concatenate((getattr(self, f), getattr(other, f))) for f in ("t0", "s0", "v0", "a", "duration")))

    def until(self, t: float) -> "Pieces":
        """The pieces up to time t, the one running at t cut there."""
        k = int(np.searchsorted(self.t0, t, side="left"))
        out = Pieces(self.t0[:k].copy(), self.s0[:k].copy(), self.v0[:k].copy(), self.a[:k].copy(), self.duration[:k].copy())
        if k and out.t0[-1] + out.duration[-1] > t:
            out.duration[-1] = t - out.t0[-1]
        return out

    def state_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, v, a) at times t (inside the pieces; beyond the end, held at the end)."""
        k = np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, len(self.t0) - 1)
        tau = np.minimum(t - self.t0[k], self.duration[k])
        a = self.a[k]
        return self.s0[k] + self.v0[k] * tau + a * tau * tau / 2.0, self.v0[k] + a * tau, a


def plan(
    zones: Zones,
    s_start: float,
    v_start: float,
    a_prev: float,
    v_end: float,
    plateau_s: float,
    t_start: float = 0.0,
    cruised_s: float = 0.0,
) -> Pieces:
    """Time-optimal pieces from (s_start, v_start) over the zones, ending at v_end at the last edge.

    `a_prev` is the last non-zero acceleration before the start and `cruised_s` how long the
    motion has cruised since; the plan does not turn against it before a full plateau.
    """
    caps = np.minimum(zones.hard, zones.soft)
    zero = np.flatnonzero(caps <= STILL_MM_S)
    if len(zero) and (caps[zero[0]:] > STILL_MM_S).any():
        # zones the motion may not move in, with zones it may after them (an override of 0 over feed
        # moves, a rapid after them in the same section): the motion cannot pass, so the plan ends
        # at rest before the next zone it may move in. Planned through, the still zones took no
        # piece at all and the pieces after them jumped over them (the head 9 mm on in one sample).
        k = int(zero[0] + np.argmax(caps[zero[0]:] > STILL_MM_S))
        zones, v_end = Zones(zones.edges[:k + 1], zones.hard[:k], zones.soft[:k], zones.accel[:k]), 0.0
    given = zones
    zones = _soft_after_braking(zones, v_start)
    hard, soft = zones.hard.copy(), zones.soft.copy()
    remaining = max(plateau_s - cruised_s, 0.0) if a_prev else 0.0  # cruise still owed the last acceleration
    cruise_first = False
    for _ in range(50):
        caps = np.minimum(hard, soft)
        w = _junction_speeds(zones.edges, caps, zones.accel, v_start, v_end)
        pieces = _zone_pieces(zones.edges, caps, zones.accel, w)
        fixes = _plateau_fixes(pieces, plateau_s)
        if not fixes:
            break
        if fixes[0][0] <= s_start + EPS_MM and (remaining > 0.0 or v_start <= EPS_V):
            # the plateau would have to start in the past, and the acceleration under way is owed
            # one: cruise now. (Moving and owed none, the fix, a cap at the present speed from here,
            # is right as it is: it cruises just as long as the end allows. A whole plateau's cruise
            # first could run past the end of a short stretch, and the fallback below then broke the
            # jerk limit. At rest, a peak too small to flatten is left as it is.)
            cruise_first = True
            break
        zones, hard, soft = _with_caps(zones, hard, soft, fixes)
    else:
        raise RuntimeError("speed profile: peaks kept needing a plateau after 50 passes")
    s0, v0, a, dur = pieces
    if v_start <= EPS_V and _turns_against(a, dur, a_prev, remaining):
        # come to rest less than a plateau ago (an override of 0 raised again at once): the rest
        # is the plateau, so stand still for what is left of it before speeding up again
        rest = plan(given, s_start, 0.0, 0.0, v_end, plateau_s, t_start + remaining)
        still = Pieces(np.array([t_start]), np.array([s_start]), np.zeros(1), np.zeros(1), np.array([remaining]))
        return still.append(rest)
    if v_start > EPS_V and (cruise_first or _turns_against(a, dur, a_prev, remaining)):
        cruise = remaining
        s_cruise = s_start + v_start * cruise
        # the cruise first, unless the end could then no longer be met (it would run past the end,
        # where the motion stops dead)
        if _room_to_cruise(given, s_start, s_cruise, v_start, v_end):
            sub = _clip_zones(given, s_cruise)
            rest = plan(sub, s_cruise, v_start, 0.0, v_end, plateau_s, t_start + cruise)
            first = Pieces(np.array([t_start]), np.array([s_start]), np.array([v_start]), np.zeros(1), np.array([cruise]))
            return first.append(rest)
        if a_prev < 0.0:
            # a speed-up asked for while the motion brakes near the end of its stretch (the override
            # raised there), with no room left for the plateau before braking again: keep to the
            # speed it has. The plan then only brakes, as the one it replaces did: no turn at all.
            capped = Zones(given.edges, np.minimum(given.hard, v_start), given.soft, given.accel)
            return plan(capped, s_start, v_start, a_prev, v_end, plateau_s, t_start, cruised_s)
        # (speeding up, the plan replaced had the room: cruising now at a lower speed needs less.
        # Should it not, turning the acceleration over at once costs at most twice the path jerk
        # for one average's span.)
    if not len(dur):
        return Pieces.empty()
    t0 = t_start + np.concatenate(([0.0], np.cumsum(dur)[:-1]))
    return Pieces(t0, s0, v0, a, dur)


def _room_to_cruise(zones: Zones, s_from: float, s_to: float, v: float, v_end: float) -> bool:
    """May the motion cruise at v from s_from to s_to and then still brake, as hard as each zone
    allows, under every hard cap after it and to v_end at the last edge?"""
    e = zones.edges
    if s_to > e[-1] + EPS_MM:
        return False
    lo = min(max(int(np.searchsorted(e, s_from, side="right") - 1), 0), len(zones.hard) - 1)
    k = min(max(int(np.searchsorted(e, s_to, side="right") - 1), 0), len(zones.hard) - 1)
    if (zones.hard[lo:k + 1] < v - EPS_V).any():
        return False
    edges = np.concatenate(([s_to], e[k + 1:]))
    shed = np.cumsum(2.0 * zones.accel[k:] * np.diff(edges))  # v^2 braking sheds by each edge after s_to
    allowed = np.concatenate((zones.hard[k + 1:], [v_end])) ** 2
    return bool((v * v - shed <= allowed * (1.0 + 1e-9) + EPS_V).all())


def _turns_against(a: np.ndarray, dur: np.ndarray, a_prev: float, plateau_s: float) -> bool:
    """Does the plan turn the acceleration it starts under over before `plateau_s` of cruise?"""
    if a_prev == 0.0 or plateau_s <= 0.0:
        return False
    flat = 0.0
    for acc, d in zip(a, dur):
        if acc == 0.0:
            flat += d
            if flat >= plateau_s * (1.0 - PLATEAU_SLACK):
                return False
            continue
        return acc * a_prev < 0.0
    return False


def rough_duration_s(zones: Zones) -> float:
    """Time of the profile from rest to rest over the zones, without the plateau rule: a quick
    estimate, to compare ways of planning a section."""
    caps = np.minimum(zones.hard, zones.soft)
    w = _junction_speeds(zones.edges, caps, zones.accel, 0.0, 0.0)
    return float(_zone_pieces(zones.edges, caps, zones.accel, w)[3].sum())


def braking_distance(v: float, accel: float, plateau_s: float) -> float:
    """Distance a stop from speed v may need: a plateau of cruise, then braking at `accel`."""
    return v * plateau_s + v * v / (2.0 * accel)


# ---------------------------------------------------------------------------------------


def _soft_after_braking(zones: Zones, v_start: float) -> Zones:
    """The zones with soft caps lifted where braking as hard as allowed from v_start has not yet
    got under them (the zone where it does is split there)."""
    v2 = v_start * v_start
    if not len(zones.soft) or v2 <= zones.soft[0] * zones.soft[0] + EPS_V:
        return zones  # under the first soft cap already (a start from rest): nothing to lift
    edges, hard, soft, accel = zones.edges.copy(), zones.hard.copy(), zones.soft.copy(), zones.accel.copy()
    for k in range(len(soft)):
        if v2 <= soft[k] * soft[k] + EPS_V:
            break
        after = v2 - 2.0 * accel[k] * (edges[k + 1] - edges[k])
        if after > soft[k] * soft[k]:
            soft[k] = np.inf
            v2 = max(after, 0.0)
            continue
        cut = edges[k] + (v2 - soft[k] * soft[k]) / (2.0 * accel[k])
        if cut > edges[k] + EPS_MM:
            edges = np.insert(edges, k + 1, cut)
            hard, accel = np.insert(hard, k, hard[k]), np.insert(accel, k, accel[k])
            soft = np.insert(soft, k, np.inf)
        break
    return Zones(edges, hard, soft, accel)


def _junction_speeds(edges: np.ndarray, caps: np.ndarray, accel: np.ndarray, v_start: float, v_end: float) -> np.ndarray:
    """Speed at every zone edge: forward (reachable) and backward (can still meet what follows) passes.

    In u = v^2 each pass is a min-plus recursion, u[k+1] = min(C[k+1], u[k] + 2 A[k] L[k]),
    whose solution is u[n] = S[n] + min over j <= n of (C[j] - S[j]), S the running sum of
    2 A L: a cumulative minimum, so both passes are a few array operations.
    """
    if len(caps) <= SMALL_ZONES:
        few = _few_junction_speeds(edges.tolist(), caps.tolist(), accel.tolist(), float(v_start), float(v_end))
        if few is not None:
            return few
    return _junction_speeds_arrays(edges, caps, accel, v_start, v_end)


def _junction_speeds_arrays(edges: np.ndarray, caps: np.ndarray, accel: np.ndarray, v_start: float,
                            v_end: float) -> np.ndarray:
    """`_junction_speeds` on arrays, for any number of zones."""
    length = np.diff(edges)
    d = 2.0 * accel * length
    cumulative = np.concatenate(([0.0], np.cumsum(d)))
    cap_at = np.minimum(np.concatenate((caps[:1], caps)), np.concatenate((caps, caps[-1:])))
    limit = cap_at * cap_at
    limit[0] = v_start * v_start
    forward = cumulative + np.minimum.accumulate(limit - cumulative)
    limit[-1] = min(limit[-1], v_end * v_end)
    limit[0] = np.inf  # the start is given; the backward pass only says whether it can be met
    backward = np.minimum.accumulate((limit + cumulative)[::-1])[::-1] - cumulative
    u = np.minimum(forward, backward)
    if backward[0] < v_start * v_start * (1.0 - 2e-6) - 1e-12:
        # Too fast to meet what follows (a window shorter than a stop): keep the speed
        # continuous and brake as hard as allowed until the profile is met.
        u = np.maximum(u, v_start * v_start - cumulative)
    w = np.sqrt(np.maximum(u, 0.0))
    w[0] = v_start  # (rounding alone otherwise)
    return w


SMALL_ZONES = 12  # up to this many zones, junction speeds and pieces are worked out number by number


def _few_junction_speeds(edges: list, caps: list, accel: list, v_start: float, v_end: float) -> np.ndarray | None:
    """`_junction_speeds` for a few zones in plain floats: the same sums (np.cumsum adds in order) and
    minima in the same order, so the same speeds; None where a value is not a finite number
    (NaN and infinite sums: the array path decides those)."""
    values = (*edges, *accel, v_start, v_end)
    if not all(math.isfinite(x) for x in values) or any(c != c for c in caps):
        return None
    n = len(caps)
    cumulative, total = [0.0], 0.0
    for k in range(n):
        total += 2.0 * accel[k] * (edges[k + 1] - edges[k])
        cumulative.append(total)
    cap_at = [caps[0]] + [min(caps[k - 1], caps[k]) for k in range(1, n)] + [caps[-1]]
    limit = [c * c for c in cap_at]
    limit[0] = v_start * v_start
    forward, low = [], math.inf
    for lim, cum in zip(limit, cumulative):
        low = min(low, lim - cum)
        forward.append(cum + low)
    limit[-1] = min(limit[-1], v_end * v_end)
    limit[0] = math.inf
    backward, low = [0.0] * (n + 1), math.inf
    for k in range(n, -1, -1):
        low = min(low, limit[k] + cumulative[k])
        backward[k] = low - cumulative[k]
    u = [min(f, b) for f, b in zip(forward, backward)]
    if backward[0] < v_start * v_start * (1.0 - 2e-6) - 1e-12:
        u = [max(x, v_start * v_start - cum) for x, cum in zip(u, cumulative)]
    w = [math.sqrt(max(x, 0.0)) for x in u]
    w[0] = v_start
    return np.array(w)


def _zone_pieces(edges, caps, accel, w) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Accelerate / cruise / decelerate pieces of every zone, as (s0, v0, a, duration), all zones at once."""
    if len(caps) <= SMALL_ZONES:
        few = _few_zone_pieces(edges.tolist(), caps.tolist(), accel.tolist(), w.tolist())
        if few is not None:
            return few
    return _zone_pieces_arrays(edges, caps, accel, w)


def _zone_pieces_arrays(edges, caps, accel, w) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_zone_pieces` on arrays, for any number of zones."""
    x0, length = edges[:-1], np.diff(edges)
    wa, wb = w[:-1], w[1:]
    with np.errstate(invalid="ignore"):  # a zone rounded to -1e-16 mm between two rests: NaN, no piece (not `real`)
        peak = np.sqrt((wa * wa + wb * wb + 2.0 * accel * length) / 2.0)
    top = np.maximum(np.minimum(caps, peak), np.maximum(wa, wb))
    d_up = np.maximum((top * top - wa * wa) / (2.0 * accel), 0.0)
    d_down = np.maximum((top * top - wb * wb) / (2.0 * accel), 0.0)
    d_flat = length - d_up - d_down
    short = d_flat < 0.0  # rounding: share the shortfall
    d_up = np.where(short, d_up + d_flat / 2.0, d_up)
    d_down = np.where(short, d_down + d_flat / 2.0, d_down)
    d_flat = np.where(short, 0.0, d_flat)
    real = length > EPS_MM
    up = real & (d_up > EPS_MM) & (top > wa + EPS_V)
    flat = real & (d_flat > EPS_MM) & (top > STILL_MM_S)
    down = real & (d_down > EPS_MM) & (top > wb + EPS_V)
    s_flat = x0 + np.where(up, d_up, 0.0)
    s_down = s_flat + np.where(flat, d_flat, 0.0)
    safe_top = np.where(top > 0.0, top, 1.0)
    # each zone's three pieces side by side, in time order (columns filled: `np.stack` costs more
    # than the arithmetic on a section's few zones)
    n = len(x0)
    s0, v0, a, dur = np.empty((n, 3)), np.empty((n, 3)), np.zeros((n, 3)), np.empty((n, 3))
    keep = np.empty((n, 3), dtype=bool)
    s0[:, 0], s0[:, 1], s0[:, 2] = x0, s_flat, s_down
    v0[:, 0], v0[:, 1], v0[:, 2] = wa, top, top
    a[:, 0], a[:, 2] = accel, -accel
    dur[:, 0], dur[:, 1], dur[:, 2] = (top - wa) / accel, d_flat / safe_top, (top - wb) / accel
    keep[:, 0], keep[:, 1], keep[:, 2] = up, flat, down
    keep = keep.ravel()
    return s0.ravel()[keep], v0.ravel()[keep], a.ravel()[keep], dur.ravel()[keep]


def _few_zone_pieces(edges: list, caps: list, accel: list, w: list):  # noqa: ANN202 - as `_zone_pieces`
    """`_zone_pieces` for a few zones (a section of one element has one), in plain floats: the same
    operations in the same order on the same IEEE doubles, so the same numbers, without the cost of
    forty array operations on arrays of one. None where a value is not a number (NaN orders
    differently in `min` and `np.minimum`) or an acceleration is not positive: the array path
    decides those."""
    s0, v0, acc, dur = [], [], [], []
    for k, (x0, cap, a) in enumerate(zip(edges, caps, accel)):
        length = edges[k + 1] - x0
        wa, wb = w[k], w[k + 1]
        if cap != cap or not a > 0.0 or length != length or wa != wa or wb != wb:
            return None  # (an acceleration of 0 divides by zero: the array path's inf and NaN)
        square = (wa * wa + wb * wb + 2.0 * a * length) / 2.0
        if square < 0.0:
            return None
        peak = math.sqrt(square)
        top = max(min(cap, peak), max(wa, wb))
        d_up = max((top * top - wa * wa) / (2.0 * a), 0.0)
        d_down = max((top * top - wb * wb) / (2.0 * a), 0.0)
        d_flat = length - d_up - d_down
        if d_flat < 0.0:  # rounding: share the shortfall
            d_up, d_down, d_flat = d_up + d_flat / 2.0, d_down + d_flat / 2.0, 0.0
        real = length > EPS_MM
        up = real and d_up > EPS_MM and top > wa + EPS_V
        flat = real and d_flat > EPS_MM and top > STILL_MM_S
        down = real and d_down > EPS_MM and top > wb + EPS_V
        s_flat = x0 + (d_up if up else 0.0)
        s_down = s_flat + (d_flat if flat else 0.0)
        if up:
            s0.append(x0), v0.append(wa), acc.append(a), dur.append((top - wa) / a)
        if flat:
            s0.append(s_flat), v0.append(top), acc.append(0.0), dur.append(d_flat / (top if top > 0.0 else 1.0))
        if down:
            s0.append(s_down), v0.append(top), acc.append(-a), dur.append((top - wb) / a)
    return np.array(s0, dtype=float), np.array(v0, dtype=float), np.array(acc, dtype=float), np.array(dur, dtype=float)


def _turns(pieces):
    """Consecutive pieces that accelerate (either way) with only cruise between: index pairs
    (i, j) and the cruise time between them."""
    s0, v0, a, dur = pieces
    moving = np.flatnonzero(a != 0.0)
    if len(moving) < 2:
        return moving[:0], moving[:0], np.zeros(0)
    cruise = np.concatenate(([0.0], np.cumsum(np.where(a == 0.0, dur, 0.0))))
    i, j = moving[:-1], moving[1:]
    return i, j, cruise[j] - cruise[i + 1]


SMALL_PIECES = 3 * SMALL_ZONES  # up to this many pieces, their turns are found number by number


def _few_turns(pieces, plateau_s: float) -> tuple[list, list]:
    """`_short_peaks` and `_short_valleys` of a few pieces in plain floats (the same sums and tests in
    the same order: the same caps)."""
    s0, v0, a, dur = (x.tolist() for x in pieces)
    short = plateau_s * (1.0 - PLATEAU_SLACK)
    peaks, valleys = [], []
    last = -1  # the last piece that accelerated
    cruise = 0.0  # cumulative cruise time, as `_turns` sums it
    since = 0.0  # the cumulative cruise after the last accelerating piece
    for k, acc in enumerate(a):
        if acc == 0.0:
            cruise += dur[k]
            continue
        if last >= 0:
            flat_s = cruise - since
            if a[last] > 0.0 and acc < 0.0 and flat_s < short:
                peaks.append((last, k))
            if a[last] < 0.0 and acc > 0.0 and flat_s < short and v0[k] > EPS_V:
                valleys.append((s0[k], s0[k] + v0[k] * (plateau_s * (1.0 + PLATEAU_AIM) - flat_s), v0[k]))
        last = k
        cruise += 0.0  # as np.cumsum adds the accelerating piece's 0 (a -0.0 sum becomes 0.0)
        since = cruise
    return peaks, valleys


def _plateau_fixes(pieces, plateau_s: float) -> list[tuple[float, float, float]]:
    """The caps that give every short peak its plateau, else those for every short valley (one
    pass over a few pieces finds both)."""
    if len(pieces[0]) <= SMALL_PIECES:
        peaks, valleys = _few_turns(pieces, plateau_s)
        return [_peak_cap(pieces, p, q, plateau_s * (1.0 + PLATEAU_AIM)) for p, q in peaks] or valleys
    return _short_peaks(pieces, plateau_s) or _short_valleys(pieces, plateau_s)


def _short_peaks(pieces, plateau_s: float) -> list[tuple[float, float, float]]:
    """Every speed-up straight into a slow-down without `plateau_s` of cruise between them,
    each as a cap (from_mm, to_mm, speed) that gives it one."""
    if len(pieces[0]) <= SMALL_PIECES:
        peaks, _ = _few_turns(pieces, plateau_s)
        return [_peak_cap(pieces, p, q, plateau_s * (1.0 + PLATEAU_AIM)) for p, q in peaks]
    s0, v0, a, dur = pieces
    i, j, flat_s = _turns(pieces)
    hit = (a[i] > 0.0) & (a[j] < 0.0) & (flat_s < plateau_s * (1.0 - PLATEAU_SLACK))
    return [_peak_cap(pieces, int(p), int(q), plateau_s * (1.0 + PLATEAU_AIM)) for p, q in zip(i[hit], j[hit])]


def _peak_cap(pieces, last_rise: int, first_fall: int, want_s: float) -> tuple[float, float, float]:
    """The cap that flattens a peak into a cruise of `want_s`: capping only flattens the top, so the
    rise and fall below it stay as they are and the cap is the highest speed v at which
    (where the fall reaches v - where the rise reaches v) / v >= want_s (found by bisection),
    or the bump is flattened away when no such speed is above where it rose from."""
    s0, v0, a, dur = (x.tolist() for x in pieces)  # plain floats: the bisection reads them number by number
    rise = range(last_rise, -1, -1)
    fall = range(first_fall, len(a))

    def rise_at(v: float) -> float:  # where the rise reaches v
        for k in rise:
            if a[k] <= 0.0:
                break
            if v >= v0[k]:
                return s0[k] + (v * v - v0[k] * v0[k]) / (2.0 * a[k])
        return -np.inf

    def fall_at(v: float) -> float:  # where the fall comes down to v
        for k in fall:
            if a[k] >= 0.0:
                break
            v_end = v0[k] + a[k] * dur[k]
            if v >= v_end:
                return s0[k] + (v0[k] * v0[k] - v * v) / (-2.0 * a[k])
        return np.inf

    k = last_rise
    while k > 0 and a[k - 1] > 0.0:
        k -= 1
    m = first_fall
    while m + 1 < len(a) and a[m + 1] < 0.0:
        m += 1
    # below the higher of the speeds the rise starts from and the fall ends at, the bump is gone
    floor = max(float(v0[k]), float(v0[m] + a[m] * dur[m]))
    lo, hi = floor, float(v0[first_fall])
    for _ in range(60):
        mid = (lo + hi) / 2.0
        if mid > 0.0 and (fall_at(mid) - rise_at(mid)) / mid >= want_s:
            lo = mid
        else:
            hi = mid
    return float(rise_at(lo)), float(fall_at(lo)), lo


def _short_valleys(pieces, plateau_s: float) -> list[tuple[float, float, float]]:
    """Every slow-down straight into a speed-up without `plateau_s` of cruise between them,
    each as a cap (from_mm, to_mm, speed) that holds the low speed long enough (a stop in
    the middle is left to the averages: they handle a rest)."""
    if len(pieces[0]) <= SMALL_PIECES:
        return _few_turns(pieces, plateau_s)[1]
    s0, v0, a, dur = pieces
    i, j, flat_s = _turns(pieces)
    hit = (a[i] < 0.0) & (a[j] > 0.0) & (flat_s < plateau_s * (1.0 - PLATEAU_SLACK)) & (v0[j] > EPS_V)
    j, flat_s = j[hit], flat_s[hit]
    v_low = v0[j]
    hi = s0[j] + v_low * (plateau_s * (1.0 + PLATEAU_AIM) - flat_s)
    return list(zip(s0[j].tolist(), hi.tolist(), v_low.tolist()))


def _with_caps(zones: Zones, hard: np.ndarray, soft: np.ndarray, caps: list[tuple[float, float, float]]):
    """Zones with extra hard caps, each on its [lo, hi] (edges split there)."""
    edges = zones.edges
    bounds = np.clip(np.array([(lo, hi) for lo, hi, _ in caps]).ravel(), edges[0], edges[-1])
    new_edges = np.unique(np.concatenate((edges, bounds)))
    idx = np.clip(np.searchsorted(edges, new_edges[:-1], side="right") - 1, 0, len(hard) - 1)
    mid = (new_edges[:-1] + new_edges[1:]) / 2.0
    new_hard = hard[idx].copy()
    for lo, hi, cap in caps:
        inside = (mid >= lo) & (mid <= hi)
        new_hard[inside] = np.minimum(new_hard[inside], cap)
    out = Zones(new_edges, new_hard, zones.soft[idx], zones.accel[idx])
    return out, new_hard.copy(), soft[idx]


def _clip_zones(zones: Zones, s_from: float) -> Zones:
    """The zones from s_from on (the one containing it cut there)."""
    edges = zones.edges
    k = min(max(int(np.searchsorted(edges, s_from, side="right") - 1), 0), len(zones.hard) - 1)
    new_edges = np.concatenate(([min(s_from, edges[-1])], edges[k + 1:]))
    return Zones(new_edges, zones.hard[k:].copy(), zones.soft[k:].copy(), zones.accel[k:].copy())
