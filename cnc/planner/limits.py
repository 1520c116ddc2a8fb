"""Kinematic limits of a section: how fast and how hard each element may be run, and why.

The planner makes motion in three stages (`trajectory.py`): an acceleration-limited
(trapezoidal) speed profile s_raw(t) along the path; a moving average of N_j samples over
s_raw, which makes the profile jerk-limited along the path (trapezoid * box = S-curve); and
a moving average of N_f samples over the axis positions q = p(s), which smooths what the
path itself does abruptly: steps of curvature where a line meets an arc, the ends of corner
blends, and tiny kinks. This module sets the caps that make the result hold every limit.

Per axis i, with u the tangent, n the normal, kappa the signed curvature, v = s':

    a = s'' u + kappa v^2 n                         (|a_i| <= |s''| + |kappa| v^2)
    output jerk = (a(t) - a(t - T_f)) / T_f         (the axis average turns steps into ramps)

so within any window of T_f = N_f dt the acceleration may change by at most J T_f. The jerk
is shared: J_t for the path profile (its average of N_j = A_t / (J_t dt) samples gives
|s'''| <= J_t; where the axis average is the longer one, it alone may hold J_t instead, with
N_j = 1 and A_t = J_t N_f dt: `smoothing_for`), the rest for geometry: for a curved element,
over the stretch of path a window can span (l = v_max (N_f + 2) dt) with curvature up to
kappa_max,

    3 kappa_max v A_t T_f  +  v^2 V   <=  J_curv T_f,
    V = min(sum of curvature steps in reach + kappa_max^2 l,  2 kappa_max)

(3 kappa v s'' from d(kappa v^2 n)/dt and the turning of u; V bounds how far the vector
kappa n can move across a window: by its steps, or at most from one side to the other).

Deviation: the axis average of N_f points lying on the path, whose arc lengths have variance
Var(s), stays within kappa_max Var(s) / 2 of the path (|T(s) - T(s_mean)| <= kappa |s - s_mean|),
and Var(s) <= v^2 (N_f^2 - 1) dt^2 / 12, so

    kappa v^2 <= 24 delta / ((N_f^2 - 1) dt^2)

keeps it within delta. N_f comes from the tolerance P: T_f = (24 P / J)^(1/3) balances the
jerk and deviation caps (the same a_n a clothoid transition of that deviation would allow).
A corner blend takes half of P (`path.py`), the smoothing the other half; G61 (P = 0) gets
no smoothing and an exact path. Kinks (tangent within KINK_MAX_RAD, e.g. an arc meeting a
line a hair off tangent) pass at a speed whose direction jump v phi the axis average can
absorb; a larger turn is an exact stop. Every cap on a stretch of path also holds for the
T_ext before and after it (`envelope`), because the averages mix samples that far apart.

The geometry's share binds only where a window reaches a curve or a kink: a straight element
of a curved section takes A_t = J N dt (N the average that holds the path's jerk) and the
envelope keeps the section's own A_t, or the curve's, over the T_ext around every curve and
kink. Kinks beside curves take only the share of the geometry's budgets they need to pass at
the fastest they may run (`_kink_share`); with no curve beside them, all of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gcode.canon import ARC

from ..config import MachineConfig
from .geometry import PathArrays
from .profile import Zones
from .path import BLEND_SHARE, COLLINEAR_RAD, Element, arc_pieces

KINK_MAX_RAD = 0.01  # a larger turn between unblended elements is an exact stop
GEOMETRY_JERK_SHARE = 0.5  # share of the jerk kept for curvature and kinks when a section has them
GEOMETRY_JERK_SHARES = (0.3, 0.5, 0.7)  # the shares `sections.py` tries, keeping the fastest
KINK_SHARE = 0.25  # of the geometry budgets (jerk, deviation) at most, when a section has kinks and curves
KINK_SHARE_MARGIN = 1.05  # the kinks' share over what they need (`_kink_share`)
KINK_ACCEL_SHARE = 0.02  # of the acceleration, when a section has kinks
RAMP_ACCEL_GIVEN = 0.01  # share of its acceleration a section gives up to ramp in a sample less (`smoothing_for`)
KINK_BISECTIONS = 8  # steps finding the fastest speed a kink's cap holds at
MAX_SMOOTHING_SAMPLES = 64
CURVE_SPEED_SHARE = 0.85  # a curve runs at this share of the speed its jerk budget allows when not speeding up


@dataclass(frozen=True)
class Smoothing:
    """The two moving averages of a section and the shares of the limits they leave."""

    dt: float
    n_path: int  # samples of the average over s (jerk along the path)
    n_axis: int  # samples of the average over the axis positions (geometric smoothing)
    accel_cap: float  # largest tangential acceleration, mm/s^2
    jerk_path: float  # jerk along the path the profile may use, mm/s^3
    deviation_mm: float  # how far the axis average may stray from the path
    geometry_share: float = 0.0  # share of the jerk kept for curvature and kinks (0: a straight section)
    jerk_reserve: float = 0.0  # share of the axes' jerk left unused, for the corner overlaps at its ends (`sections.py`)
    turn_samples: int = 0  # the average that holds the path's jerk (n_path, or n_axis where it is longer: `smoothing_for`)
    alone: tuple[int, float] = (0, 0.0)  # n_path and accel_cap where the path average alone holds the path's jerk

    @property
    def plateau_s(self) -> float:
        """The cruise the raw acceleration keeps between turning from +A to -A (or back): the
        average that holds the path's jerk must never see both turns at once; two samples' margin."""
        return (max(self.turn_samples, self.n_path) + 2) * self.dt

    @property
    def extension_s(self) -> float:
        """How far in time a cap must reach beyond its stretch: the two averages' span, and a sample."""
        return (self.n_path + self.n_axis + 3) * self.dt

    @property
    def alone_extension_s(self) -> float:
        """`extension_s` where the path average alone holds the path's jerk (`alone`)."""
        return (self.alone[0] + self.n_axis + 3) * self.dt


