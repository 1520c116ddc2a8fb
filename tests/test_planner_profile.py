"""The raw speed profile: caps and acceleration held, a plateau between speeding up and slowing down."""

from __future__ import annotations

import random

import numpy as np
import pytest

from cnc.planner.profile import PLATEAU_SLACK, Pieces, Zones, plan

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

A, PLATEAU = 5000.0, 0.027


def zones(edges, hard, soft=None, accel=None) -> Zones:
    m = len(hard)
    return Zones(
        np.asarray(edges, float), np.asarray(hard, float),
        np.full(m, np.inf) if soft is None else np.asarray(soft, float),
        np.full(m, A) if accel is None else np.asarray(accel, float),
    )


def sampled(p: Pieces, dt: float = 1e-4):
    t = np.arange(0.0, p.t_end + dt, dt)
    return p.state_at(t)


def cap_at(z: Zones, s: np.ndarray) -> np.ndarray:
    k = np.clip(np.searchsorted(z.edges, s, side="right") - 1, 0, len(z.hard) - 1)
    return np.minimum(z.hard[k], z.soft[k])


def check(p: Pieces, z: Zones, v_start: float = 0.0) -> None:
    s, v, a = sampled(p)
    assert np.isfinite(s).all() and (np.diff(s) >= -1e-9).all(), "never backwards"
    assert p.end_state()[0] == pytest.approx(z.edges[-1], abs=1e-6) and abs(p.end_state()[1]) < 1e-6, "at rest at the end"
    assert (np.abs(p.a) <= A + 1e-9).all()
    inside = s < z.edges[-1] - 1e-6
    assert (v[inside] <= np.maximum(cap_at(z, s[inside]), v_start) + 1e-6).all(), "within the cap of the zone it is in"
    # continuity: each piece starts where the one before ended
    for k in range(1, len(p)):
        d = p.duration[k - 1]
        assert p.s0[k] == pytest.approx(p.s0[k - 1] + p.v0[k - 1] * d + p.a[k - 1] * d * d / 2, abs=1e-6)
        assert p.v0[k] == pytest.approx(p.v0[k - 1] + p.a[k - 1] * d, abs=1e-6)


def plateaus_ok(p: Pieces) -> bool:
    """Between a speed-up and a slow-down (or the reverse) there is at least PLATEAU of cruise."""
    last_sign, flat = 0.0, 0.0
    for a, d in zip(p.a, p.duration):
        if a == 0.0:
            flat += d
            continue
        if last_sign and np.sign(a) != last_sign and flat < PLATEAU * (1 - PLATEAU_SLACK):
            return False
        last_sign, flat = np.sign(a), 0.0
    return True


def test_a_long_line_accelerates_cruises_and_stops_exactly_at_its_end():
    z = zones([0.0, 300.0], [500.0])
    p = plan(z, 0.0, 0.0, 0.0, 0.0, PLATEAU)
    check(p, z)
    assert list(np.sign(p.a)) == [1.0, 0.0, -1.0] and p.v0[1] == pytest.approx(500.0)
    assert p.t_end == pytest.approx(300.0 / 500.0 + 500.0 / A), "the time-optimal trapezoid"


def test_a_slow_zone_is_entered_at_its_speed_and_left_at_once():
    z = zones([0.0, 100.0, 110.0, 300.0], [500.0, 50.0, 500.0])
    p = plan(z, 0.0, 0.0, 0.0, 0.0, PLATEAU)
    check(p, z)
    s, v, _ = sampled(p)
    assert v[(s >= 100.0) & (s < 110.0)].max() == pytest.approx(50.0) and v.max() == pytest.approx(500.0)


def test_a_peak_without_room_to_cruise_is_lowered_until_it_has_a_plateau():
    z = zones([0.0, 5.0], [500.0])
    p = plan(z, 0.0, 0.0, 0.0, 0.0, PLATEAU)
    check(p, z)
    assert plateaus_ok(p) and list(np.sign(p.a)) == [1.0, 0.0, -1.0]


def test_a_plan_against_the_acceleration_under_way_cruises_first():
    z = zones([0.0, 300.0], [500.0], soft=[100.0])
    p = plan(z, 0.0, 400.0, A, 0.0, PLATEAU)
    assert p.a[0] == 0.0 and p.duration[0] == pytest.approx(PLATEAU), "a full plateau before slowing down"
    assert p.a[1] < 0.0


def test_a_plateau_already_begun_counts():
    z = zones([0.0, 300.0], [500.0], soft=[100.0])
    p = plan(z, 0.0, 400.0, A, 0.0, PLATEAU, cruised_s=0.02)
    assert p.a[0] == 0.0 and p.duration[0] == pytest.approx(PLATEAU - 0.02)


