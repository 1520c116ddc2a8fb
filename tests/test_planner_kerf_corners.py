"""The corner kerf compensation makes where a part is entered: a lead-in, a kink of a few degrees,
and an arc of the kerf's radius around the contour's first point. The planner folds such a small
arc into one corner within G64 P (`sections._fold_small_arcs`), which a corner overlap passes,
instead of stopping at the kink and crawling through the arc."""

from __future__ import annotations

import dataclasses
import math
import random
import numpy as np
import pytest

from gcode.canon import ARC
from gcode.interp import interpret

from cnc.machine_dialect import dialect_for
from cnc.planner.path import Element, LINE
from cnc.planner.sections import Section, _folded_corner, iter_steps

from .conftest import machine_config
from .test_planner_motion import run, runs_clean, speed, within_limits, within_tolerance

KERF_RADIUS = 0.125  # D1 of the shipped machine: half of its 0.25 mm kerf


def _right(d: tuple[float, float]) -> tuple[float, float]:
    return d[1], -d[0]


def _left(d: tuple[float, float]) -> tuple[float, float]:
    return -d[1], d[0]


def _entry(side: str = "G41", heading_deg: float = 90.0, p: float = 0.05, feed: float = 2400.0,
           at: tuple[float, float] = (300.0, 300.0)) -> str:
    """A part entered as a CAM nest enters it: a rapid, the jet on and its pierce dwell, a 3 mm
    lead-in along `heading_deg` with the compensation on, the contour turning by a right angle
    away from the compensated side (to the right under G41, to the left under G42: an outside
    corner of the compensated path, so an arc of the kerf's radius) into three 2.7 mm lines and on
    around a rounded corner, the compensation off on a lead-out, the jet off."""
    turn = _right if side == "G41" else _left
    h = math.radians(heading_deg)
    u = (math.cos(h), math.sin(h))
    w = turn(u)
    v = turn(w)
    x, y = at
    lines = [f"G21 G90 G17 G64 P{p:g}", "T1 M6", f"G0 X{x - 3.0 * u[0]:.4f} Y{y - 3.0 * u[1]:.4f}", "M3", "G4 P0.3",
             f"{side} D1 G1 X{x:.4f} Y{y:.4f} F{feed:g}"]
    for _ in range(3):
        x, y = x + 2.7 * w[0], y + 2.7 * w[1]
        lines.append(f"G1 X{x:.4f} Y{y:.4f}")
    r = 2.2
    ex, ey = x + r * (w[0] + v[0]), y + r * (w[1] + v[1])
    lines.append(f"{'G2' if side == 'G41' else 'G3'} X{ex:.4f} Y{ey:.4f} I{r * v[0]:.4f} J{r * v[1]:.4f}")
    x, y = ex + 6.0 * v[0], ey + 6.0 * v[1]
    out = turn(turn(turn(v)))  # away from the part
    lines += [f"G1 X{x:.4f} Y{y:.4f}", f"G40 G1 X{x + 2.0 * out[0]:.4f} Y{y + 2.0 * out[1]:.4f}", "M5", "M2"]
    return "\n".join(lines) + "\n"


def _kerf_arcs(program) -> int:
    """How many arcs of the kerf's radius the compensation made (one per outside corner)."""
    seg = program.segments
    arcs = seg[seg["kind"] == ARC]
    radius = np.hypot(*(arcs["start"][:, :2] - arcs["center"]).T)
    return int(np.sum(np.abs(radius - KERF_RADIUS) < 1e-6))


def _sections(text: str, config) -> list[Section]:
    program = interpret(text, dialect_for(config))
    return [s for s in iter_steps(program, config) if isinstance(s, Section)]


def _has_kerf_arc(sections: list[Section]) -> bool:
    return any(e.kind == ARC and abs(math.dist(e.start[:2], e.center) - KERF_RADIUS) < 1e-6
               for s in sections for e in s.elements)


def _lowest_speed_near(records, point: tuple[float, float], within_mm: float = 1.0) -> float:
    near = np.hypot(*(records["position"][:, :2] - np.asarray(point)).T) < within_mm
    moving = speed(records)[near]
    return float(moving[moving > 0.0].min())


def _time_near(records, point: tuple[float, float], within_mm: float = 1.0) -> int:
    """Servo periods the head spends within `within_mm` of the point."""
    return int(np.sum(np.hypot(*(records["position"][:, :2] - np.asarray(point)).T) < within_mm))


@pytest.mark.parametrize("side,heading,feed", [("G41", 90.0, 2400.0), ("G42", 30.0, 2400.0), ("G41", 200.0, 12000.0),
                                               ("G42", 315.0, 30000.0)])
