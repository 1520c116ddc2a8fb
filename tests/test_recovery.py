"""Restarting a program inside it (`cnc.planner.recovery`): continuing a cut where the jet stopped,
backed up by the overlap and never past the cut's pierce; starting at part N; running from a line.
The joined cut is compared with the program's: no gap, no more overlap than asked."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cnc.planner.preflight import preflight
from cnc.planner.recovery import (
    RecoveryError, continue_at, cut_starts, into_segments, locate, point_at, run_from_line, segment_length, start_at_part,
)
from cnc.planner.steps import ProgramTiming
from cnc.machine_dialect import dialect_for
from gcode.canon import ARC, DWELL, RAPID
from gcode.interp import Interpreter

from .conftest import machine_config

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

CONFIG = machine_config()
NEST = """(three parts: kerf compensated squares with a rounded corner, a full circle, a pierce dwell each)
G21 G90 G64 P0.05 F1200 T1 M6
G0 X20 Y20
M3
G4 P0.5
G41 D1 G1 X30 Y20
G1 X80
G1 Y60
G3 X70 Y70 R10
G1 X30
G1 Y20
G40 G1 X20 Y20
M5
G0 X120 Y20
M3
G4 P0.5
G1 X160 Y20
G1 Y60
G1 X120
G1 Y20
M5
G0 X250 Y40
M3
G2 X250 Y40 I20 J0 P2
M5
G0 X10 Y10
M2
"""
HEAD = (5.0, 5.0, 0.0)


def program(text: str = NEST):
    return Interpreter(dialect_for(CONFIG), "nest.ngc").run(text.encode())


def cut_path(prog, step_mm: float = 0.5) -> list[tuple[float, float]]:
    """Points every `step_mm` along the program's cutting moves (jet on, not rapids or dwells)."""
    pts = []
    for s in prog.segments:
        if not s["jet"] or int(s["kind"]) in (RAPID, DWELL):
            continue
        length = segment_length(s)
        for d in np.arange(0.0, length + 1e-9, step_mm):
            pts.append(point_at(s, float(d))[:2])
    return pts


def cut_length(prog) -> float:
    return sum(segment_length(s) for s in prog.segments if s["jet"] and int(s["kind"]) not in (RAPID, DWELL))


def test_a_cut_continues_an_overlap_before_where_the_jet_stopped_and_runs_the_rest():
    prog = program()
    k = next(i for i, s in enumerate(prog.segments) if s["jet"] and tuple(s["end"][:2]) == pytest.approx((79.875, 60.0)))
    stop = point_at(prog.segments[k], 25.0)  # 25 mm up the square's right side
    r = continue_at(prog, k, stop, 5.0, HEAD)
    assert r.segment == k and r.into_mm == pytest.approx(20.0)
    assert r.at == pytest.approx(point_at(prog.segments[k], 20.0)), "5 mm before the stop"
    first = r.program.segments[0]
    assert int(first["kind"]) == RAPID and tuple(first["start"]) == HEAD and not first["jet"], "a rapid, jet closed"
    assert r.program.segments[1]["jet"] and tuple(r.program.segments[1]["start"]) == pytest.approx(r.at)
    done_before = sum(segment_length(s) for s in prog.segments[:k] if s["jet"] and int(s["kind"]) not in (RAPID, DWELL))
    assert cut_length(r.program) == pytest.approx(cut_length(prog) - (done_before + 25.0) + 5.0), "the rest and the overlap"
    assert r.program.stats.pierces == prog.stats.pierces - 1 + 1, "this cut pierces again, the others as before"
    assert "continue the cut of line" in r.description


def test_the_overlap_backs_up_across_segments_but_never_past_the_pierce():
    prog = program()
    seg = prog.segments
    corner = next(i for i, s in enumerate(seg) if s["jet"] and int(s["kind"]) == ARC and not s["turns"])
    r = continue_at(prog, corner, point_at(seg[corner], 2.0), 6.0, HEAD)  # 2 mm into the rounded corner, 6 mm back
    assert r.segment == corner - 1 and r.into_mm == pytest.approx(segment_length(seg[corner - 1]) - 4.0)
    lead_in = cut_starts(prog)[0] + 1  # after the part's pierce dwell: its lead-in
    r = continue_at(prog, lead_in, point_at(seg[lead_in], 3.0), 50.0, HEAD)
    assert (r.segment, r.into_mm) == (lead_in, 0.0), "the overlap ends at the cut's pierce"
    with pytest.raises(RecoveryError, match="the jet was not cutting there; start at the next part instead"):
        continue_at(prog, 0, (20.0, 20.0), 5.0, HEAD)