@dataclass(frozen=True)
class SectionLimits:
    """Per-element caps of one section (arrays over its elements; junction arrays over n - 1)."""

    v_hard: np.ndarray  # mm/s: axis velocities, curvature, jerk and deviation caps
    v_feed: np.ndarray  # mm/s: programmed feed (inf for rapids)
    rapid: np.ndarray  # bool
    accel: np.ndarray  # mm/s^2: tangential acceleration at any override
    v_kink: np.ndarray  # mm/s at each junction (inf where smooth)
    smoothing: Smoothing
    caps: "PathCaps | None" = None  # what they were made from: the path's own caps, for the other shares
    accel_feed: np.ndarray | None = None  # mm/s^2: the same where no element runs over its feed (None: `accel`)

    def accel_for(self, over_feed: bool) -> np.ndarray:
        """The tangential accelerations of a motion that may run over its feeds (an override above
        100 % since the section began) or never does. A curve's turning takes more of its jerk
        budget the faster it runs (`_curvature_caps`), so an arc planned for twice its feed leaves
        less to speed changes than the same arc never run over its feed."""
        return self.accel if over_feed or self.accel_feed is None else self.accel_feed

    @property
    def v_max(self) -> float:
        return float(np.minimum(self.v_hard, self.v_feed).max())

    @property
    def v_max_any(self) -> float:
        """The fastest the section may go at any override (feeds up to 200 %)."""
        return float(np.minimum(self.v_hard, np.where(self.rapid, np.inf, 2.0 * self.v_feed)).max())