def test_the_kerf_arc_at_a_part_s_entry_is_folded_into_a_corner_passed_faster_within_p(side, heading, feed):
    """Kept, the arc makes the head stop at the kink before it and crawl through it (about 10 mm/s
    at r = 0.125 mm: its centripetal jerk). Folded into one corner, the corner overlap passes it:
    faster and sooner, every axis within its limits, every record within P of the compensated path
    as programmed (the arc included), the planned time the one run. `[planner] corner_move_share
    = 0` keeps the arc."""
    text = _entry(side, heading, feed=feed)
    program, _, records, planned = run(text, chunk=37)
    assert _kerf_arcs(program) == 1
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    kept = machine_config(**{"planner.corner_move_share": 0.0})
    assert not _has_kerf_arc(_sections(text, machine_config())), "folded"
    assert _has_kerf_arc(_sections(text, kept)), "kept"
    _, _, crawled, planned_kept = run(text, kept, chunk=37)
    assert len(crawled) == planned_kept
    corner = program.segments[program.segments["kind"] == ARC][0]["center"]
    assert _lowest_speed_near(crawled, corner) < 12.0, "the arc's crawl"
    assert _time_near(records, corner) < 0.8 * _time_near(crawled, corner), "through the corner sooner"
    assert len(crawled) - len(records) >= 40, "sooner by tens of milliseconds"


def test_an_arc_that_does_not_slow_the_head_is_not_folded():
    """A lead-in with a kink into an arc of 5 mm: the head runs it at its feed, so it is a curve
    to follow, not a corner; at a tolerance too tight for the fold (P 0.005: where the lead-in and
    the contour's line meet lies 0.055 mm off the kerf arc), the kerf arc is kept too. Both within P."""
    config = machine_config()
    text = "\n".join(["G21 G90 G17 G64 P0.05", "G0 X300 Y297", "M3", "G1 X299.8 Y300 F2400",
                      "G2 X305 Y305.2 I5.2 J0", "G1 X310 Y305.2", "M5", "M2"]) + "\n"
    assert any(e.kind == ARC and abs(math.dist(e.start[:2], e.center) - 5.2) < 1e-6
               for s in _sections(text, config) for e in s.elements)
    program, _, records, planned = run(text, chunk=37)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    tight = _entry("G41", 90.0, p=0.005)
    assert _has_kerf_arc(_sections(tight, config)), "kept under P 0.005"
    program, _, records, planned = run(tight, chunk=37)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned


def test_a_folded_corner_never_leaves_the_travel():
    """The corner is sought between the arc and where the two lines meet (G64 P0.1 here); a point
    beyond the travel is never taken, even where the lines would stray least (the travel ending
    0.035 mm short of the arc); where none inside it keeps within P, the arc is kept."""
    config = machine_config()
    lead_in = Element(LINE, (300.0, 297.0, 0.0), (299.875, 300.0, 0.0), None, False, 0, 40.0, 0.1, True, 0, 0, 1, 1)
    arc = Element(ARC, (299.875, 300.0, 0.0), (300.0, 300.125, 0.0), (300.0, 300.0), True, 0, 40.0, 0.1, True, 0, 0, 2, 2)
    contour = Element(LINE, (300.0, 300.125, 0.0), (302.7, 300.125, 0.0), None, False, 0, 40.0, 0.1, True, 0, 0, 3, 2)
    free = _folded_corner(lead_in, arc, contour, True, False, config)
    assert free is not None and free[0].end[0] < 299.905, "where it strays least, 0.1 mm before the arc's end"
    edge = 299.91
    bounded = _folded_corner(lead_in, arc, contour, True, False, _travel_from(config, edge))
    assert bounded is not None and edge <= bounded[0].end[0] < 300.0, "the nearest the travel allows"
    assert _folded_corner(lead_in, arc, contour, True, False, _travel_from(config, 299.99)) is None, \
        "none inside the travel keeps within P"


def _travel_from(config, x_min: float):  # noqa: ANN202 - a MachineConfig
    """The machine with its X travel starting at `x_min` (the machine file's homing would be outside it)."""
    return dataclasses.replace(config, axis={**config.axis, "x": dataclasses.replace(config.axis["x"], travel_min_mm=x_min)})