def test_a_cut_stopped_while_piercing_pierces_again_and_cuts_the_whole_part():
    """A fault during a pierce (the jet open, the head standing in the pierce dwell) leaves the cut
    point on the dwell. "continue" pierces there again and cuts the part from its start, every
    millimetre of it, rather than refusing and sending the operator to the next part (a random
    CAM part stopped in its pierce by the sweep of this test's generator was refused so)."""
    prog = program()
    seg = prog.segments
    second = cut_starts(prog)[1]  # the second square's pierce dwell (G4 P0.5 after M3)
    assert int(seg[second]["kind"]) == DWELL and seg[second]["jet"]
    r = continue_at(prog, second, tuple(seg[second]["start"][:2]), 5.0, HEAD)
    assert (r.segment, r.into_mm) == (second, 0.0) and "pierce again" in r.description
    first = r.program.segments[0]
    assert int(first["kind"]) == RAPID and not first["jet"] and r.at == pytest.approx(tuple(seg[second]["start"]))
    assert int(r.program.segments[1]["kind"]) == DWELL and r.program.segments[1]["jet"], "the pierce dwell again"
    rest = sum(segment_length(s) for s in seg[second:] if s["jet"] and int(s["kind"]) not in (RAPID, DWELL))
    assert cut_length(r.program) == pytest.approx(rest), "the part cut whole, and the parts after it"
    assert r.program.stats.pierces == len(cut_starts(prog)) - 1, "this part's pierce and the ones after it"


def test_a_cut_stopped_in_a_dwell_inside_it_continues_from_where_the_head_stood():
    """A dwell with the jet open inside a cut (the head standing at a corner): the cut stopped at the
    end of the move before the dwell, and continues from there, backed up by the overlap."""
    text = NEST.replace("G1 Y60\nG3 X70 Y70 R10", "G1 Y60\nG4 P0.3\nG3 X70 Y70 R10", 1)
    prog = program(text)
    seg = prog.segments
    dwell = next(i for i, s in enumerate(seg) if int(s["kind"]) == DWELL and s["jet"] and int(seg[i - 1]["kind"]) != RAPID
                 and seg[i - 1]["jet"] and int(seg[i - 1]["kind"]) != DWELL)
    before = seg[dwell - 1]
    r = continue_at(prog, dwell, tuple(before["end"][:2]), 5.0, HEAD)
    assert r.segment == dwell - 1 and r.into_mm == pytest.approx(segment_length(before) - 5.0)
    assert r.at == pytest.approx(point_at(before, segment_length(before) - 5.0))
    assert "continue the cut" in r.description


def test_a_cut_stopped_at_its_very_end_starts_the_next_part_at_its_own_pierce():
    """The program closed the jet at the end of a part's lead-out and the stop came after (in the
    rapid to the next part): the jet last cut at that very end. That cut is whole: "continue"
    starts the next part with its own pierce, where the CAM placed it, instead of piercing at the
    finished part's edge to cut the overlap again (which it used to). After the last cut of the
    program nothing is left to cut, and it says so."""
    prog = program()
    seg = prog.segments
    starts = cut_starts(prog)
    end = max(i for i in range(starts[1]) if seg[i]["jet"] and int(seg[i]["kind"]) not in (RAPID, DWELL))
    r = continue_at(prog, end, tuple(seg[end]["end"][:2]), 2.0, HEAD)
    assert (r.segment, r.into_mm) == (starts[1], 0.0) and r.at == pytest.approx(tuple(seg[starts[1]]["start"]))
    assert r.description == "the cut of line 12 was complete: start at part 2 of 3 (line 16)"
    assert r.program.stats.pierces == 2 and cut_length(r.program) == pytest.approx(
        sum(segment_length(s) for s in seg[starts[1]:] if s["jet"] and int(s["kind"]) not in (RAPID, DWELL)))
    r = continue_at(prog, end, point_at(seg[end], segment_length(seg[end]) - 0.01), 2.0, HEAD)
    assert r.segment <= end and "continue the cut of line" in r.description, "a hair short of the end: not whole"
    last = program(NEST.split("G0 X250 Y40")[0] + "G0 X10 Y10\nM2\n")  # the two squares only
    k = max(i for i, s in enumerate(last.segments) if s["jet"] and int(s["kind"]) not in (RAPID, DWELL))
    with pytest.raises(RecoveryError, match=r"nest.ngc:\d+: the cut that stopped was complete and no cut follows it"):
        continue_at(last, k, tuple(last.segments[k]["end"][:2]), 2.0, HEAD)