def smoothing_for(
    config: MachineConfig, tolerance_mm: float, has_curves: bool, has_kinks: bool, blended: bool,
    geometry_share: float = GEOMETRY_JERK_SHARE, top_speed_mm_s: float = math.inf, jerk_reserve: float = 0.0,
    n_axis: int | None = None,
) -> Smoothing:
    """The averages of a section whose tightest corner tolerance is `tolerance_mm`; a section with
    curves or kinks keeps `geometry_share` of the jerk for them, and averages its axis positions
    over `n_axis` samples (None: `axis_average_samples`; a section whose curves are held back by
    their curvature steps may take a longer one, `sections._section`).

    `top_speed_mm_s`: the fastest the section may ever run (any override). A speed change dv
    at acceleration a through the path average (a/J long) takes dv/a + a/J, least at
    a = sqrt(dv J) (a triangle of acceleration, 2 sqrt(dv/J)) and growing with a above it; so
    a section that never changes its speed by more than v_top runs every change soonest, and
    stops within a shorter distance (v^2/2a + v a/2J, also growing above sqrt(v J)), at
    a = min(A, sqrt(v_top J)). Slow sections (a waterjet's cutting feeds) then ramp in
    2 sqrt(v/J) instead of v/A + A/J: 28 ms against 33 ms from 40 mm/s, 14 ms against 27 ms
    from 10 mm/s at this machine's limits.

    `jerk_reserve`: the share of the axes' jerk the section leaves unused, so that where it meets
    the next (or last) section the two motions' jerks may add in a corner overlap (`overlap.py`)."""
    dt = config.timing.period_s
    a_min, j_min = _axis_min(config, "max_accel_mm_s2"), _axis_min(config, "max_jerk_mm_s3")
    geometry = has_curves or has_kinks
    if not geometry:
        n_axis = 1  # a straight path has nothing to smooth
    elif n_axis is None or tolerance_mm <= 0.0:
        n_axis = axis_average_samples(config, tolerance_mm)
    share = geometry_share if geometry else 0.0
    jerk_path = j_min * (1.0 - jerk_reserve) * (1.0 - share)
    a_cap = a_min * (1.0 - KINK_ACCEL_SHARE) if has_kinks else a_min
    accel_cap = a_cap
    if 0.0 < top_speed_mm_s < math.inf:
        accel_cap = min(accel_cap, math.sqrt(top_speed_mm_s * jerk_path))
    ramp = accel_cap / (jerk_path * dt)  # samples of the path average at this acceleration and jerk
    n_path = max(1, math.ceil(ramp - 1e-9))
    if n_path > 1 and (n_path - 1) >= ramp * (1.0 - RAMP_ACCEL_GIVEN):
        # just over a whole number of samples (a jerk reserve of a few thousandths does that): a
        # hair less acceleration, not a sample more of ramp at a twentieth less jerk
        n_path -= 1
        accel_cap = n_path * jerk_path * dt
    turn, alone = n_path, (n_path, accel_cap)
    if n_axis > 1:
        # The axis average smooths the path's speed as well: a step of the raw acceleration
        # reaches the axes as a ramp over N_f samples whatever the path average does, so a
        # section with N_f >= N_j may hold its path jerk with the axis average alone (N_j = 1,
        # A <= J_t N_f dt, the raw acceleration turning no sooner than N_f apart). Where that
        # changes speed sooner (slow sections: from 40 mm/s in 35 ms instead of 54 at this
        # machine's limits, 0.05 mm), it is taken.
        a_axis = min(a_cap, jerk_path * n_axis * dt)
        v = top_speed_mm_s if 0.0 < top_speed_mm_s < math.inf else a_cap * a_cap / jerk_path
        if v / a_axis + (1 + n_axis) * dt < v / accel_cap + (n_path + n_axis) * dt:
            n_path, accel_cap, turn = 1, a_axis, n_axis
    deviation = tolerance_mm * (1.0 - BLEND_SHARE) if blended else tolerance_mm
    return Smoothing(dt, n_path, n_axis, accel_cap, accel_cap / (turn * dt),
                     deviation if n_axis > 1 else 0.0, share, jerk_reserve, turn, alone)


def axis_average_samples(config: MachineConfig, tolerance_mm: float) -> int:
    """N_f, the samples of the axis average of a section with curves or kinks under G64 P
    `tolerance_mm` (1, no average, under G61)."""
    if tolerance_mm <= 0.0:
        return 1
    t_f = (24.0 * tolerance_mm / _axis_min(config, "max_jerk_mm_s3")) ** (1.0 / 3.0)
    return int(min(max(round(t_f / config.timing.period_s), 1), MAX_SMOOTHING_SAMPLES))


def arc_pieces_for_caps(elements: list[Element], config: MachineConfig,
                        n_axis: int | None = None) -> tuple[list[Element], np.ndarray]:
    """The section's elements with each long arc cut into pieces, and the element each piece is
    cut from: a head and a tail as long as the stretch a window of the axis average spans at
    the fastest the arc could run (its feed at 200 %, the axes, its normal acceleration), and
    the middle. Caps are counted per element (`_curvature_caps`): whole, an arc between two
    lines takes the curvature steps at both its ends over all its length; in pieces only its
    head and tail do, and its middle runs at what its curvature alone allows. Arcs shorter
    than two such stretches, blends, arcs of several turns and sections under G61 stay whole.
    `n_axis`: the samples of the section's axis average (None: `axis_average_samples`)."""
    if not any(e.kind == ARC and not e.blend and not e.turns for e in elements):
        return elements, np.arange(len(elements))
    tolerance = min(e.tolerance_mm for e in elements)
    if tolerance <= 0.0:
        return elements, np.arange(len(elements))
    span_s = ((n_axis or axis_average_samples(config, tolerance)) + 2) * config.timing.period_s
    v_axes = _axis_min(config, "max_velocity_mm_s")
    a_normal = config.planner.arc_normal_share * _axis_min(config, "max_accel_mm_s2")
    out, origin = [], []
    for k, e in enumerate(elements):
        pieces = [e]
        if e.kind == ARC and not e.blend and not e.turns:
            radius = math.hypot(e.start[0] - e.center[0], e.start[1] - e.center[1])
            head = min(v_axes, 2.0 * e.feed_mm_s, math.sqrt(a_normal * radius)) * span_s
            length = e.length_mm
            if length >= 3.0 * head:
                pieces = arc_pieces(e, [head / length, 1.0 - head / length])
            elif length >= 2.0 * head:
                pieces = arc_pieces(e, [0.5])
        out += pieces
        origin += [k] * len(pieces)
    return out, np.array(origin, dtype=np.int64)