def _random_compensated_parts(seed: int) -> tuple[str, int]:
    """One to three parts under G41 or G42 at random, entered by a lead-in at a random heading and
    angle: polygons whose corners turn either way, or curves in chords a few degrees apart, so
    that the kerf arcs fall at the entries, at outside corners and between chords; a random feed,
    P and take size."""
    rng = random.Random(seed)
    feed = rng.choice([600, 2400, 6000, 12000, 30000])
    lines = [f"G21 G90 G17 G64 P{rng.choice([0.005, 0.02, 0.05, 0.2]):g}", "T1 M6", "G0 X300 Y300"]
    x = y = 300.0
    for _ in range(rng.randint(1, 3)):
        side = rng.choice(["G41", "G42"])
        x, y = x + rng.uniform(-30.0, 30.0), y + rng.uniform(-30.0, 30.0)
        heading = rng.uniform(0.0, 2.0 * math.pi)
        lead = rng.uniform(1.0, 4.0)
        lines += [f"G0 X{x - lead * math.cos(heading):.4f} Y{y - lead * math.sin(heading):.4f}", "M3", "G4 P0.1",
                  f"{side} D1 G1 X{x:.4f} Y{y:.4f} F{feed}"]
        direction = heading + rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(30.0), math.radians(150.0))
        curve = rng.random() < 0.5  # a curve in chords (turns of a few degrees, one way) or a polygon
        bend = rng.choice([-1.0, 1.0])
        for _ in range(rng.randint(8, 30) if curve else rng.randint(3, 7)):
            length = rng.uniform(0.5, 3.0) if curve else rng.uniform(2.0, 15.0)
            x, y = x + length * math.cos(direction), y + length * math.sin(direction)
            lines.append(f"G1 X{x:.4f} Y{y:.4f}")
            direction += bend * rng.uniform(math.radians(2.0), math.radians(15.0)) if curve else \
                rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(20.0), math.radians(150.0))
        out = direction + rng.uniform(-1.0, 1.0)
        lines += [f"G40 G1 X{x + 2.0 * math.cos(out):.4f} Y{y + 2.0 * math.sin(out):.4f}", "M5"]
    return "\n".join(lines + ["M2"]) + "\n", rng.choice([1, 7, 50, 997])


@pytest.mark.parametrize("seed", range(8))
def test_random_compensated_parts_keep_every_limit_and_p_and_time_exactly(seed):
    """Random parts under kerf compensation, plain and, for every other seed, under the operator's
    controls at random (holds, overrides 0-200 %, a stop): every axis within its limits, every record
    within P of the compensated path as programmed, the planned time the one run."""
    text, chunk = _random_compensated_parts(seed)
    runs_clean(text, chunk, seed if seed % 2 == 0 else None)


def _chord_circle(side: str, chords: int = 60, radius: float = 20.0) -> str:
    """A circle in chords cut clockwise, its kerf compensated by the controller: on the outside
    under G41 (an arc of the kerf's radius at every vertex), on the inside under G42 (none)."""
    points = [(300.0 + radius * math.sin(2.0 * math.pi * k / chords), 300.0 - radius + radius * math.cos(2.0 * math.pi * k / chords))
              for k in range(chords + 1)]
    x0, y0 = points[0]
    body = [f"G1 X{x:.4f} Y{y:.4f}" for x, y in points[1:]]
    return "\n".join(["G21 G90 G17 G64 P0.05", f"G0 X{x0:.4f} Y{y0 + 3.0:.4f}", f"{side} D1 G1 X{x0:.4f} Y{y0:.4f} F2400",
                      *body, f"G40 G1 X{x0 + 2.0:.4f} Y{y0 + 3.0:.4f}", "M2"]) + "\n"


def test_a_curve_in_chords_compensated_on_its_outside_runs_as_fast_as_on_its_inside():
    """Compensated on the outside, each vertex of a chord circle gets an arc of the kerf's radius
    a few degrees long; the head held to its centripetal jerk crawled through each (8.5 s against
    3.4 s). The corner of two chords lies a fraction of a micrometre off such an arc: folded, it is
    blended as on the inside (`sections._fold_small_turns`), within P of the compensated path as
    programmed, every axis within its limits, the planned time the one run."""
    outside, _, records, planned = run(_chord_circle("G41"), chunk=61)
    assert _kerf_arcs(outside) == 59
    within_limits(records)
    assert (within_tolerance(outside, records) <= 1e-9).all()
    assert len(records) == planned
    inside, _, inside_records, _ = run(_chord_circle("G42"), chunk=61)
    assert _kerf_arcs(inside) <= 1
    assert len(records) <= 1.02 * len(inside_records), "as fast as on the inside, within 2 %"
    _, _, crawled, planned_kept = run(_chord_circle("G41"), machine_config(**{"planner.corner_move_share": 0.0}), chunk=61)
    assert len(crawled) == planned_kept
    assert len(crawled) > 2.0 * len(records), "kept, the arcs were crawled through"