def test_a_plan_from_a_rest_reached_less_than_a_plateau_ago_stands_still_for_the_rest_of_it():
    """An override of 0 raised again just after the head came to rest: the rest is the plateau
    between slowing down and speeding up, so the plan stands still for what is left of it (it
    used to speed up at once, and the averages met the stop's last deceleration: 1.6x the jerk)."""
    z = zones([50.0, 300.0], [500.0])
    p = plan(z, 50.0, 0.0, -A, 0.0, PLATEAU, t_start=1.0, cruised_s=0.008)
    assert p.a[0] == 0.0 and p.v0[0] == 0.0 and p.duration[0] == pytest.approx(PLATEAU - 0.008)
    assert p.t0[1] == pytest.approx(1.0 + PLATEAU - 0.008) and p.s0[1] == 50.0 and p.a[1] == A
    assert p.end_state()[0] == pytest.approx(300.0) and plateaus_ok(p)
    rested = plan(z, 50.0, 0.0, -A, 0.0, PLATEAU, t_start=1.0, cruised_s=PLATEAU)
    assert rested.a[0] == A and rested.t0[0] == 1.0, "a full plateau at rest: off at once"


def test_a_peak_too_short_to_flatten_is_a_cruise_at_the_present_speed_when_no_plateau_is_owed():
    """Cruising long at 253 mm/s, 9 mm before the end (a raised override): a speed-up would have no
    room for its plateau. The plan keeps the speed until it must brake; it used to cruise a whole
    plateau first, which ran past the end, and the fallback then turned +A to -A at once (2x the jerk)."""
    z = zones([444.8725, 453.796], [506.7])
    p = plan(z, 444.8725, 253.3656, A, 0.0, PLATEAU, cruised_s=0.24)
    assert (p.a <= 0.0).all() and list(np.sign(p.a)) == [0.0, -1.0]
    assert p.end_state()[0] == pytest.approx(453.796) and abs(p.end_state()[1]) < 1e-6 and plateaus_ok(p)


def test_a_speed_up_asked_for_while_braking_without_room_for_its_plateau_keeps_braking():
    """Braking at 425 mm/s, 20 mm before the end, when the override is raised: a plateau, then the
    braking the end needs, no longer fits, so the plan does not speed up at all (it used to turn
    from -A to +A at once: 1.6x the jerk)."""
    z = zones([979.9312, 1000.0], [625.0])
    p = plan(z, 979.9312, 425.0, -A, 0.0, PLATEAU)
    assert (p.a <= 0.0).all() and (p.v0 <= 425.0 + 1e-9).all()
    assert p.end_state()[0] == pytest.approx(1000.0) and abs(p.end_state()[1]) < 1e-6


def test_a_hold_while_speeding_up_cruises_its_plateau_first_when_the_zones_ahead_leave_room_to_brake():
    """Held at 200 mm/s just as it sped up, 20 mm before the end, whose last zone (a curve) allows
    only 1202 mm/s^2: braking at the next zone's 5000 mm/s^2 leaves room for the plateau first. The
    room was judged at the last zone's acceleration, found too short, and the plan turned +A to
    -A at once (1.33x the jerk)."""
    z = zones([22.5, 32.73051, 42.795969], [521.051716, 136.108924], soft=[0.0, 0.0], accel=[A, 1201.773101])
    p = plan(z, 22.5, 200.0, A, 0.0, 0.038)
    assert p.a[0] == 0.0 and p.duration[0] == pytest.approx(0.038) and p.a[1] == -A
    assert abs(p.end_state()[1]) < 1e-9 and p.end_state()[0] < 42.795969
    s, v, _ = sampled(p)
    assert (v[s > 32.73051] <= 136.108924 + 1e-6).all(), "under the curve's cap"


def test_an_override_of_0_ends_the_plan_at_rest_before_a_rapid_it_cannot_reach():
    """Feed moves held by an override of 0, a rapid (its own override still 100 %) after them in the
    same section: the plan stops in the feed moves and stays there. The zone of speed 0 used to get
    no piece at all, and the rapid's pieces after it made the head jump 9 mm in one sample."""
    z = zones([961.8545, 965.6618, 995.0458, 1004.9488, 1034.3328, 1737.1755],
              [591.1464, 358.3411, 358.3411, 358.3411, 591.1464], soft=[0.0, 0.0, np.inf, 0.0, 0.0],
              accel=[A, 3163.9707, 3163.9707, 3163.9707, A])
    p = plan(z, 961.8545, 408.0212, -A, 0.0, 0.052)
    s, v, _ = p.end_state()
    assert abs(v) < 1e-9 and s < 995.0458, "at rest before the rapid"
    ends = p.s0 + p.v0 * p.duration + p.a * p.duration**2 / 2.0
    assert np.allclose(ends[:-1], p.s0[1:], atol=1e-9), "every piece starts where the one before ended"
    assert (p.a <= 0.0).all()


def test_an_override_below_the_speed_brakes_as_hard_as_allowed_to_the_new_feed():
    z = zones([0.0, 300.0], [500.0], soft=[100.0])
    p = plan(z, 0.0, 400.0, 0.0, 0.0, PLATEAU)
    assert p.a[0] == -A and p.v0[1] == pytest.approx(100.0) and p.s0[1] == pytest.approx((400.0**2 - 100.0**2) / (2 * A))
    check(p, z, v_start=400.0)