@dataclass
class PathCaps:
    """What a section's limits take from its path alone, whatever share of the jerk its curves get:
    made once and shared by the shares a section tries (`sections._fastest_limits`)."""

    kinks: np.ndarray  # turn at each junction, rad
    kink: np.ndarray  # bool: a kink the motion passes at speed
    v_axis: np.ndarray  # speed the axes allow on each element
    a_axis: np.ndarray  # acceleration the axes allow on each element
    windows: "CurveWindows | None" = None  # the curvature windows' sums (`_curvature_caps`), made when first asked


def path_caps(path: PathArrays, config: MachineConfig) -> PathCaps:
    """The caps a section's path sets by itself (`PathCaps`), for `section_limits` under any share."""
    kinks = path.kink_angles()
    v_axis, a_axis = _axis_caps(path, config, _axis_min(config, "max_accel_mm_s2"))
    return PathCaps(kinks, (kinks > COLLINEAR_RAD) & (kinks <= KINK_MAX_RAD), v_axis, a_axis)


def section_limits(
    path: PathArrays, feed_mm_s: np.ndarray, rapid: np.ndarray, tolerance_mm: float, blended: bool, config: MachineConfig,
    geometry_share: float = GEOMETRY_JERK_SHARE, caps: PathCaps | None = None, jerk_reserve: float = 0.0,
    n_axis: int | None = None,
) -> SectionLimits:
    """Caps for every element and junction of one section (`caps`: its path's, when made already;
    `jerk_reserve`: the share of the jerk it leaves unused, and `n_axis` its axis average's
    samples, `smoothing_for`)."""
    n = len(path)
    caps = caps or path_caps(path, config)
    kinks, kink = caps.kinks, caps.kink
    curved = path.arc
    j_min, a_min = _axis_min(config, "max_jerk_mm_s3"), _axis_min(config, "max_accel_mm_s2")
    v_axis, a_axis = caps.v_axis, caps.a_axis
    v_feed = np.where(rapid, np.inf, feed_mm_s)
    # the fastest each element may run at any override (feeds up to 200 %, rapids up to 100 %)
    v_fast = np.minimum(v_axis, np.where(rapid, np.inf, 2.0 * v_feed))
    v_top = float(v_fast.max()) if n else math.inf
    sm = smoothing_for(config, tolerance_mm, bool(curved.any()), bool(kink.any()), blended, geometry_share, v_top,
                       jerk_reserve, n_axis)
    a_cap = a_min * (1.0 - KINK_ACCEL_SHARE) if kink.any() else a_min
    if sm.geometry_share > 0.0:
        # the curves' and kinks' share of the jerk binds only where a window of the averages
        # reaches them: there each element's acceleration is widened over its neighbours
        # (`section_zones`); a straight element elsewhere speeds up with the whole path jerk
        a_far = min(a_cap, j_min * (1.0 - jerk_reserve) * sm.turn_samples * sm.dt)
        a_axis = np.where(curved, np.minimum(a_axis, sm.accel_cap), np.minimum(a_axis, max(a_far, sm.accel_cap)))
    else:
        a_axis = np.minimum(a_axis, sm.accel_cap)
    j_geometry = j_min * (1.0 - jerk_reserve) - sm.jerk_path
    share_kink = _kink_share(path, kinks * kink, sm, curved.any(), np.minimum(v_fast[:-1], v_fast[1:]),
                             j_geometry, a_min) if kink.any() else 0.0
    v_hard, accel = v_axis.copy(), a_axis.copy()
    accel_feed = accel
    if curved.any():
        if caps.windows is None:
            caps.windows = CurveWindows(path, kinks * kink)
        v_curve, a_curve, a_curve_feed = _curvature_caps(path, caps.windows, sm, v_feed, j_geometry * (1.0 - share_kink),
                                           sm.deviation_mm * (1.0 - share_kink), config.planner.arc_normal_share * a_min, v_top,
                                           a_cap)
        v_hard = np.minimum(v_hard, v_curve)
        accel_feed = np.where(curved, np.minimum(accel, a_curve_feed), accel)
        accel = np.where(curved, np.minimum(accel, a_curve), accel)
    v_kink = np.full(max(n - 1, 0), np.inf)
    if kink.any():
        v_run = np.minimum(v_axis, v_feed)
        v_kink[kink] = _kink_caps(path, kinks * kink, sm, np.minimum(v_run[:-1], v_run[1:]), np.minimum(v_fast[:-1], v_fast[1:]),
                                  j_geometry * share_kink, sm.deviation_mm * share_kink, a_min)[kink]
    return SectionLimits(v_hard, v_feed, rapid, accel, v_kink, sm, caps, accel_feed)