# (kept, the arcs' sections take a longer axis average, `sections._longer_averages`: 55-60 ms sooner than
# with their own, 0.354 / 0.269 / 0.179 s behind the folded corners at 45 / 60 / 90 degrees before it)
@pytest.mark.parametrize("turn_deg,faster_than_kept_s", [(30.0, 0.8), (45.0, 0.25), (60.0, 0.18), (90.0, 0.1)])
def test_a_polygon_compensated_on_its_outside_passes_its_corners_in_overlaps(turn_deg, faster_than_kept_s):
    """Compensated on the outside, every corner of a polygon is an arc of the kerf's radius; it is
    folded into one corner, where the two edges meet (turns up to about 70 degrees at P 0.05 with
    this kerf) or, at a right angle, between the arc and there, an edge tilted a hair about its
    far end; the edges, sections of their own between two such corners, pass each in an overlap
    as on the inside: sooner than crawling through the arcs, every axis within its limits, every
    record within P of the path as programmed."""
    n = int(round(360.0 / turn_deg))
    points = [(300.0 + 20.0 * math.cos(math.radians(-turn_deg * k)), 300.0 + 20.0 * math.sin(math.radians(-turn_deg * k)))
              for k in range(n + 1)]
    x0, y0 = points[0]
    text = "\n".join(["G21 G90 G17 G64 P0.05", f"G0 X{x0 + 3.0:.4f} Y{y0 - 3.0:.4f}", f"G41 D1 G1 X{x0:.4f} Y{y0:.4f} F2400",
                      *[f"G1 X{x:.4f} Y{y:.4f}" for x, y in points[1:]], f"G40 G1 X{x0 + 3.0:.4f} Y{y0 + 3.0:.4f}", "M2"]) + "\n"
    program, _, records, planned = run(text, chunk=41)
    assert _kerf_arcs(program) >= n - 1, "one at every corner but the last, where G40 ends it"
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    assert not _has_kerf_arc(_sections(text, machine_config())), "every corner folded"
    _, _, kept, _ = run(text, machine_config(**{"planner.corner_move_share": 0.0}), chunk=41)
    assert (len(kept) - len(records)) * 1e-3 >= faster_than_kept_s


def test_ruling_folded_corners_out_on_coarse_samples_first_changes_no_step(monkeypatch):
    """A folded corner's candidates are ruled out on every 64th and every 8th sample of their lines
    before the whole sampling (`FOLD_COARSE_STRIDES`): those are a subset of its samples, so a
    candidate over P on them is over P on all, and the corner chosen is the same. On a slow Y,
    where every arc up to 20 mm slows the head and is tried as a corner, that made a step take a
    second; the steps, sampled both ways, are equal on slow and shipped machines, nests with
    kerf-compensated entries and random CAM parts."""
    from cnc.planner import sections
    from cnc.planner.steps import StepSource

    from .test_planner_overlap import _random_cam_parts
    from .test_recovery_cycle import SLOW_PLANNER

    whole, samplings = sections._fold_strays, []

    def counted(points, *args, stride: int = 1):
        samplings.append((stride, len(points)))
        return whole(points, *args, stride=stride)

    monkeypatch.setattr(sections, "_fold_strays", counted)
    coarse_strides = sections.FOLD_COARSE_STRIDES
    texts = [_entry(side, heading, p) for side in ("G41", "G42") for heading in (0.0, 77.0) for p in (0.05, 0.2)]
    texts += [_random_cam_parts(seed, jet=True)[0] for seed in (3, 11, 56)]
    for config in (machine_config(), machine_config(**SLOW_PLANNER)):
        dialect = dataclasses.replace(dialect_for(config), start_position_mm=(0.0, 0.0, 0.0))
        whole_samplings = {}
        for text in texts:
            program = interpret(text, dialect)
            made = []
            for strides in ((), coarse_strides):
                monkeypatch.setattr(sections, "FOLD_COARSE_STRIDES", strides)
                samplings.clear()
                steps = StepSource(iter_steps(program, config))
                steps.build_until(1 << 62)
                made.append([repr(steps.peek(i)) for i in range(steps.made)])
                whole_samplings[strides] = whole_samplings.get(strides, 0) + sum(n for stride, n in samplings if stride == 1)
            assert made[0] == made[1], text
        assert whole_samplings[()] > 0, "folded corners were tried"
        assert whole_samplings[coarse_strides] <= whole_samplings[()]
    assert whole_samplings[coarse_strides] * 4 < whole_samplings[()], "on the slow machine most are ruled out coarsely"
