"""Planner path: corners blended within the tolerance, measured against the programmed path."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from gcode.canon import ARC, LINE
from gcode.dialect import Dialect
from gcode.interp import interpret

from cnc.planner.geometry import PathArrays
from cnc.planner.path import Element, blend_corners, deviation, distance_to, elements_from_program

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

XY = Dialect(axes="xyz", default_tolerance_mm=0.05)


def path_of(text: str, dialect: Dialect = XY):
    programmed = elements_from_program(interpret(text + "M2\n", dialect).segments)
    return programmed, blend_corners(programmed)


def chained(path) -> bool:
    return all(math.dist(a.end, b.start) < 1e-9 for a, b in zip(path, path[1:]))


def test_a_right_angle_corner_is_blended_to_exactly_half_the_tolerance():
    programmed, path = path_of("G64 P0.1\nG1 X100 Y0 F6000\nG1 X100 Y100\n")
    assert [e.kind for e in path] == [LINE, ARC, LINE] and path[1].blend
    r = 0.05 / (1.0 - math.cos(math.pi / 4))  # the other half of P is the planner's smoothing
    cx, cy = path[1].center
    assert math.hypot(path[1].start[0] - cx, path[1].start[1] - cy) == pytest.approx(r)
    dev = deviation(path, programmed, step_mm=0.001)
    assert dev.max() <= 0.05 + 1e-9 and dev.max() == pytest.approx(0.05, abs=1e-3), "the bound is used, not wasted (to the sampling step)"
    assert chained(path)


def test_exact_stop_mode_keeps_every_corner():
    programmed, path = path_of("G61\nG1 X10 F600\nG1 Y10\nG1 X0\n")
    assert len(path) == len(programmed) == 3 and not any(e.blend for e in path)
    assert deviation(path, programmed).max() < 1e-12


def test_blends_never_overlap_on_short_segments():
    programmed, path = path_of("G64 P5\nG1 X1 F600\nG1 Y1\nG1 X2\nG1 Y2\n")
    lines = [e for e in path if e.kind == LINE]
    assert all(e.length_mm >= -1e-12 for e in lines)
    assert chained(path) and deviation(path, programmed, 0.001).max() <= 5.0


def test_no_blend_where_the_jet_switches_or_at_a_reversal():
    _, path = path_of("G64 P0.5\nG1 X10 F600\nM3\nG1 Y10\nM5\n")
    assert not any(e.blend for e in path), "the jet switches exactly at the corner"
    _, path = path_of("G64 P0.5\nG1 X10 F600\nG1 X0\n")
    assert not any(e.blend for e in path), "a reversal is a stop"
    _, path = path_of("G64 P0.5\nG1 X10 F600\nG2 X20 Y0 R5\nG3 X30 Y0 R5 M3\n")
    assert sum(e.blend for e in path) == 1, "the line-arc kink blends; the jet switching at the arc-arc kink stops"


@pytest.mark.parametrize("text", [
    "G1 X10 F600\nG2 X20 Y0 R5\n",  # line into an arc, 90 degrees, the turn to the arc's outside
    "G1 X10 F600\nG3 X20 Y0 R5\n",  # ... and to its inside
    "G3 X10 Y0 R5 F600\nG1 Y-10\n",  # an arc into a line
    "G2 X10 Y0 R5 F600\nG2 X20 Y0 R5\n",  # arc into arc, both clockwise: a cusp of 180 degrees is a stop
    "G2 X10 Y0 R6 F600\nG3 X20 Y0 R7\n",  # arc into arc, an S with a kink
    "G1 X10 Y1 F600\nG3 X14 Y5 R4.5\nG1 X14 Y20\nG2 X30 Y20 R8.5\n",  # a chain of small kinks
])
def test_a_kink_between_an_arc_and_a_line_or_two_arcs_blends_within_half_the_tolerance(text):
    programmed, path = path_of("G64 P0.1\nG1 X0 Y0 F600\n" + text)
    assert chained(path)
    assert deviation(path, programmed, step_mm=0.0005).max() <= 0.05 + 1e-6, "the smoothing keeps the other half"
    for e in path:
        if e.kind == ARC and e.blend:  # tangent to both neighbours: no kink left
            i = path.index(e)
            for u, v in ((path[i - 1].direction_at_end(), e.direction_at_start()),
                         (e.direction_at_end(), path[i + 1].direction_at_start())):
                assert u[0] * v[0] + u[1] * v[1] > 1.0 - 1e-9
    kinks = sum(1 for a, b in zip(programmed, programmed[1:])
                if a.direction_at_end()[0] * b.direction_at_start()[0] + a.direction_at_end()[1] * b.direction_at_start()[1]
                < math.cos(1e-6) and a.direction_at_end()[0] * b.direction_at_start()[0]
                + a.direction_at_end()[1] * b.direction_at_start()[1] > math.cos(math.pi - 1e-3))
    assert sum(e.blend for e in path) == kinks, "every kink but a reversal blends"


def test_a_nest_of_chords_and_arcs_blends_every_kink_within_its_tolerance():
    """The nest's round parts: lines and R arcs around a circle, every junction a small kink."""
    rng = random.Random(5)
    text = ["G64 P0.05", "G1 X0 Y0 F3000"]
    for part in range(6):
        cx, cy, rad = 50 * part, 0.0, rng.uniform(8, 18)
        n = rng.randint(24, 60)
        text.append(f"G1 X{cx + rad:.4f} Y{cy:.4f}")
        for k in range(1, n + 1):
            a = 2 * math.pi * k / n
            x, y = cx + rad * math.cos(a), cy + rad * math.sin(a)
            text.append(f"G3 X{x:.4f} Y{y:.4f} R{rad * 1.02:.4f}" if k % 3 == 0 else f"G1 X{x:.4f} Y{y:.4f}")
    programmed, path = path_of("\n".join(text) + "\n")
    arcs_in = sum(1 for e in programmed if e.kind == ARC)
    blended_at_arcs = sum(1 for i, e in enumerate(path) if e.blend and (path[i - 1].kind == ARC and not path[i - 1].blend
                                                                         or path[i + 1].kind == ARC))
    assert chained(path) and blended_at_arcs >= 1.5 * arcs_in, "both ends of nearly every arc blend"
    assert deviation(path, programmed, 0.004).max() <= 0.025 + 1e-6


