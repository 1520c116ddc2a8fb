"""Section limits: axis limits projected on each element, curves within their jerk and deviation budgets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcode.canon import ARC, LINE

from cnc.planner.geometry import PathArrays
from cnc.planner.limits import envelope, section_limits, smoothing_for
from cnc.planner.path import Element

from .conftest import machine_config

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)


def element(kind, start, end, center=None, cw=False, feed=math.inf):
    return Element(kind, start, end, center, cw, 0, feed, 0.05, False, 0, 0, 0, 1)


def limits_of(elements, tolerance=0.05, blended=False, config=None):
    path = PathArrays.of(elements)
    feed = np.array([e.feed_mm_s for e in elements])
    return section_limits(path, feed, np.zeros(len(elements), bool), tolerance, blended, config or machine_config())


def test_a_move_along_one_axis_gets_that_axis_limits():
    lim = limits_of([element(LINE, (0, 0, 0), (100, 0, 0))])
    assert lim.v_hard[0] == 500.0 and lim.accel[0] == 5000.0


def test_a_diagonal_may_go_faster_than_either_axis_alone():
    lim = limits_of([element(LINE, (0, 0, 0), (100, 100, 0))])
    assert lim.v_hard[0] == pytest.approx(500.0 * math.sqrt(2))


def test_the_programmed_feed_is_a_separate_cap():
    lim = limits_of([element(LINE, (0, 0, 0), (100, 0, 0), feed=40.0)])
    assert lim.v_feed[0] == 40.0 and lim.v_hard[0] == 500.0


def test_tighter_arcs_run_slower_and_accelerate_less_along_the_path():
    caps = []
    for r in (1.0, 10.0, 100.0):
        lim = limits_of([element(LINE, (0, -50, 0), (0, 0, 0)), element(ARC, (0, 0, 0), (r, r, 0), center=(r, 0), cw=True),
                         element(LINE, (r, r, 0), (r + 50, r, 0))])
        caps.append((lim.v_hard[1], lim.accel[1]))
        a_normal = caps[-1][0] ** 2 / r
        assert a_normal <= 0.5 * 5000.0 + 1e-9, "never more than the arc's share of the acceleration for turning"
    assert caps[0][0] < caps[1][0] < caps[2][0]
    assert all(lim_a < 5000.0 for _, lim_a in caps)


def test_the_smoothing_follows_the_tolerance_and_an_exact_path_has_none():
    cfg = machine_config()
    exact = smoothing_for(cfg, 0.0, True, False, False)
    loose = smoothing_for(cfg, 0.05, True, False, False)
    tight = smoothing_for(cfg, 0.005, True, False, False)
    assert exact.n_axis == 1 and exact.deviation_mm == 0.0
    assert 1 < tight.n_axis < loose.n_axis
    assert loose.n_path * cfg.timing.period_s == pytest.approx(5000.0 / 100000.0, abs=1e-3), "A / J_t samples along the path"
    assert smoothing_for(cfg, 0.05, False, False, False).n_path == 25, "straight sections get the whole jerk"


def test_a_slow_curved_section_holds_its_path_jerk_with_the_axis_average_alone():
    """A section with curves smooths its axis positions over N_f samples, which smooths its speed
    as well: at a cutting feed (top speed 80 mm/s, F2400 at 200 %) the path average is left out
    (N_j = 1) and the acceleration set so that the axis average alone holds the path's jerk
    (A = J_t N_f dt), the raw acceleration turning no sooner than N_f samples apart: its ramps take
    v/A + N_f dt, well under what the path average would add. A fast section keeps the path average
    (its A / J_t is longer than N_f), and so does a straight one (it has no axis average)."""
    cfg = machine_config()
    dt = cfg.timing.period_s
    j_t = 2e5 * (1.0 - 0.3)
    slow = smoothing_for(cfg, 0.05, True, False, False, 0.3, top_speed_mm_s=80.0)
    assert slow.n_axis == 18 and slow.n_path == 1 and slow.turn_samples == slow.n_axis
    assert slow.accel_cap == pytest.approx(j_t * slow.n_axis * dt)
    assert slow.accel_cap / (max(slow.n_path, slow.turn_samples) * dt) <= j_t * (1.0 + 1e-12), "the path's jerk"
    assert slow.plateau_s == pytest.approx((slow.n_axis + 2) * dt), "no turn of the acceleration within one axis window"
    n_alone, a_alone = slow.alone
    assert n_alone > slow.n_axis
    ramp, ramp_alone = 80.0 / slow.accel_cap + (1 + slow.n_axis) * dt, 80.0 / a_alone + (n_alone + slow.n_axis) * dt
    assert ramp < ramp_alone - 0.01, "from 80 mm/s at least 10 ms sooner"
    fast = smoothing_for(cfg, 0.05, True, False, False, 0.3, top_speed_mm_s=1000.0)
    assert fast.n_path == fast.alone[0] > fast.n_axis and fast.turn_samples == fast.n_path
    assert fast.accel_cap == pytest.approx(5000.0)
    straight = smoothing_for(cfg, 0.05, False, False, False, top_speed_mm_s=80.0)
    assert straight.n_axis == 1 and straight.n_path == straight.alone[0] == 20


def test_a_jerk_reserve_of_a_few_thousandths_costs_a_hair_of_acceleration_not_a_sample_of_ramp():
    """The path average is a whole number of samples, a / (J dt) rounded up: a reserve that puts
    it a hair over a whole number gives up under 1 % of the acceleration instead of ramping a
    sample longer at a twentieth less jerk. The jerk never exceeds the reserved one."""
    cfg = machine_config()
    dt = cfg.timing.period_s
    full = smoothing_for(cfg, 0.05, False, False, False, top_speed_mm_s=80.0)
    reserved = smoothing_for(cfg, 0.05, False, False, False, top_speed_mm_s=80.0, jerk_reserve=4e-4)
    assert reserved.n_path == full.n_path == 20, "sqrt(80 mm/s x 2e5 mm/s^3) / 2e5 mm/s^3 = 20 ms"
    assert 0.99 * full.accel_cap < reserved.accel_cap < full.accel_cap
    assert reserved.accel_cap / (reserved.n_path * dt) <= 2e5 * (1.0 - 4e-4) * (1.0 + 1e-12)
    much = smoothing_for(cfg, 0.05, False, False, False, top_speed_mm_s=80.0, jerk_reserve=0.03)
    assert much.n_path == 21, "3 % less jerk: a sample more, at the acceleration its top speed needs"


def test_a_blended_section_leaves_the_smoothing_half_the_tolerance():
    cfg = machine_config()
    assert smoothing_for(cfg, 0.05, True, False, True).deviation_mm == pytest.approx(0.025)
    assert smoothing_for(cfg, 0.05, True, False, False).deviation_mm == pytest.approx(0.05)


def test_a_near_tangent_kink_gets_a_speed_cap_and_a_smooth_join_none():
    a = element(LINE, (0, 0, 0), (50, 0, 0))
    b = element(LINE, (50, 0, 0), (100, 0.2, 0))  # 0.004 rad
    c = element(LINE, (100, 0.2, 0), (150, 0.4, 0))  # straight on
    lim = limits_of([a, b, c])
    assert 0 < lim.v_kink[0] < 500.0 and lim.v_kink[1] == np.inf


def test_kinks_with_no_curve_beside_them_take_the_whole_geometry_budget():
    """A polyline's kinks (chords of a curve, passed at speed) share the geometry's jerk and
    deviation budgets with nothing: their cap is the one the whole budgets leave (`_kink_caps`:
    the velocity's jump v phi spread over the axis average), not a quarter of them."""
    cfg = machine_config()
    phi = 0.008
    a = element(LINE, (0, 0, 0), (50, 0, 0))
    b = element(LINE, (50, 0, 0), (50 + 50 * math.cos(phi), 50 * math.sin(phi), 0))
    lim = limits_of([a, b], config=cfg)
    sm, dt = lim.smoothing, cfg.timing.period_s
    j_geometry = 200000.0 - sm.jerk_path
    k = min(j_geometry * sm.n_axis * dt * dt / 2.0, 0.02 * 5000.0 * sm.n_axis * dt / 2.0, 4.0 * sm.deviation_mm / (sm.n_axis * dt))
    assert lim.v_kink[0] == pytest.approx(k / phi, rel=1e-6)
    assert lim.v_kink[0] > 2.0 * (0.25 * j_geometry * sm.n_axis * dt * dt / 2.0) / phi


def _rounded_corner(end_y: float) -> list:
    """A rounded rectangle's corner as a CAM writes it to 3 decimals (the comparison nest's part 44):
    a line, a quarter arc R2.014, a line; `end_y` 88.509 leaves the arc's end a micrometre off its
    tangent (a kink of 0.5 mrad into the line), 88.510 meets it exactly."""
    return [element(LINE, (873.561, 90.524, 0), (847.014, 90.524, 0), feed=40.0),
            element(ARC, (847.014, 90.524, 0), (845.0, end_y, 0), center=(847.014, 88.510), feed=40.0),
            element(LINE, (845.0, end_y, 0), (845.0, 65.0, 0), feed=40.0)]


def test_a_hairs_kink_where_an_arc_meets_a_line_leaves_the_arc_its_jerk_budget():
    """A kink of half a milliradian, a CAM's rounding where an arc ends, takes the share of the
    geometry budgets it needs to pass at the fastest it may run (twice its feed), a few per cent,
    and the arc keeps within 3 % the cap it has where it meets the line exactly (the kink took a
    quarter of the budgets, and the nest's arc ran at 37 mm/s instead of its 40 mm/s feed)."""
    exact = limits_of(_rounded_corner(88.510))
    rounded = limits_of(_rounded_corner(88.509))
    assert np.isinf(exact.v_kink).all()
    assert math.isfinite(rounded.v_kink[1]) and rounded.v_kink[1] >= 80.0
    assert 0.97 * exact.v_hard[1] <= rounded.v_hard[1] <= exact.v_hard[1]  # a quarter of the budget: 0.87


def test_a_contours_straights_away_from_its_curves_speed_up_with_the_whole_path_jerk():
    """The curves' share of the jerk binds where a window of the averages reaches them: a straight
    element of a section with arcs accelerates at what the whole path jerk allows through the
    average that holds it (`Smoothing.turn_samples`), and the zones hold the section's own
    acceleration, or the arc's, wherever a window can reach the arc or a kink."""
    from cnc.planner.geometry import PathArrays
    from cnc.planner.limits import section_zones

    cfg = machine_config()
    elements = _rounded_corner(88.509)
    lim = limits_of(elements, config=cfg)
    sm, dt = lim.smoothing, cfg.timing.period_s
    a_far = min(5000.0 * 0.98, 200000.0 * sm.turn_samples * dt)
    assert sm.geometry_share > 0.0 and lim.accel[0] == pytest.approx(a_far) and lim.accel[2] == pytest.approx(a_far)
    assert lim.accel[0] > 1.5 * sm.accel_cap and lim.accel[1] <= sm.accel_cap
    path = PathArrays.of(elements)
    zones = section_zones(path, lim, 0.0, path.total_mm, False, 1.0, 1.0, False)
    reach_mm = lim.v_max_any * sm.extension_s
    mid = (zones.edges[:-1] + zones.edges[1:]) / 2.0
    near = (mid > path.s0[1] - reach_mm) & (mid < path.s0[2] + reach_mm)
    assert (zones.accel[near] <= sm.accel_cap * (1 + 1e-12)).all()
    assert zones.accel[0] == pytest.approx(a_far) and zones.accel[-1] == pytest.approx(a_far)


def test_an_envelope_is_the_lowest_cap_widened_to_where_it_reaches():
    edges, values = envelope(np.array([0.0, 10.0]), np.array([10.0, 20.0]), np.array([100.0, 5.0]), np.array([1.0, 1.0]), 0.0, 20.0)
    assert list(edges) == [0.0, 9.0, 20.0] and list(values) == [100.0, 5.0]


def test_a_slow_section_accelerates_at_what_its_top_speed_needs_and_its_arcs_keep_their_share():
    """At a waterjet feed (10 mm/s; 20 at the override's 200 %) the section's acceleration is
    sqrt(v_top J) (the least-time jerk-limited ramps to that speed), and a small arc's share of
    it is reckoned at the speed it can reach, not at the far higher speed its curvature alone
    would allow (at that speed the centripetal acceleration left it almost none: 1.7 mm/s^2)."""
    cfg = machine_config()
    j = cfg.axis["x"].max_jerk_mm_s3
    lines = [element(LINE, (0, -50, 0), (0, 0, 0), feed=10.0), element(LINE, (0, 0, 0), (50, 0, 0), feed=10.0)]
    straight = limits_of(lines, config=cfg)
    assert straight.smoothing.accel_cap == pytest.approx(math.sqrt(20.0 * j))
    assert straight.smoothing.jerk_path <= j * (1 + 1e-12)
    assert (straight.accel <= straight.smoothing.accel_cap).all()
    fast = limits_of([element(LINE, (0, -50, 0), (0, 0, 0))], config=cfg)
    assert fast.smoothing.accel_cap == 5000.0 and fast.smoothing.n_path == 25, "a fast section keeps the machine's"
    r = 1.5
    arc = [element(LINE, (0, -50, 0), (0, 0, 0), feed=10.0),
           element(ARC, (0, 0, 0), (r, r, 0), center=(r, 0), cw=True, feed=10.0),
           element(LINE, (r, r, 0), (r + 50, r, 0), feed=10.0)]
    lim = limits_of(arc, config=cfg)
    assert lim.v_hard[1] <= 20.0
    assert lim.accel[1] >= 0.5 * lim.smoothing.accel_cap


@pytest.mark.parametrize("seed", range(10))
def test_a_section_of_one_element_gets_the_zone_the_envelope_would_give_it(seed):
    """Most sections of a CAM nest are one element (a rapid, a lead-in, a lead-out): their zone is
    made directly, and must be the general envelope's, number for number, under every control."""
    import random

    from cnc.planner.limits import _enveloped_zones, section_zones

    rng = random.Random(seed)
    config = machine_config()
    for _ in range(40):
        x, y = rng.uniform(0, 1000), rng.uniform(0, 1000)
        kind = rng.choice(["line", "rapid", "arc"])
        if kind == "arc":
            r = rng.uniform(0.5, 50.0)
            e = element(ARC, (x + r, y, 0.0), (x, y + r, 0.0), (x, y), cw=False, feed=rng.uniform(1.0, 200.0))
        else:
            end = (x + rng.uniform(-300, 300), y + rng.uniform(-300, 300), 0.0)
            e = element(LINE, (x, y, 0.0), end, feed=math.inf if kind == "rapid" else rng.uniform(1.0, 200.0))
        path = PathArrays.of([e])
        lim = section_limits(path, np.array([e.feed_mm_s]), np.array([kind == "rapid"]), 0.05, False, config)
        total = path.total_mm
        lo = rng.choice([0.0, rng.uniform(0.0, total / 2)])
        hi = rng.choice([total, rng.uniform(lo + 1e-6, total)])
        controls = (rng.random() < 0.2, rng.choice([0.0, 0.5, 1.0, 2.0]), rng.choice([0.0, 0.25, 1.0]), rng.random() < 0.5)
        got, want = section_zones(path, lim, lo, hi, *controls), _enveloped_zones(path, lim, lo, hi, *controls)
        for field in ("edges", "hard", "soft", "accel"):
            assert np.asarray(getattr(got, field)).tobytes() == np.asarray(getattr(want, field)).tobytes(), (field, kind, controls)


def polyline(angles, spacing, feed):
    """Lines of `spacing` mm turning by each of `angles` (rad) in turn, at `feed`."""
    heading, at, lines = 0.0, np.zeros(2), []
    for turn in (0.0, *angles):
        heading += turn
        end = at + spacing * np.array([math.cos(heading), math.sin(heading)])
        lines.append(element(LINE, (*at, 0.0), (*end, 0.0), feed=feed))
        at = end
    return lines


@pytest.mark.parametrize("spacing_spans", [0.6, 1.5, 3.0])
def test_kinks_a_window_spans_together_keep_their_share_at_any_override(spacing_spans):
    """Kinks closer than a window spans at twice the feed (what the 200 % override runs) add their
    jumps in it: each kink's cap holds with every kink the window spans at the fastest speed the
    kink runs at any override, and a kink a window at the feed spans alone still runs at the feed."""
    feed = 60.0
    lone = limits_of(polyline([0.002], 20.0, feed))
    sm = lone.smoothing
    budget = lone.v_kink[0] * 0.002  # the cap is budget / phi, phi the turns a window spans
    span = (sm.n_axis + 2) * sm.dt
    phi0 = budget / (3.0 * feed)  # alone: three times the feed; with its two neighbours: the feed
    angles = [phi0] * 20
    lim = limits_of(polyline(angles, spacing_spans * feed * span, feed))
    assert lim.smoothing.n_axis == sm.n_axis
    path_at = np.cumsum([spacing_spans * feed * span] * 21)[:-1]
    kinks = lim.v_kink[np.isfinite(lim.v_kink)]
    assert len(kinks) == 20
    for cap, at in zip(kinks, path_at):
        fastest = min(cap, 2.0 * feed)
        phi = sum(phi0 for other in path_at if abs(other - at) <= fastest * span)
        assert fastest * phi <= budget * (1 + 1e-9), "the kinks a window spans at the fastest this one runs"
    if spacing_spans > 1.0:
        assert kinks.min() >= feed * (1 - 1e-9), "a window at the feed spans one kink: the feed holds"