@settings(max_examples=80, deadline=None)
@given(where=st.floats(0.0, 1.0), overlap=st.floats(0.0, 30.0))
@example(where=0.9999999999999999, overlap=0.0)  # a hair before the end of two turns: one turn is left
def test_the_joined_cut_has_no_gap_and_no_more_overlap_than_asked(where, overlap):
    """Stop anywhere on any cut: what was cut before the stop and what the restart cuts cover the
    program's cut, and they share exactly the overlap (less only where the cut began closer)."""
    prog = program()
    seg = prog.segments
    cutting = [i for i, s in enumerate(seg) if s["jet"] and int(s["kind"]) not in (RAPID, DWELL)]
    lengths = np.array([segment_length(seg[i]) for i in cutting])
    target = where * lengths.sum()
    j = min(int(np.searchsorted(np.cumsum(lengths), target, side="right")), len(cutting) - 1)
    into = min(target - (np.cumsum(lengths)[j] - lengths[j]), lengths[j])
    k = cutting[j]
    if into >= lengths[j] - 1e-6 and (j + 1 == len(cutting) or not all(seg[i]["jet"] for i in range(k + 1, cutting[j + 1]))):
        return  # at the very end of a cut: whole (test_a_cut_stopped_at_its_very_end_starts_the_next_part_at_its_own_pierce)
    r = continue_at(prog, k, point_at(seg[k], float(into)), overlap, HEAD)
    # the program's cut length from the start of this cut to the stop point
    start = max(s for s in cut_starts(prog) if s <= k)
    since_pierce = sum(segment_length(seg[i]) for i in range(start, k) if int(seg[i]["kind"]) != DWELL) + locate(
        seg[k], point_at(seg[k], float(into)))
    done = sum(segment_length(seg[i]) for i in cutting if i < k) + locate(seg[k], point_at(seg[k], float(into)))
    used = min(overlap, since_pierce)
    assert cut_length(r.program) == pytest.approx(cut_length(prog) - done + used, abs=1e-6)
    assert math.dist(r.at[:2], point_at(seg[r.segment], r.into_mm)[:2]) < 1e-9


def test_an_arc_of_several_turns_stopped_in_its_first_turn_keeps_the_turns_left():
    prog = program()
    seg = prog.segments
    k = next(i for i, s in enumerate(seg) if int(s["kind"]) == ARC and s["turns"] == 1)
    full = segment_length(seg[k])
    assert full == pytest.approx(2 * 2 * math.pi * 20.0)
    r = continue_at(prog, k, point_at(seg[k], 30.0), 0.0, HEAD)
    rest = r.program.segments[1]
    assert int(rest["turns"]) == 1 and segment_length(rest) == pytest.approx(full - 30.0)
    assert locate(seg[k], point_at(seg[k], 30.0)) == pytest.approx(30.0)


@pytest.mark.parametrize("into", [30.0, 126.0, 160.0, 250.0])
def test_an_arc_of_several_turns_continues_in_the_turn_its_cut_point_was_on(into):
    """The cut point says roughly how far into the segment the jet stopped (the planner's progress,
    a few mm off either way): the restart backs up from there in that turn. Without it, the first."""
    prog = program()
    seg = prog.segments
    k = next(i for i, s in enumerate(seg) if int(s["kind"]) == ARC and s["turns"] == 1)
    full = segment_length(seg[k])
    stop = point_at(seg[k], into)
    for hint in (into - 3.0, into + 3.0):
        assert locate(seg[k], stop, hint) == pytest.approx(into)
        r = continue_at(prog, k, stop, 5.0, HEAD, segment_mm=hint)
        assert r.segment == k and r.into_mm == pytest.approx(into - 5.0)
        assert segment_length(r.program.segments[1]) == pytest.approx(full - (into - 5.0))
    assert locate(seg[k], stop) == pytest.approx(into % (full / 2.0)), "no hint: the first turn"