def test_cam_polyline_corners_all_blend_within_their_tolerance():
    rng = random.Random(4)
    x = y = 0.0
    heading = 0.0
    text = ["G64 P0.02", "G1 X0 Y0 F3000"]
    for _ in range(300):
        heading += rng.uniform(-0.6, 0.6)
        step = rng.uniform(0.3, 3.0)
        x, y = x + step * math.cos(heading), y + step * math.sin(heading)
        text.append(f"G1 X{x:.4f} Y{y:.4f}")
    programmed, path = path_of("\n".join(text) + "\n")
    blends = [e for e in path if e.blend]
    assert len(blends) > 250, "nearly every corner of a CAM polyline is blended"
    assert chained(path)
    assert deviation(path, programmed, 0.002).max() <= 0.01 + 1e-9


def test_the_path_keeps_segment_and_line_for_progress():
    _, path = path_of("G64 P0.1\nG1 X10 F600\nG1 Y10\n")
    assert [e.line for e in path] == [2, 3, 3] and [e.segment for e in path] == [0, 1, 1]
    assert all(e.feed_mm_s == pytest.approx(10.0) for e in path)


def test_the_distance_to_an_arc_whose_end_is_off_its_circle_follows_the_spiral_it_is_run_as():
    """An arc is run as a spiral from its start's radius to its end's (`PathArrays.points`); the
    checks within P (a corner's overlap, a blend) measure against the same spiral. Against the
    start's circle, an end 2 um off its circle let a point on the run path read 2 um off it."""
    r0, r1 = 10.0, 10.002
    arc = Element(ARC, (10.0, 0.0, 0.0), (0.0, r1, 0.0), (0.0, 0.0), False, 0, math.inf, 0.05, False, 0, 0, 0, 1)  # a quarter turn, CCW
    path = PathArrays.of([arc])
    on_run_path = path.points(np.linspace(0.0, path.total_mm, 9))[:, :2]
    assert distance_to(on_run_path, [arc]).max() < 1e-9
    halfway = np.array([[math.cos(math.pi / 4) * (r0 + 0.001), math.sin(math.pi / 4) * (r0 + 0.001)]])
    assert distance_to(halfway, [arc])[0] == pytest.approx(0.0, abs=1e-9)
    outside = np.array([[0.0, r1 + 0.005]])  # at the end, 5 um outside
    assert distance_to(outside, [arc])[0] == pytest.approx(0.005, abs=1e-9)
    several = Element(ARC, arc.start, arc.end, arc.center, False, 2, math.inf, 0.05, False, 0, 0, 0, 1)  # two more turns
    beyond = np.array([[r0 + 0.0005, 0.0]])  # a hair outside where the first turn starts
    assert distance_to(beyond, [several])[0] <= 0.0005 + 1e-9