def test_a_hold_stops_along_the_path_within_the_braking_distance():
    z = zones([10.0, 300.0], [500.0], soft=[0.0])  # zones begin where the plan does
    p = plan(z, 10.0, 300.0, 0.0, 0.0, PLATEAU)
    s_stop, v_stop, _ = p.end_state()
    assert v_stop == pytest.approx(0.0, abs=1e-9) and s_stop == pytest.approx(10.0 + 300.0**2 / (2 * A))


@pytest.mark.parametrize("seed", range(20))
def test_seeded_random_zones_keep_every_cap_and_plateau_and_end_at_rest(seed):
    rng = random.Random(seed)
    edges = np.cumsum([0.0] + [rng.choice([rng.uniform(0.1, 2.0), rng.uniform(5.0, 60.0)]) for _ in range(40)])
    hard = [rng.choice([20.0, 80.0, 250.0, 500.0]) for _ in range(40)]
    accel = [rng.choice([A, 2500.0, 800.0]) for _ in range(40)]
    z = Zones(edges, np.array(hard), np.full(40, np.inf), np.array(accel))
    p = plan(z, 0.0, 0.0, 0.0, 0.0, PLATEAU)
    check(p, z)
    assert plateaus_ok(p)
    k = np.clip(np.searchsorted(z.edges, p.s0 + 1e-9, side="right") - 1, 0, 39)
    assert (np.abs(p.a) <= z.accel[k] + 1e-9).all(), "each piece within its zone's acceleration"


def _same(a, b) -> bool:
    """The same numbers, bit for bit (NaN equal to NaN)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("seed", range(40))
def test_a_few_zones_worked_in_plain_floats_give_the_array_path_s_speeds_and_pieces_bit_for_bit(seed):
    """Sections of one element (rapids, lead-ins, lead-outs: most of a CAM nest) have a zone or
    a few; their junction speeds and pieces are worked out number by number. The timing and
    the run must not move by a rounding: the same doubles as the array path, in every case the
    planner meets (caps at 0 and infinite, starts and ends at speed, zones of a hair)."""
    from cnc.planner.profile import (
        SMALL_ZONES, _junction_speeds, _junction_speeds_arrays, _zone_pieces, _zone_pieces_arrays,
    )

    rng = random.Random(seed)
    for _ in range(50):
        n = rng.randint(1, SMALL_ZONES)
        lengths = [rng.choice([1e-10, 1e-6, rng.uniform(0.01, 3.0), rng.uniform(5.0, 900.0)]) for _ in range(n)]
        edges = np.cumsum([rng.uniform(0.0, 1000.0)] + lengths)
        caps = np.array([rng.choice([0.0, 1e-7, rng.uniform(1.0, 80.0), rng.uniform(100.0, 500.0), np.inf])
                         for _ in range(n)])
        accel = np.array([rng.choice([A, rng.uniform(5.0, 5000.0)]) for _ in range(n)])
        v_start, v_end = rng.choice([0.0, rng.uniform(0.0, 600.0)]), rng.choice([0.0, rng.uniform(0.0, 100.0)])
        w = _junction_speeds(edges, caps, accel, v_start, v_end)
        assert _same(w, _junction_speeds_arrays(edges, caps, accel, v_start, v_end))
        few = _zone_pieces(edges, caps, accel, w)
        assert all(_same(x, y) for x, y in zip(few, _zone_pieces_arrays(edges, caps, accel, w)))


@pytest.mark.parametrize("seed", range(20))
def test_short_peaks_and_valleys_of_a_few_pieces_are_the_array_path_s_caps(seed, monkeypatch):
    """The plateau rule's caps, found number by number for a few pieces, are the array path's."""
    import cnc.planner.profile as profile

    rng = random.Random(seed)
    cases = []
    for _ in range(60):
        n = rng.randint(1, profile.SMALL_ZONES)
        edges = np.cumsum([0.0] + [rng.choice([rng.uniform(0.01, 3.0), rng.uniform(5.0, 90.0)]) for _ in range(n)])
        caps = np.array([rng.choice([rng.uniform(1.0, 80.0), rng.uniform(100.0, 500.0)]) for _ in range(n)])
        accel = np.array([rng.choice([A, rng.uniform(500.0, 5000.0)]) for _ in range(n)])
        w = profile._junction_speeds(edges, caps, accel, rng.choice([0.0, 50.0]), 0.0)
        cases.append((profile._zone_pieces(edges, caps, accel, w), rng.choice([PLATEAU, 0.002, 0.05])))
    few = [(profile._short_peaks(p, t), profile._short_valleys(p, t)) for p, t in cases]
    monkeypatch.setattr(profile, "SMALL_PIECES", 0)
    arrays = [(profile._short_peaks(p, t), profile._short_valleys(p, t)) for p, t in cases]
    assert few == arrays
    assert any(peaks or valleys for peaks, valleys in few), "the cases include peaks and valleys to fix"
