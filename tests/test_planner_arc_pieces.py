"""Long arcs cut into pieces for their caps: the middle of an arc runs at what its curvature
allows, only its head and tail at what the curvature steps at its ends allow."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcode.canon import ARC, LINE
from gcode.interp import interpret

from cnc.machine_dialect import dialect_for
from cnc.planner.geometry import PathArrays
from cnc.planner.limits import arc_pieces_for_caps
from cnc.planner.path import Element, arc_pieces
from cnc.planner.sections import Section, iter_steps

from .conftest import machine_config
from .test_planner_motion import _xyz_machine, run, speed, within_limits, within_tolerance

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

# a straight, a half circle of R10 and a straight back, at 500 mm/s under G64 P0.005 (the paper's
# test contour's kind of corner): the curvature steps by 1/10 at both ends of the arc
U_TURN = "G21 G90 G64 P0.005\nG0 X100 Y100\nF30000\nG1 X200 Y100\nG3 X200 Y120 I0 J10\nG1 X100 Y120\nM2\n"


def arc(start, end, center, cw=False, turns=0, tolerance=0.05, feed=500.0, blend=False) -> Element:
    return Element(ARC, start, end, center, cw, turns, feed, tolerance, False, 0, 0, 7, 3, 0.0, blend)


def line(start, end, tolerance=0.05, feed=500.0) -> Element:
    return Element(LINE, start, end, None, False, 0, feed, tolerance, False, 0, 0, 6, 2)


@pytest.mark.parametrize("whole", [
    arc((10.0, 0.0, 0.0), (0.0, 10.0, 0.0), (0.0, 0.0)),  # a quarter, counter-clockwise
    arc((10.0, 0.0, 0.0), (0.0, -10.0, 0.0), (0.0, 0.0), cw=True),  # a quarter, clockwise
    arc((10.0, 0.0, 0.0), (10.0, 0.0, 0.0), (0.0, 0.0)),  # a full circle: its ends are one point
    arc((10.0, 0.0, 0.0), (10.0, 0.0, 0.0), (0.0, 0.0), cw=True),
    arc((5.0, 0.0, 0.0), (-5.0, 0.0, -2.0), (0.0, 0.0), cw=True),  # half a helix turn
])
@pytest.mark.parametrize("fractions", [[0.5], [0.01, 0.99], [0.2, 0.5, 0.9]])
def test_arc_pieces_are_the_arc_point_for_point_and_tangent_where_they_meet(whole, fractions):
    pieces = arc_pieces(whole, fractions)
    assert len(pieces) == len(fractions) + 1
    assert pieces[0].start == whole.start and pieces[-1].end == whole.end
    assert sum(p.sweep_rad for p in pieces) == pytest.approx(whole.sweep_rad, rel=1e-12)
    assert sum(p.length_mm for p in pieces) == pytest.approx(whole.length_mm, rel=1e-12)
    for a, b in zip(pieces, pieces[1:]):
        assert a.end == b.start
        assert a.direction_at_end() == pytest.approx(b.direction_at_start(), abs=1e-12)
    assert all((p.segment, p.line, p.cw, p.center) == (whole.segment, whole.line, whole.cw, whole.center) for p in pieces)
    # the same points at the same arc lengths, the pieces one after the other against the whole
    s = np.linspace(0.0, whole.length_mm, 97)
    assert PathArrays.of(pieces).points(s) == pytest.approx(PathArrays.of([whole]).points(s), abs=1e-9)


def test_the_pieces_of_an_arc_ending_a_hair_off_its_circle_follow_its_radius_as_the_whole_does():
    """A program's arc (end and centre rounded to 4 decimals) ends a little off the circle of its
    start: the planner runs it with the radius changing along it. Its pieces change it alike,
    so their ends lie on the whole arc's path, not on the start's circle."""
    whole = arc((78.7, 0.0, 0.0), (0.0, 78.7001, 0.0), (0.0, 0.0))
    pieces = arc_pieces(whole, [0.1, 0.6])
    s_whole = PathArrays.of([whole])
    for piece, f in zip(pieces[1:], (0.1, 0.6)):
        on_whole = s_whole.points(np.array([f * whole.length_mm]))[0]
        assert piece.start == pytest.approx(tuple(on_whole), abs=1e-12)
        assert math.hypot(*piece.start[:2]) == pytest.approx(78.7 + 0.0001 * f, abs=1e-12)


def test_an_arc_is_cut_only_where_its_middle_can_run_apart_from_its_ends():
    config = machine_config()
    long_arc = arc((10.0, 0.0, 0.0), (-10.0, 0.0, 0.0), (0.0, 0.0))  # a half circle of R10, 31 mm
    pieces, origin = arc_pieces_for_caps([line((10.0, -20.0, 0.0), (10.0, 0.0, 0.0)), long_arc], config)
    assert [p.kind for p in pieces] == [LINE, ARC, ARC, ARC] and origin.tolist() == [0, 1, 1, 1]
    head, middle, tail = pieces[1:]
    assert head.length_mm == pytest.approx(tail.length_mm) and middle.length_mm > head.length_mm
    # what stays whole: an arc shorter than its head and tail, a corner blend, several turns, G61
    short = arc((10.0, 0.0, 0.0), (9.9995, 0.1, 0.0), (0.0, 0.0))
    blend = arc((10.0, 0.0, 0.0), (-10.0, 0.0, 0.0), (0.0, 0.0), blend=True)
    turns = arc((10.0, 0.0, 0.0), (-10.0, 0.0, 0.0), (0.0, 0.0), turns=2)
    exact = arc((10.0, 0.0, 0.0), (-10.0, 0.0, 0.0), (0.0, 0.0), tolerance=0.0)
    for stays in ([short], [blend], [turns], [exact]):
        kept, origin = arc_pieces_for_caps(stays, config)
        assert kept == stays and origin.tolist() == [0]


def test_the_middle_of_a_long_arc_runs_faster_than_where_its_curvature_steps_within_every_limit():
    """The Fig. 10 kind of contour: whole, the half circle took the steps at both its ends over
    all its length (V = 2/R) and ran at 64 mm/s; in pieces its middle runs at what its normal
    acceleration and deviation allow, its ends as before. At 100 % and 200 % override."""
    config = machine_config()
    program, runner, records, planned = run(U_TURN, config)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    on_arc = records["segment"] == int(np.flatnonzero(program.segments["kind"] == ARC)[0])
    v = speed(records)
    centre = np.array([200.0, 110.0])
    angle = np.degrees(np.arctan2(*(records["position"][:, :2] - centre).T[::-1]))  # -90 at the start, 90 at the end
    ends = on_arc & (np.abs(angle) > 80.0)
    middle = on_arc & (np.abs(angle) < 30.0)
    assert v[middle].max() > 1.3 * v[ends].max(), (v[middle].max(), v[ends].max())
    sections = [s for s in iter_steps(program, config) if isinstance(s, Section)]
    assert sum(e.kind == ARC for s in sections for e in s.elements) == 3  # head, middle, tail
    # 200 %: the arc's caps hold at any override
    _, _, fast, _ = run(U_TURN, config, actions={0: lambda r: r.set_override(2.0)})
    within_limits(fast)


def test_a_helix_in_pieces_keeps_every_axis_limit_on_an_xyz_machine():
    config = _xyz_machine()
    text = "G21 G90 G64 P0.01\nG0 X0 Y0 Z0\nF12000\nG1 X40 Y0\nG3 X40 Y40 I0 J20 Z-6\nG1 X0 Y40\nM2\n"
    program = interpret(text, dialect_for(config))
    assert sum(e.kind == ARC for s in iter_steps(program, config) if isinstance(s, Section) for e in s.elements) == 3
    program, runner, records, planned = run(text, config)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    assert records["position"][-1] == pytest.approx(program.segments["end"][-1], abs=1e-9)
    # Z follows the helix: down 6 mm along the arc's length, linearly
    on_arc = records["segment"] == int(np.flatnonzero(program.segments["kind"] == ARC)[0])
    xy = records["position"][on_arc]
    turned = np.arctan2(xy[:, 1] - 20.0, xy[:, 0] - 40.0) + math.pi / 2.0
    assert xy[:, 2] == pytest.approx(-6.0 * turned / math.pi, abs=0.02)