def test_how_far_into_its_segment_each_setpoint_lies_carries_across_bursts_and_a_restart():
    into, carry = into_segments(np.array([0, 0, 1, 1, 1, 2, 2]), np.arange(7.0), (-1, 0.0))
    assert into.tolist() == [0, 1, 0, 1, 2, 0, 1]
    into, carry = into_segments(np.array([2, 2, 3]), np.array([7.0, 8.0, 9.0]), carry)
    assert into.tolist() == [2, 3, 0], "the segment under way when the last burst ended goes on"
    # a restart: its segment 1 begins 40 mm into the program's segment, its segment 0 is the rapid there
    into, _ = into_segments(np.array([0, 0, 0, 1, 1]), np.array([0.0, 5.0, 5.0, 10.0, 12.0]), (-1, 0.0), restart_into_mm=40.0)
    assert into.tolist() == [40, 40, 40, 40, 42]


def test_a_nest_starts_at_part_n_and_from_a_line_and_the_planner_runs_each():
    prog = program()
    starts = cut_starts(prog)
    assert len(starts) == 3 == prog.stats.pierces
    r = start_at_part(prog, 2, HEAD)
    assert int(r.program.segments[1]["kind"]) == DWELL and r.program.segments[1]["jet"], "its own pierce dwell first"
    assert r.program.stats.pierces == 2 and r.line == 16
    with pytest.raises(RecoveryError, match="has 3 parts \\(pierces\\): there is no part 4"):
        start_at_part(prog, 4, HEAD)
    r3 = run_from_line(prog, 23, HEAD)  # M3 moves nothing: from the arc after it
    assert r3.line == 24 and int(r3.program.segments[1]["kind"]) == ARC
    with pytest.raises(RecoveryError, match="nothing moves at or after line 99"):
        run_from_line(prog, 99, HEAD)
    for restart in (r, r3, continue_at(prog, starts[0] + 3, point_at(prog.segments[starts[0] + 3], 10.0), 2.0, HEAD)):
        preflight(restart.program.segments, CONFIG, dict.fromkeys(CONFIG.axis_names, True), "restart")
        timing = ProgramTiming.of(restart.program, CONFIG)
        assert timing.failure is None and timing.total_ticks > 0


def test_a_line_in_a_loop_starts_at_its_first_pass_and_says_so():
    prog = program("G21 G90 F600\n#1=0\nO100 while [#1 LT 3]\nM3\nG1 X[10+#1*10] Y10\nM5\nG0 Y0\n#1=[#1+1]\n"
                   "O100 endwhile\nM2\n")
    r = run_from_line(prog, 5, HEAD)
    assert "runs 3 times in a loop or subroutine: from its first pass" in r.description
    assert r.program.segments[1]["end"][0] == pytest.approx(10.0)


def test_a_restarted_programs_figures_are_counted_as_the_interpreter_counts_them():
    from cnc.planner.recovery import _statistics

    prog = program()
    st = _statistics(prog.segments, prog.stats.lines)
    assert (st.pierces, st.segments) == (prog.stats.pierces, prog.stats.segments)
    for name in ("cut_length_mm", "feed_length_mm", "rapid_length_mm", "dwell_s"):
        assert getattr(st, name) == pytest.approx(getattr(prog.stats, name)), name