def _kink_share(
    path: PathArrays, kink_angles: np.ndarray, sm: Smoothing, curves: bool, v_top: np.ndarray, j_geometry: float,
    a_min: float,
) -> float:
    """The share of the geometry's jerk and deviation budgets the kinks take: all of it in a
    section without curves; beside curves, what lets every kink pass at the fastest it may run
    (`v_top`, any override), up to `KINK_SHARE`. A CAM program's rounding leaves kinks of a
    fraction of a milliradian where an arc meets a line (its end a micrometre off the tangent):
    such a hair needs a few per cent of the budget, and the curves keep the rest."""
    if not curves:
        return 1.0
    n_axis, dt = sm.n_axis, sm.dt
    if n_axis <= 1 or j_geometry <= 0.0 or sm.deviation_mm <= 0.0:
        return KINK_SHARE
    kinks = kink_angles > 0
    if not np.isfinite(v_top[kinks]).all():
        return KINK_SHARE
    phi = _window_turns(path, kink_angles, np.where(kinks, v_top, 0.0) * (n_axis + 2) * dt)
    need = float((v_top * phi)[kinks].max())  # k of `_kink_caps` that passes every kink at v_top
    if need > KINK_ACCEL_SHARE * a_min * n_axis * dt / 2.0:
        return KINK_SHARE  # the acceleration's share caps it anyway
    share = max(need * 2.0 / (n_axis * dt * dt) / j_geometry, need * n_axis * dt / 4.0 / sm.deviation_mm)
    return min(KINK_SHARE, share * KINK_SHARE_MARGIN)


def _axis_min(config: MachineConfig, key: str) -> float:
    """The tightest limit among the axes that carry the planar path (X and Y), or all axes."""
    planar = [config.axis[a] for a in ("x", "y") if a in config.axis] or list(config.axes)
    return min(getattr(a, key) for a in planar)


def _axis_caps(path: PathArrays, config: MachineConfig, accel_cap: float) -> tuple[np.ndarray, np.ndarray]:
    """Path velocity and acceleration the axes allow: min_i limit_i / |u_i| on lines, the tightest axis on arcs."""
    n = len(path)
    v = np.full(n, np.inf)
    a = np.full(n, accel_cap)
    for i, name in enumerate(("x", "y", "z")):
        u = np.abs(path.direction[:, i])
        ax = config.axis.get(name)
        if ax is None:
            continue
        with np.errstate(divide="ignore"):
            v = np.minimum(v, np.where(u > 1e-12, ax.max_velocity_mm_s / u, np.inf))
            a = np.minimum(a, np.where(u > 1e-12, ax.max_accel_mm_s2 / u, np.inf))
    if path.arc.any():
        planar = [config.axis[a] for a in ("x", "y") if a in config.axis]
        v = np.where(path.arc, min(a.max_velocity_mm_s for a in planar), v)
        a = np.where(path.arc, min(accel_cap, *(a.max_accel_mm_s2 for a in planar)), a)
    return v, a


