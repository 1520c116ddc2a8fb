"""The cycle-time bounds the LinuxCNC comparison states (`bench/linuxcnc_compare.py`) are what they
claim: the closed form on a single move, and never above what our jerk-limited planner achieves."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

sys.path.append(str(Path(__file__).resolve().parent.parent / "bench"))  # linuxcnc_compare imports its neighbours by name

import linuxcnc_compare as lc  # noqa: E402

from cnc.config import load_machine  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402

CONFIG = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)


def test_the_jerk_limited_bound_of_one_straight_move_is_the_closed_form():
    """100 mm along X at 200 mm/s from rest to rest: 200 > A^2/J, so each ramp takes
    v/A + A/J = 65 ms over 6.5 mm, 32.5 ms more than cruising that far."""
    program, _ = lc.interpret_from_start("G21 G90 G0 X100 Y100\nG1 X200 F12000\nM2\n", CONFIG)
    x = CONFIG.axis["x"]
    v, a, j = 200.0, x.max_accel_mm_s2, x.max_jerk_mm_s3
    ramp_s = v / a + a / j
    assert lc.jerk_bound_s(program, CONFIG) == pytest.approx(100.0 / v + 2 * (ramp_s - (v * ramp_s / 2) / v), rel=1e-12)
    assert lc.feed_bound_s(program, CONFIG) == pytest.approx(0.5)


def test_a_move_too_short_to_reach_its_feed_counts_as_the_fastest_rest_to_rest_move():
    program, _ = lc.interpret_from_start("G21 G90 G0 X100 Y100\nG1 X101 F12000\nM2\n", CONFIG)
    j = CONFIG.axis["x"].max_jerk_mm_s3
    # 1 mm never reaches A (the ramp to v_peak is a triangle of acceleration): 2 ramps of
    # 2 sqrt(v/J) covering v sqrt(v/J) each, so v = (J / 4)^(1/3) mm/s
    v_peak = (j / 4.0) ** (1.0 / 3.0)
    assert lc.jerk_bound_s(program, CONFIG) == pytest.approx(4.0 * math.sqrt(v_peak / j), rel=1e-9)


@pytest.mark.parametrize("text", [
    "G21 G90 G64 P0.05 G0 X200 Y200\nF12000\nG1 X300\nG1 Y300\nG1 X200\nG1 Y200\nM2\n",
    "G21 G90 G64 P0.05 G0 X900 Y600\nF6000\n" + "\n".join(
        f"G1 X{800 + 100 * math.cos(k / 60):.4f} Y{600 + 100 * math.sin(k / 60):.4f}" for k in range(1, 200)) + "\nM2\n",
    "G21 G90 G0 X100 Y100\nG1 X101 F12000\nG4 P0.5\nG1 X150 Y120\nM2\n",
])
def test_our_planner_never_beats_the_bounds(text):
    program, _ = lc.interpret_from_start(text, CONFIG)
    ours_s = ProgramRunner(program, CONFIG).planned_ticks() * CONFIG.timing.period_s
    assert lc.feed_bound_s(program, CONFIG) < lc.jerk_bound_s(program, CONFIG) <= ours_s


def test_the_nest_comparison_tells_rapids_lead_ins_contours_lead_outs_and_parts_apart():
    text = ("G21 G90\nG0 X0 Y0\nG1 X0 Y3 F2400\nG1 X10 Y3\nG3 X10 Y9 I0 J3\nG1 X-2 Y1\n"
            "G0 X50 Y0\nG1 X50 Y3\nG1 X48 Y1\nM2\n")
    kinds, parts = lc.line_kinds(text), lc.line_parts(text)
    assert kinds == {2: "rapids", 3: "lead-ins", 4: "contours", 5: "contours", 6: "lead-outs",
                     7: "rapids", 8: "lead-ins", 9: "lead-outs"}
    assert parts == {2: 1, 3: 1, 4: 1, 5: 1, 6: 1, 7: 2, 8: 2, 9: 2}
    split = lc.time_split([2, 2, 3, 4, 4, 5, 6, 1, 10, 8], kinds, parts, 0.001)  # lines 1 and 10 move nothing
    assert split["by_line_kind_s"] == pytest.approx({"rapids": 0.002, "lead-ins": 0.002, "contours": 0.003,
                                                     "lead-outs": 0.001})
    assert split["by_part_s"] == pytest.approx([0.0, 0.007, 0.001])


def _limits(feed_mm_min: float, tolerance_mm: float) -> "lc.corner_bound.Limits":
    return lc.corner_limits(CONFIG, feed_mm_min, tolerance_mm)


def _rest_to_rest_ticks(length_mm: float, v: float) -> int:
    """The closed form of a straight move from rest to rest at v (long enough to reach it): its
    samples hold every limit (a backward difference is a mean of the derivative), so it is a
    trajectory the bound may not be above."""
    ramp_s, _ = lc._ramp(v, CONFIG.axis["x"].max_accel_mm_s2, CONFIG.axis["x"].max_jerk_mm_s3)
    return math.ceil((length_mm / v + ramp_s) / CONFIG.timing.period_s)


def test_the_corner_bound_of_a_straight_move_is_its_closed_form_sampled():
    """10 mm at 50 mm/s from rest to rest: 200 ms cruising and a ramp of 2 sqrt(v / J) = 32 ms
    in closed form; the least sampled trajectory is at most that and not more than a few periods
    under it."""
    ticks = lc.corner_bound.polyline_bound_ticks([(100.0, 100.0), (110.0, 100.0)], _limits(3000, 0.05))
    assert _rest_to_rest_ticks(10.0, 50.0) - 4 <= ticks <= _rest_to_rest_ticks(10.0, 50.0)


def test_a_corner_costs_time_more_under_a_tighter_tolerance_and_never_more_than_stopping_there():
    """A right angle of two 4 mm legs at 50 mm/s: dearer than the straight 8 mm, dearer at
    P 0.005 than at 0.05, and never dearer than stopping at the corner (two rest-to-rest moves,
    a trajectory that exists)."""
    corner = [(100.0, 100.0), (104.0, 100.0), (104.0, 104.0)]
    loose = lc.corner_bound.polyline_bound_ticks(corner, _limits(3000, 0.05))
    tight = lc.corner_bound.polyline_bound_ticks(corner, _limits(3000, 0.005))
    straight = lc.corner_bound.polyline_bound_ticks([(100.0, 100.0), (108.0, 100.0)], _limits(3000, 0.05))
    assert straight < loose < tight <= 2 * _rest_to_rest_ticks(4.0, 50.0)


def test_our_planner_never_beats_the_corner_bound_and_a_sharp_turn_costs_more_than_going_straight():
    """A 135 degree turn (the outgoing leg runs back along the incoming one: its cut must not be
    met by a sample near the incoming leg)."""
    points = [(100.0, 100.0), (104.0, 100.0), (101.3333, 102.6667)]
    text = "G21 G90 G64 P0.005 G0 X100 Y100\nF3000\nG1 X104 Y100\nG1 X101.3333 Y102.6667\nM2\n"
    program, _ = lc.interpret_from_start(text, CONFIG)
    ours = ProgramRunner(program, CONFIG).planned_ticks()
    straight = lc.corner_bound.polyline_bound_ticks([(100.0, 100.0), (107.7712, 100.0)], _limits(3000, 0.005))
    assert straight < lc.corner_bound.polyline_bound_ticks(points, _limits(3000, 0.005)) <= ours


def test_the_corner_bound_refuses_a_polyline_whose_other_legs_come_near():
    hairpin = [(100.0, 100.0), (110.0, 100.0), (110.0, 100.08), (100.0, 100.08)]
    with pytest.raises(ValueError, match="legs 1 and 3 of the polyline come within 0.080 mm"):
        lc.corner_bound.polyline_bound_ticks(hairpin, _limits(3000, 0.05))


def test_a_stretch_of_one_corner_at_one_feed_has_the_corner_windows_bound():
    """The mixed-integer stretch bound and the windows' branch and bound state the same problem
    for one corner at one feed: a right angle of two 2 mm legs at 40 mm/s, cut at both ends."""
    window = lc.corner_bound.Window((100.0, 98.0), (100.0, 100.0), (102.0, 100.0), False, False)
    limits = _limits(2400, 0.05)
    stretch = lc.corner_bound.stretch_ticks([(100.0, 98.0), (100.0, 100.0), (102.0, 100.0)], [40.0, 40.0], limits)
    assert stretch == lc.corner_bound.window_ticks(window, limits)


def test_our_planner_never_beats_the_bound_of_a_lead_out_a_rapid_and_a_lead_in():
    """Between two parts: a lead-out turned back at 45 degrees, a short rapid, the next lead-in,
    cut at the leads' middles (`bench/nest_stretches.py`). Our run over it is a trajectory the
    programme must admit in as many periods (the bound is never above it: the bisection finds the
    least N that is); the rapid's speed is its axes' alone, so with the leads' feed on the rapid
    no trajectory makes it in those periods."""
    import nest_stretches

    text = ("G21 G90 G64 P0.05 G0 X100 Y97\nG1 X100 Y100 F2400\nG1 X104 Y100\nG1 X103 Y99\n"
            "G0 X107 Y98.5\nG1 X107 Y100\nG1 X110 Y100\nM2\n")
    program, start = lc.interpret_from_start(text, CONFIG)
    (stretch,) = nest_stretches.stretches(program)
    assert stretch.points == ((103.5, 99.5), (103.0, 99.0), (107.0, 98.5), (107.0, 99.25))
    assert stretch.feeds == (40.0, math.inf, 40.0)
    ours = nest_stretches.periods_over(*nest_stretches.ours(program, start, CONFIG), stretch)
    limits = _limits(2400, 0.05)
    assert lc.corner_bound._stretch_feasible(list(stretch.points), list(stretch.feeds), limits, ours)
    assert not lc.corner_bound._stretch_feasible(list(stretch.points), [40.0, 40.0, 40.0], limits, ours)