@pytest.mark.parametrize("seed", [3, 6, 12, 29])  # 6 stops on an arc, 29 while piercing
def test_random_cam_parts_stopped_anywhere_continue_within_the_overlap_and_cut_the_rest(seed):
    """Random CAM parts (`test_planner_overlap._random_cam_parts`, cut with the jet) run by the
    planner and stopped at a random tick with the jet open; "continue" from the last record the jet
    was open on (as the servo notes it) starts, through the planner again, where the overlap before
    that point says (never past the cut's pierce; piercing: that pierce again) and cuts all the rest
    of the program, keeping the limits and P. 380 seeds of this ran clean (2026-12-07)."""
    import random

    from .test_planner_motion import JET, records_of, within_limits, within_tolerance
    from .test_planner_overlap import _random_cam_parts

    rng = random.Random(seed * 31 + 7)
    text, chunk = _random_cam_parts(seed, jet=True)
    prog = Interpreter(dialect_for(CONFIG), "parts.ngc").run(text.encode())
    seg = prog.segments
    plain = records_of(prog, CONFIG, 64)
    stopped = records_of(prog, CONFIG, 64, (int(rng.choice(np.flatnonzero(plain["flags"] & JET))), "stop"))
    last = np.flatnonzero(stopped["flags"] & JET)[-1]
    k, point = int(stopped["segment"][last]), tuple(stopped["position"][last])
    overlap = rng.choice([0.5, 2.0, 5.0, 30.0])
    r = continue_at(prog, k, point, overlap, (*stopped["position"][-1], 0.0))
    again = records_of(r.program, CONFIG, chunk)
    within_limits(again)
    assert (within_tolerance(r.program, again) <= 1e-9).all()
    start = r.segment  # the cut's pierce: the first of its jet-on segments
    while start > 0 and seg[start - 1]["jet"] and int(seg[start - 1]["kind"]) != RAPID:
        start -= 1
    at = sum(segment_length(s) for s in seg[start:r.segment]) + r.into_mm  # where it starts again, along the cut
    if "was complete" in r.description:  # stopped at the very end of a cut: the next one from its pierce
        assert locate(seg[k], point) >= segment_length(seg[k]) - 1e-6 and r.segment in cut_starts(prog) and r.segment > k
    elif int(seg[k]["kind"]) == DWELL:
        assert (r.segment, r.into_mm) == (start, 0.0), "stopped while piercing: that pierce again"
    else:
        stop = sum(segment_length(s) for s in seg[start:k]) + locate(seg[k], point)
        assert at == pytest.approx(max(stop - overlap, 0.0), abs=float(seg[k]["tolerance"])), "the overlap back, not past the pierce"
    rest = sum(segment_length(s) for s in seg[r.segment:] if s["jet"] and int(s["kind"]) not in (RAPID, DWELL)) - r.into_mm
    assert cut_length(r.program) == pytest.approx(rest, abs=1e-9), "all the rest is cut"
    assert (again["flags"] & JET).any(), "and the jet opens for it"


def test_a_restart_from_the_first_line_counts_its_figures_as_the_interpreter_counted_the_program():
    """A restart's figures (cut, feed and rapid lengths, pierces, dwell, bounds) are counted over
    the whole program at once; from the program's first line with the head where it starts, they
    are the interpreter's own, on every shape: kerf-compensated nests with subroutines and inch
    parts, arcs of several turns, jet-on dwells, random CAM parts with the jet and without."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from bench.nests import cam_nest, production_nest

    from cnc.planner.recovery import segment_lengths
    from .test_planner_overlap import _random_cam_parts

    texts = [NEST, cam_nest(40), cam_nest(30, subroutines=True, inch_every=3), production_nest(30)]
    texts += [_random_cam_parts(seed, jet=seed % 2 == 0)[0] for seed in range(40)]
    for text in texts:
        prog = program(text)
        seg = prog.segments
        assert segment_lengths(seg) == pytest.approx([segment_length(s) for s in seg], rel=1e-12, abs=1e-12)
        r = run_from_line(prog, 1, tuple(float(v) for v in seg[0]["start"]))
        got, want = r.program.stats, prog.stats
        assert got.pierces == want.pierces and len(cut_starts(r.program)) == len(cut_starts(prog))
        for figure in ("cut_length_mm", "feed_length_mm", "rapid_length_mm", "dwell_s"):
            assert getattr(got, figure) == pytest.approx(getattr(want, figure), rel=1e-9, abs=1e-9), figure
        assert got.bounds_min == pytest.approx(want.bounds_min) and got.bounds_max == pytest.approx(want.bounds_max)