def _reach(path: PathArrays, reach_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """First and last element index within `reach_mm` of each element."""
    lo = path.index_at(path.s0[:-1] - reach_mm)
    hi = np.searchsorted(path.s0, path.s0[1:] + reach_mm, side="left") - 1
    return lo, np.clip(hi, 0, len(path) - 1)


def _curvature_caps(
    path: PathArrays, windows: "CurveWindows", sm: Smoothing, v_feed: np.ndarray, j_curv: float, deviation_mm: float,
    a_normal_max: float, v_top: float = math.inf, a_axes: float = math.inf,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed and tangential acceleration of each curved element that keep its turning within the
    jerk, acceleration and deviation budgets, and the tangential acceleration where it never runs
    over its feed (an override up to 100 %: the budget's turning at that speed, not at twice it).

    The jerk budget 3 kappa_max v A_t T + v^2 V <= J_curv T binds speed and tangential
    acceleration together: at A_t = 0 the speed could reach v0 = sqrt(J_curv T / V); the
    element runs at CURVE_SPEED_SHARE of that (or less, for deviation and normal acceleration,
    or the section's top speed `v_top`, which it never exceeds at any override) and the rest of
    the budget is its tangential acceleration.

    V and kappa_max are taken over the stretch of path a window of the axis average spans
    while it mixes the element in: the window's time times the fastest the element runs, its
    cap or its feed at 200 %, whichever is lower (the envelope holds the cap wherever the
    averages mix the element in, at any override; the straight elements around it may run
    faster, but not while a window reaches into it). So the cap f(v) found over the stretch
    that a speed v spans falls as v rises, and a speed v holds where v <= f(v). Found per
    element: v1 = f over the element and its two junctions alone, above
    every speed that holds; then v2 = f(v1) <= v1, which holds; and the feed and twice the
    feed, each taken where it holds and is faster than v2 (capped at its feed, an arc that a
    longer stretch would slow below it runs at it, with the tangential acceleration of that
    speed). A long arc is capped in pieces (`arc_pieces_for_caps`): only its head and tail
    take the curvature steps at its ends.
    """
    kappa, arc = windows.kappa, path.arc
    span = (sm.n_axis + 2) * sm.dt  # a window's time, and a sample either side
    t_w = sm.n_axis * sm.dt
    budget = j_curv * t_w
    a_dev = 24.0 * deviation_mm / ((sm.n_axis**2 - 1) * sm.dt**2) if sm.n_axis > 1 else np.inf
    v = np.full(len(path), np.inf)
    a_t = np.full(len(path), sm.accel_cap)
    a_feed = a_t.copy()  # where the element never runs over its feed (an override up to 100 %)
    with np.errstate(divide="ignore", invalid="ignore"):
        v_cap = np.minimum(np.sqrt(min(a_normal_max, a_dev) / kappa), v_top)  # normal acceleration, deviation, top

        def speed(window: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
            """f: the speed the jerk budget over `window` leaves (and the other caps)."""
            return np.minimum(CURVE_SPEED_SHARE * np.sqrt(budget / window[1]), v_cap)

        def accel(window: tuple[np.ndarray, np.ndarray], u: np.ndarray) -> np.ndarray:
            """The tangential acceleration the budget over `window` leaves at speed u."""
            # the budget's; the section's own cap; the axes' acceleration less the turning's (where a
            # slow section's cap is set for its jerk, `smoothing_for`, the turning may take more of
            # it than the cap leaves, never more than the axes allow)
            a = np.minimum((budget - u * u * window[1]) / (3.0 * window[0] * u * t_w),
                           np.minimum(sm.accel_cap, max(a_axes, sm.accel_cap) - kappa * u * u))
            return np.maximum(a, 0.001 * sm.accel_cap)

        v_max = speed(windows.own)

        def take(candidate: np.ndarray, ask: np.ndarray) -> np.ndarray:
            """Where `candidate` holds among the elements `ask`ed (taken, with its acceleration)."""
            ask = ask & (candidate <= v_max)
            if not ask.any():
                return ask
            window = windows.over(np.where(arc, candidate, 0.0) * span, remember=True)  # the same for every share
            holds = ask & (candidate <= speed(window))
            v[holds], a_t[holds] = candidate[holds], accel(window, candidate)[holds]
            a_feed[holds] = accel(window, np.minimum(candidate, v_feed))[holds]  # the window spans more: conservative
            return holds

        rest = arc & ~take(2.0 * v_feed, arc)  # twice the feed holds: no override runs the element faster
        if rest.any():
            window = windows.over(np.where(rest, np.minimum(v_max, 2.0 * v_feed), 0.0) * span)
            v_2 = speed(window)
            v[rest], a_t[rest] = v_2[rest], accel(window, v_2)[rest]
            a_feed[rest] = accel(window, np.minimum(v_2, v_feed))[rest]
            take(v_feed, rest & (v_feed > v_2))
    return v, a_t, a_feed


class CurveWindows:
    """What the curvature windows of one section's path sum, whatever share of the jerk its
    curves get (made once, kept in its `PathCaps`): per element, over the path within a reach
    of it, the largest curvature and V, how far the vector kappa n can move there (by the
    curvature steps at the junctions and the normal's turn at a kink, or at most from one side
    to the other)."""

    def __init__(self, path: PathArrays, kink_angles: np.ndarray) -> None:
        self.path = path
        kappa = self.kappa = np.abs(path.curvature)
        steps = np.abs(np.diff(path.curvature)) + np.maximum(kappa[:-1], kappa[1:]) * kink_angles
        self.cum = np.concatenate(([0.0], np.cumsum(steps)))
        self.table = _max_table(kappa)
        # the element and its two junctions alone: the shortest stretch any window spans
        k_near = np.maximum(kappa, np.maximum(np.concatenate((kappa[:1], kappa[:-1])), np.concatenate((kappa[1:], kappa[-1:]))))
        step_in, step_out = np.concatenate(([0.0], steps)), np.concatenate((steps, [0.0]))
        self.own = k_near, np.minimum(step_in + step_out, 2.0 * k_near)
        self._memo: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}

    def over(self, reach: np.ndarray, remember: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(largest curvature, V) per element over the path within `reach` (mm, per element) of
        it, at least its two junctions; `remember`: kept for the next share to ask the same."""
        key = reach.tobytes() if remember else None
        if key is not None and key in self._memo:
            return self._memo[key]
        reach = reach + 1e-6
        lo, hi = _reach(self.path, reach)
        k_max = _range_max(self.table, lo, hi)
        # junction b lies between elements b and b+1: within reach of element e when lo <= b < hi
        step_sum = self.cum[hi] - self.cum[lo]
        window = k_max, np.minimum(step_sum + k_max * k_max * reach, 2.0 * k_max)
        if key is not None:
            self._memo[key] = window
        return window


def _kink_caps(
    path: PathArrays, kink_angles: np.ndarray, sm: Smoothing, v_run: np.ndarray, v_top: np.ndarray, j_kink: float,
    deviation_mm: float, a_min: float,
) -> np.ndarray:
    """Speed at each kink: the jump v phi of the velocity direction, spread over the axis average,
    stays within the kinks' share of jerk, acceleration and deviation.

    Kinks a window spans together add their jumps: phi sums the kinks within the stretch a window
    spans at the kink's own speed (the envelope holds its cap wherever the averages mix it in, so
    no window with the kink in it runs faster). The cap f(v) = K / phi(v) falls as v rises and a
    speed v holds where v <= f(v). Found per kink by bisection between f over the kink alone (above
    every speed that holds) and f over the stretch the fastest it runs at any override (`v_top`)
    spans (which holds); then f of the lowest speed found to fail (which holds), and the feed at
    100 % (`v_run`) where it holds.
    """
    n_axis, dt = sm.n_axis, sm.dt
    span = (n_axis + 2) * dt
    k = min(j_kink * n_axis * dt * dt / 2.0, KINK_ACCEL_SHARE * a_min * n_axis * dt / 2.0)
    if n_axis > 1:
        k = min(k, 4.0 * deviation_mm / (n_axis * dt))

    def f(v: np.ndarray) -> np.ndarray:
        """The cap the kinks within the stretch a window spans at speed v leave."""
        return k / _window_turns(path, kink_angles, v * span)

    with np.errstate(divide="ignore", invalid="ignore"):
        v_own = k / kink_angles
        hi = np.minimum(v_own, v_top)
        lo = f(hi)
        v = lo  # holds (never above v_own: phi is at least the kink's own turn)
        hi = np.where(lo >= hi, lo, hi)  # the fastest it runs holds, or the kink alone caps it: done
        for _ in range(KINK_BISECTIONS):
            mid = 0.5 * (v + hi)
            holds = mid <= f(mid)
            v, hi = np.where(holds, mid, v), np.where(holds, hi, mid)
        v = np.maximum(v, np.minimum(f(hi), hi))  # below a speed that fails, its cap holds
        feed_holds = (v_run > v) & (v_run <= hi) & (v_run <= f(v_run))
        v = np.where(feed_holds, v_run, v)
    return np.where(kink_angles > 0, v, np.inf)


def _window_turns(path: PathArrays, kink_angles: np.ndarray, reach_mm: np.ndarray) -> np.ndarray:
    """phi per junction: the turns of the kinks within `reach_mm` of it (per junction) on either
    side, at least its own: what a window of the axis average spanning that stretch adds up."""
    at = path.s0[1:-1]
    cum = np.concatenate(([0.0], np.cumsum(kink_angles)))
    reach = reach_mm + 1e-6
    return np.maximum(cum[np.searchsorted(at, at + reach, side="right")] - cum[np.searchsorted(at, at - reach, side="left")],
                      kink_angles)


def _max_table(values: np.ndarray) -> list[np.ndarray]:
    """The sparse table of `values` for `_range_max`: maxima over runs of 1, 2, 4, ... values."""
    table = [values]
    width = 1
    while 2 * width <= len(values):
        prev = table[-1]
        table.append(np.maximum(prev[:-width], prev[width:]))
        width *= 2
    return table


def _range_max(table: list[np.ndarray], lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """max(values[lo[i] : hi[i] + 1]) for every i, from their `_max_table` (O(1) each)."""
    span = hi - lo + 1
    level = np.floor(np.log2(np.maximum(span, 1))).astype(int)
    out = np.empty(len(lo))
    for lv in np.unique(level):
        m = level == lv
        t = table[lv]
        out[m] = np.maximum(t[lo[m]], t[hi[m] - (1 << lv) + 1])
    return out


def envelope(
    starts: np.ndarray, ends: np.ndarray, values: np.ndarray, widen_mm: np.ndarray, lo_mm: float, hi_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Lower envelope over [lo_mm, hi_mm] of values that each hold on [start - widen, end + widen].

    Returns (breakpoints (m + 1,), the value of each of the m pieces; inf where nothing holds).
    """
    a = np.maximum(starts - widen_mm, lo_mm)
    b = np.minimum(ends + widen_mm, hi_mm)
    keep = b > a
    a, b, c = a[keep], b[keep], values[keep]
    edges = np.unique(np.concatenate(([lo_mm, hi_mm], a, b)))
    out = np.full(len(edges) - 1, np.inf)
    i0 = np.searchsorted(edges, a, side="left")
    i1 = np.searchsorted(edges, b, side="left")
    for k in np.argsort(-c, kind="stable"):  # paint high values first, lower ones over them
        out[i0[k]:i1[k]] = c[k]
    keep = np.concatenate(([True], out[1:] != out[:-1]))  # merge equal neighbours
    return np.concatenate((edges[:-1][keep], edges[-1:])), out[keep]


def section_zones(
    path: PathArrays, lim: SectionLimits, lo: float, hi: float, holding: bool, override: float, rapid_override: float,
    over_feed: bool,
) -> Zones:
    """Caps and accelerations over [lo, hi] of a section under these controls, each widened to
    where the averages could mix it in (by its own speed times `Smoothing.extension_s`);
    `over_feed`: the motion may run over its feeds (`SectionLimits.accel_for`)."""
    if len(path) == 1 and 0.0 <= lo < hi <= path.total_mm:
        return _one_zone(lim, lo, hi, holding, override, rapid_override, over_feed)
    return _enveloped_zones(path, lim, lo, hi, holding, override, rapid_override, over_feed)


def _enveloped_zones(
    path: PathArrays, lim: SectionLimits, lo: float, hi: float, holding: bool, override: float, rapid_override: float,
    over_feed: bool,
) -> Zones:
    """`section_zones` for any section: each cap the lower envelope of the elements' caps widened."""
    reach = lim.smoothing.extension_s
    widen_mm = lim.v_max_any * reach
    s0_all, s1_all = path.s0[:-1], path.s0[1:]
    i0 = int(np.searchsorted(s1_all, lo - widen_mm, side="left"))
    i1 = int(np.searchsorted(s0_all, hi + widen_mm, side="right"))
    s0, s1 = s0_all[i0:i1], s1_all[i0:i1]
    hard = lim.v_hard[i0:i1]
    if holding:
        soft = np.zeros(len(hard))  # a hold stops rapids too
    else:
        with np.errstate(invalid="ignore"):  # a rapid's feed is inf: inf * 0 % is nan, and not taken
            soft = np.where(lim.rapid[i0:i1], hard * rapid_override, lim.v_feed[i0:i1] * override)
    finite = np.isfinite(lim.v_kink)
    kink_at, kink_cap = path.s0[1:-1][finite], lim.v_kink[finite]
    k = (kink_at >= lo - widen_mm) & (kink_at <= hi + widen_mm)
    e_hard, v_hard = envelope(
        np.concatenate((s0, kink_at[k])), np.concatenate((s1, kink_at[k])),
        np.concatenate((hard, kink_cap[k])), np.concatenate((hard, kink_cap[k])) * reach, lo, hi,
    )
    e_soft, v_soft = envelope(s0, s1, soft, np.minimum(soft, hard) * reach, lo, hi)
    # a kink holds the section's own acceleration wherever a window reaches it (a straight element
    # may speed up harder away from the curves and kinks: `section_limits`)
    a_kink = np.full(int(k.sum()), lim.smoothing.accel_cap)
    e_acc, v_acc = envelope(np.concatenate((s0, kink_at[k])), np.concatenate((s1, kink_at[k])),
                            np.concatenate((lim.accel_for(over_feed)[i0:i1], a_kink)),
                            np.concatenate((hard, kink_cap[k])) * reach, lo, hi)
    edges = np.unique(np.concatenate((e_hard, e_soft, e_acc)))
    mid = (edges[:-1] + edges[1:]) / 2.0
    pick = lambda e, v: v[np.clip(np.searchsorted(e, mid, side="right") - 1, 0, len(v) - 1)]  # noqa: E731
    return Zones(edges, pick(e_hard, v_hard), pick(e_soft, v_soft), pick(e_acc, v_acc))


def _one_zone(
    lim: SectionLimits, lo: float, hi: float, holding: bool, override: float, rapid_override: float, over_feed: bool,
) -> Zones:
    """`section_zones` of a section of one element (a rapid, a lead-in, a lead-out: most sections of
    a CAM nest) over [lo, hi] inside it: one zone of its own caps, with nothing to widen against.
    The same values as the general path (the same operations on them), without its dozens of
    array operations."""
    hard = float(lim.v_hard[0])
    if holding:
        soft = 0.0
    elif lim.rapid[0]:
        soft = hard * rapid_override
    else:
        soft = float(lim.v_feed[0]) * override
    return Zones(np.array([lo, hi]), np.array([hard]), np.array([soft]), np.array([float(lim.accel_for(over_feed)[0])]))
