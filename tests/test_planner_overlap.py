"""Corner overlaps: the next section starts while the last one still slows down (`cnc/planner/overlap.py`).

Each test runs a program through the real interpreter and the planner's runner and measures the
setpoint records the servo would get: every axis within its limits, every record within G64 P of
the program, the planned cycle time the one run, and the operator's controls in an overlap acting
when it ends.
"""

from __future__ import annotations

import functools
import math
import random

import numpy as np
import pytest

from gcode.interp import interpret

from cnc.config import ConfigError
from cnc.machine_dialect import dialect_for
from cnc.planner.runner import ProgramRunner, RunState

from .conftest import machine_config
from .test_planner_motion import DT, JET, LIMITS, _operator_at_random, run, runs_clean, speed, within_limits, within_tolerance

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

SQUARE = "G21 G90 G64 P{p}\nG1 X{x0} Y{y0} F{f}\nG1 X{x1}\nG1 Y{y1}\nG1 X{x0}\nG1 Y{y0}\nM2\n"


def square(p: float = 0.05, feed: float = 12000.0, size: float = 100.0) -> str:
    return SQUARE.format(p=p, f=feed, x0=0.0, y0=0.0, x1=size, y1=size)


def corner_speeds(records, corners) -> list[float]:
    """The head's lowest speed within 1 mm of each corner."""
    xy, v = records["position"][:, :2], speed(records)
    return [float(v[np.hypot(*(xy - np.asarray(c)).T) < 1.0].min()) for c in corners]


NO_OVERLAP = {"planner.corner_overlap_ms": 0.0}
NO_CONNECTION = {"planner.corner_connection_ms": 0.0}  # the overlap's own choices, measured without connections
SQUARE_CORNERS = [(100.0, 0.0), (100.0, 100.0), (0.0, 100.0)]


@pytest.mark.parametrize("feed,p", [(12000.0, 0.05), (30000.0, 0.05), (30000.0, 0.005), (2400.0, 0.05)])
def test_a_corner_with_nothing_switching_is_overlapped_within_every_limit_and_p(feed, p):
    """A square's sharp corners: the head no longer stops at them, yet every axis keeps its limits,
    every record stays within P of the program, and the planned time is the one run."""
    program, runner, records, planned = run(square(p, feed), chunk=37)
    _, _, stopping, _ = run(square(p, feed), machine_config(**NO_OVERLAP), chunk=37)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned, "the planned cycle time counts the overlaps"
    assert records["position"][-1] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert min(corner_speeds(records, SQUARE_CORNERS)) > 0.0, "never at rest at a corner"
    assert max(corner_speeds(stopping, SQUARE_CORNERS)) == 0.0, "with no overlap, at rest at each"
    saved = len(stopping) - len(records)
    assert 3 <= saved <= 3 * machine_config().planner.corner_overlap_ms / 1000.0 / DT, "at most the overlap at each"


def test_the_overlap_at_200_percent_override_keeps_every_limit():
    """Checked on the samples as they are: at 200 % the motions into and out of the corner are
    faster, and the overlap the check allows is what keeps the sum within the limits."""
    program, runner, records, _ = run(square(0.05, 6000.0), actions={0: lambda r: r.set_override(2.0)}, chunk=11)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert min(corner_speeds(records, SQUARE_CORNERS)) > 0.0
    assert speed(records).max() == pytest.approx(200.0, rel=1e-6), "200 % of F6000"


@pytest.mark.parametrize("text,why", [
    ("G21 G90 G61\nG1 X100 F12000\nG1 Y100\nM2\n", "G61: an exact stop"),
    ("G21 G90 G64 P0.05\nG1 X100 F12000\nM3\nG1 Y100\nM5\nM2\n", "the jet opens at the corner"),
    ("G21 G90 G64 P0.05\nG1 X100 F12000\nG4 P0.01\nG1 Y100\nM2\n", "a dwell at the corner"),
    ("G21 G90 G64 P0.05\nG1 X100 F12000\nM62 P0\nG1 Y100\nM2\n", "an output switches at the corner"),
])
def test_a_corner_where_something_happens_is_still_a_stop(text, why):
    program, runner, records, planned = run(text, chunk=23)
    assert len(records) == planned
    assert corner_speeds(records, [(100.0, 0.0)]) == [0.0], why
    within_limits(records)


def test_chained_overlaps_of_short_sections_never_add_three_motions_and_time_exactly():
    """A zigzag of 1.5 mm strokes at sharp turns: every section is short, so an overlap at its
    start and one at its end would meet; the second keeps clear of the first (no sample is the sum
    of three motions) and the timing makes the same choice, tick for tick, whatever the take size."""
    lines = ["G21 G90 G64 P0.05", "G1 X0 Y0 F6000"]
    for k in range(1, 30):
        lines.append(f"G1 X{1.5 * k:.3f} Y{0.0 if k % 2 == 0 else 1.0:.3f}")
    text = "\n".join(lines + ["M2"]) + "\n"
    for chunk in (1, 7, 997):
        program, runner, records, planned = run(text, chunk=chunk)
        within_limits(records)
        assert (within_tolerance(program, records) <= 1e-9).all()
        assert len(records) == planned, f"take({chunk})"
    _, _, stopping, _ = run(text, machine_config(**NO_OVERLAP))
    assert len(records) < len(stopping)


CONTROLS = {"hold": lambda r: r.hold(), "stop": lambda r: r.stop(), "override 0": lambda r: r.set_override(0.0),
            "override 200": lambda r: r.set_override(2.0), "override 10": lambda r: r.set_override(0.1)}


@pytest.mark.parametrize("control", list(CONTROLS))
@pytest.mark.parametrize("feed", [2400.0, 30000.0])
def test_a_control_in_an_overlap_acts_when_it_ends_and_every_limit_holds(control, feed):
    """The overlap's samples are committed: they come out as in a run without the control, then
    the next section's motion obeys it: a hold, a stop or 0 % bring the head to rest on the path
    within the braking distance of its speed from the overlap's end on; 10 % and 200 % go on."""
    text = square(0.05, feed)
    program, undisturbed = _undisturbed_square(feed)
    config = machine_config()
    runner = ProgramRunner(interpret(text, dialect_for(config)), config)
    made = []
    while not runner.overlap_left:
        made.append(runner.take(1)[0])
    made.append(runner.take(3)[0])  # three samples into the overlap
    given, left = sum(len(m) for m in made), runner.overlap_left
    assert left > 0
    records, shared = control_after_committed(runner, control, made, program, undisturbed, given + left)
    v = speed(records)
    if control in ("hold", "stop", "override 0"):
        assert v[-1] == 0.0 and not records["flags"][-1] & JET
        assert runner.state in {"hold": (RunState.HELD,), "stop": (RunState.ABORTED,), "override 0": (RunState.RUNNING,)}[control]
        end = records["position"][-1]
        moved = config.planner.corner_move_share * 0.05 + 1e-9  # a corner it may overlap is moved outward, within P
        assert abs(end[1]) <= moved or abs(end[0] - 100.0) <= moved, "at rest on the square's side"
        travelled = float(np.hypot(*np.diff(records["position"][shared:], axis=0).T).sum())
        peak, a, j = float(v[shared:].max()), LIMITS["acceleration"], LIMITS["jerk"]
        # the head is speeding up out of the corner: a hold lets the acceleration run out first
        # (a / J, the plateau the path average needs), then brakes, as a hold anywhere in a speed-up
        assert travelled <= peak * (a / j + 5 * DT) + peak * peak / (2.0 * a) + peak * a / (2.0 * j)
    else:
        assert runner.state == RunState.DONE and records["position"][-1] == pytest.approx([0.0, 0.0], abs=1e-9)


def control_after_committed(runner: ProgramRunner, control: str, made: list, program, undisturbed,  # noqa: ANN001
                            committed: int) -> tuple[np.ndarray, int]:
    """Press `control` (`CONTROLS`) with `committed` samples given or queued (a corner's), then
    take records until the run ends or waits for the operator: every record (`made`, those before,
    first) keeps every axis's limits and P, and the committed ones are the undisturbed run's.
    The records, and how many from the first the two runs share."""
    CONTROLS[control](runner)
    while not runner.finished:
        recs, _ = runner.take(50)
        made.append(recs)
        if not len(recs) and runner.idle:
            break
    records = np.concatenate(made)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    shared = shared_records(undisturbed, records)
    assert shared >= committed - 1, "the corner's samples are the undisturbed run's (records leave one late)"
    return records, shared


@functools.lru_cache(maxsize=None)
def _undisturbed_square(feed: float):  # noqa: ANN202 - (program, records)
    """The square run without a control, a record at a time: made once per feed for the five controls."""
    program, _, records, _ = run(square(0.05, feed), chunk=1)
    records.flags.writeable = False
    return program, records


def shared_records(undisturbed, records) -> int:
    """How many records, from the first, two runs have alike."""
    n = min(len(undisturbed), len(records))
    same = np.all(np.abs(undisturbed["position"][:n] - records["position"][:n]) <= 1e-12, axis=1)
    differs = np.flatnonzero(~same)
    return int(differs[0]) if len(differs) else n


def _outside_square(records, x0: float, y0: float, size: float) -> float:
    """How far the farthest record lies outside the square (0 when none does)."""
    x, y = records["position"][:, 0], records["position"][:, 1]
    out = np.maximum.reduce([x0 - x, x - (x0 + size), y0 - y, y - (y0 + size), np.zeros(len(x))])
    return float(out.max())


@pytest.mark.parametrize("feed,p", [(12000.0, 0.05), (2400.0, 0.05), (30000.0, 0.05)])
def test_a_corner_moved_outward_within_p_is_passed_faster_and_sooner(feed, p):
    """An overlap cuts a corner on its inside. Moved outward by half of P first
    (`sections._move_stop_corners`), the corner may be cut deeper and still within P of the
    programmed one: the head uses the band on both sides of the corner, passes it faster and the
    square is cut sooner, every axis within its limits, every record within P of the program, the
    planned time the one run; `[planner] corner_move_share = 0` leaves the corners where they are.
    (Overlaps only: a connection, `connection.py`, passes some of these corners sooner still.)"""
    text = SQUARE.format(p=p, f=feed, x0=200.0, y0=200.0, x1=300.0, y1=300.0)
    corners = [(300.0, 200.0), (300.0, 300.0), (200.0, 300.0)]
    program, _, records, planned = run(text, machine_config(**NO_CONNECTION), chunk=29)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    _, _, unmoved, planned_unmoved = run(text, machine_config(**NO_CONNECTION, **{"planner.corner_move_share": 0.0}), chunk=29)
    assert len(unmoved) == planned_unmoved
    assert len(records) < len(unmoved), "sooner"
    assert min(corner_speeds(records, corners)) > max(corner_speeds(unmoved, corners)), "faster at every corner"
    # along the square (the program starts at X0 Y0 and comes to it diagonally)
    on_square = [r[int(np.flatnonzero(r["position"][:, 0] > 210.0)[0]):] for r in (records, unmoved)]
    assert _outside_square(on_square[1], 200.0, 200.0, 100.0) < 1e-9, "unmoved, the overlap stays inside the corner"
    assert 0.1 * p < _outside_square(on_square[0], 200.0, 200.0, 100.0) <= p, "moved, it uses the band outside it too"


def test_a_corner_at_the_end_of_the_travel_is_not_moved_out_of_it():
    """The square of the tests starts at X0 Y0, the travel's lower ends: its corners on them stay
    where they are (outward would be beyond the travel), the one inside the travel moves; no record
    leaves the travel. The program's timing never takes a run there for a copy elsewhere: a run
    within P of a travel end has no key (`sections.run_key`)."""
    from cnc.planner.path import iter_elements
    from cnc.planner.sections import run_key

    config = machine_config()
    program, _, records, planned = run(square(0.05, 12000.0), chunk=29)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    assert records["position"][:, :2].min() >= 0.0, "never beyond the travel's lower ends"
    assert _outside_square(records, 0.0, 0.0, 100.0) > 0.0, "the corner at X100 Y100 is moved outward"
    elements = list(iter_elements(program.segments))
    assert run_key(elements, None, config) is None
    far = interpret(SQUARE.format(p=0.05, f=12000.0, x0=200.0, y0=200.0, x1=300.0, y1=300.0), dialect_for(config))
    assert run_key(list(iter_elements(far.segments))[1:], None, config) is not None, "from X200 Y200 on"


def test_a_line_tilted_by_a_moved_corner_gives_up_only_the_jerk_the_other_move_adds():
    """At a right angle whose corner moved, each line runs a hair off its axis: on each axis the
    move mostly along it gives up what the other adds there (a few ten-thousandths), not the small
    move its own share; where two moves share an axis in earnest, each would give up much."""
    from cnc.planner.sections import _jerk_shares_needed

    tilt = 1.77e-4
    a, b = (1.0, -tilt), (-tilt, 1.0)
    need_a, need_b = _jerk_shares_needed(a, b)
    assert tilt <= need_a < 1.01 * tilt + 1e-5 and tilt <= need_b < 1.01 * tilt + 1e-5
    assert _jerk_shares_needed((1.0, 0.0), (0.0, 1.0)) == (0.0, 0.0), "a square's corner: nothing shared"
    need_a, need_b = _jerk_shares_needed((1.0, 0.0), (math.cos(math.radians(60.0)), math.sin(math.radians(60.0))))
    assert need_a == pytest.approx(math.tan(math.radians(30.0)), rel=1e-2) and need_b == 0.0, "a 60 degree turn shares much of X"


def test_the_overlap_is_a_machine_file_key_validated_by_name():
    with pytest.raises(ConfigError, match=r"corner_overlap_ms"):
        machine_config(**{"planner.corner_overlap_ms": -5.0})
    with pytest.raises(ConfigError, match=r"corner_overlap_ms"):
        machine_config(**{"planner.corner_overlap_ms": "soon"})
    assert machine_config().planner.corner_overlap_ms == 40.0
    for bad in (-0.1, 1.0, "half"):
        with pytest.raises(ConfigError, match=r"corner_move_share"):
            machine_config(**{"planner.corner_move_share": bad})
    assert machine_config().planner.corner_move_share == 0.5


def _random_polyline(seed: int) -> tuple[str, int]:
    """Lines and rapids of random lengths (5 um to 60 mm) and directions at a random feed and P,
    and the take size to run it with."""
    rng = random.Random(seed)
    x = y = 0.0
    feed = rng.choice([300, 2400, 6000, 12000, 30000])
    lines = [f"G21 G90 G64 P{rng.choice([0.005, 0.05, 0.2]):g}", f"G1 X0 Y0 F{feed}"]
    for _ in range(rng.randint(3, 12)):
        angle = rng.uniform(0.0, 2.0 * math.pi)
        length = rng.choice([rng.uniform(0.005, 0.2), rng.uniform(0.2, 3.0), rng.uniform(3.0, 60.0)])
        x, y = x + length * math.cos(angle), y + length * math.sin(angle)
        lines.append(f"{'G0' if rng.random() < 0.2 else 'G1'} X{x:.4f} Y{y:.4f}")
    return "\n".join(lines + ["M2"]) + "\n", rng.choice([1, 7, 50, 997])


@pytest.mark.parametrize("seed", [66, 89, 104, 113, *range(12)])
def test_random_polylines_overlap_within_every_limit_and_time_exactly(seed):
    """Seeds 66, 89, 104 and 113 once overlapped a section shorter than the overlap (its samples
    ran out before the last section's: the runner failed); 150 seeds run clean now."""
    text, chunk = _random_polyline(seed)
    program, runner, records, planned = run(text, chunk=chunk)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned


@pytest.mark.parametrize("seed", range(8))
def test_random_polylines_under_the_operators_controls_at_random_keep_every_limit(seed):
    """The polylines of the fuzz above, with holds, resumes, overrides from 0 to 200 % and a stop at
    random moments (about four overlaps a run, controls landing in some): 300 seeds run clean."""
    program, records, stopped, _ = _operator_at_random(seed, text=_random_polyline(seed)[0])
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    if not stopped:
        assert records["position"][-1] == pytest.approx(program.segments["end"][-1][:2], abs=1e-9)


def _lead_in_and_chords(radius: float = 16.0, chords: int = 56, feed: int = 2400) -> str:
    """A CAM part as the comparison nest cuts its round ones: a lead-in along +Y, then a circle in
    chords whose first runs a few degrees off +X (both moves share the Y axis, one barely)."""
    cx, cy = 0.0, 3.0 + radius
    lines = ["G21 G90 G64 P0.05", f"G1 X0 Y0 F{feed}", "G1 Y3"]
    for k in range(1, chords + 1):
        a = -math.pi / 2 + 2 * math.pi * k / chords
        lines.append(f"G1 X{cx + radius * math.cos(a):.4f} Y{cy + radius * math.sin(a):.4f}")
    return "\n".join(lines + ["M2"]) + "\n"


def test_a_lead_in_into_a_contour_a_few_degrees_off_square_overlaps_as_the_tolerance_allows(monkeypatch):
    """The lead-in's last jerk and the contour's first add on Y, where the contour's first chord
    barely moves: at the axis's full jerk the overlap was refused for 1 % too much and the head
    stood at the corner. The straight lead-in now leaves a few per cent of its jerk unused there
    (`sections._jerk_reserves`): the corner overlaps far longer, every axis keeps its limits, every
    record stays within P, and the planned time is the one run. At F4800, where the contour's path
    average holds its jerk (at F2400 its axis average does, `limits.smoothing_for`: its first
    jerk comes later and smaller, and meets the lead-in's last within the limit either way)."""
    from cnc.planner import sections

    text = _lead_in_and_chords(feed=4800)
    program, _, records, planned = run(text, chunk=41)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    monkeypatch.setattr(sections, "JERK_RESERVE", 0.0)
    _, _, full_jerk, planned_full = run(text, chunk=41)
    within_limits(full_jerk)
    assert len(full_jerk) == planned_full
    assert len(full_jerk) - len(records) >= 20, "the overlap at the lead-in's corner is tens of ms longer"
    first_pass = records[: len(records) // 2]  # the circle closes at the corner: its end stops there
    assert corner_speeds(first_pass, [(0.0, 3.0)])[0] > 5.0, "the head passes the corner at speed"
    assert corner_speeds(full_jerk[: len(full_jerk) // 2], [(0.0, 3.0)])[0] == 0.0, "with the whole jerk it stood there"


def test_an_overlap_never_passes_over_the_programmed_feed(monkeypatch):
    """The sum of a move still arriving and the next already at its feed would pass over F (by a
    per cent at a cutting feed): an overlap keeps every summed sample within the faster of the two
    feeds, so no record of a program of feed moves is faster than F, at 100 % as at 150 %, at
    F2400 and at F1200 (where, without the cap, the sum passes over F by 0.2 %)."""
    from cnc.planner import overlap

    for feed in (2400, 1200):
        text = _lead_in_and_chords(feed=feed)
        for override in (1.0, 1.5):
            program, _, records, planned = run(text, actions={0: lambda r, o=override: r.set_override(o)}, chunk=41)
            assert speed(records).max() <= override * feed / 60.0 * (1.0 + 1e-6)
            within_limits(records)
    monkeypatch.setattr(overlap, "_speed_cap", lambda a, b: math.inf)
    _, _, over, _ = run(text, chunk=41)
    assert speed(over).max() > 20.0 * (1.0 + 1e-4), "without the cap the overlap's sum passes over F"


def test_only_a_straight_move_at_a_corner_sharing_an_axis_barely_leaves_jerk_unused():
    """A square's corners (the two moves on different axes) and a zigzag's (both well along a
    common axis) take the whole jerk; a lead-in meeting a contour that starts a few degrees off
    square leaves `JERK_RESERVE` of it unused, and so does a rapid arriving a little across it."""
    from cnc.planner.path import iter_elements
    from cnc.planner.sections import JERK_RESERVE, _jerk_reserves

    config = machine_config()

    def reserves(text: str) -> list[float]:
        elements = [e for e in iter_elements(interpret(text, dialect_for(config)).segments)]
        return _jerk_reserves([[e] for e in elements], config)

    assert reserves(square()) == [0.0] * 4
    zigzag = "G21 G90 G64 P0.05\nG1 X10 Y0 F6000\nG1 X18.66 Y5\nG1 X10 Y10\nM2\n"
    assert reserves(zigzag) == [0.0] * 3
    # a rapid arriving from the left and a little below, the lead-in up, the contour a few degrees off +X
    lead_in = "G21 G90 G64 P0.05\nG0 X-57 Y-1\nG0 X0 Y0\nG1 X0 Y3 F2400\nG1 X10 Y3.5\nM2\n"
    assert reserves(lead_in) == [0.0, JERK_RESERVE, JERK_RESERVE, JERK_RESERVE]
    no_tolerance = lead_in.replace("G64 P0.05", "G61")
    assert reserves(no_tolerance) == [0.0] * 4, "no overlap under an exact stop, nothing to reserve for"


def _round_part(kerf_by_controller: bool, feed: int = 2400) -> str:
    """A round part of the comparison nest (`bench/gcode_speed.py`: R11.5379 in 52 chords, every
    third an arc, a lead-in along Y), its kerf offset by the controller (G41 with the jet, the
    pierce dwell and G40) or already by CAM (the path as programmed)."""
    ox, oy, radius, n = ROUND_PART
    lines = ["G21 G90 G17 G64 P0.05", "T1 M6", f"G0 X{ox:.3f} Y{oy - 3:.3f}"]
    lines += ["M3", "G4 P0.3", f"G41 D1 G1 X{ox:.3f} Y{oy:.3f} F{feed}"] if kerf_by_controller else [f"G1 X{ox:.3f} Y{oy:.3f} F{feed}"]
    for k in range(1, n + 1):
        a = -math.pi / 2 + 2 * math.pi * k / n
        x, y = ox + radius * math.cos(a), oy + radius + radius * math.sin(a)
        lines.append(f"G3 X{x:.4f} Y{y:.4f} R{radius:.4f}" if k % 3 == 0 else f"G1 X{x:.4f} Y{y:.4f}")
    lines += [f"G40 G1 X{ox - 2:.3f} Y{oy - 2:.3f}", "M5"] if kerf_by_controller else [f"G1 X{ox - 2:.3f} Y{oy - 2:.3f}"]
    return "\n".join(lines + ["M2"]) + "\n"


ROUND_PART = (625.0, 20.0, 11.5379, 52)  # lead-in end (X, Y), radius, chords
ROUND_PART_FIRST_CHORD_END = (ROUND_PART[0] + ROUND_PART[2] * math.cos(-math.pi / 2 + 2 * math.pi / ROUND_PART[3]),
                              ROUND_PART[1] + ROUND_PART[2] + ROUND_PART[2] * math.sin(-math.pi / 2 + 2 * math.pi / ROUND_PART[3]))


@pytest.mark.parametrize("feed,gentle_mm_s", [(2400, 30.0), (4800, 45.0)])
def test_a_gentle_corner_next_to_a_sharp_one_is_blended_at_its_own_speed(monkeypatch, feed, gentle_mm_s):
    """A lead-in along Y into a round part in chords and arcs, as CAM writes one: the lead-in's
    corner is sharp (a stop, overlapped) and the next, between the first two chords, turns 7
    degrees. The averages spread the sharp blend's crawl over the gentle one's cap, which made
    the gentle corner a stop as well. It is weighed at the speed its own curvature allows when
    the sharp corner beside it is a stop (`sections._corners_to_stop`): blended, passed near the feed
    (over 30 mm/s at F2400, over 45 at F4800). Weighed as a sharp one it is a stop: at F4800 the
    head stands there; at F2400, where the contour's axis average holds its jerk (`limits.
    smoothing_for`) and its arcs brake harder at 100 % (`SectionLimits.accel_for`), it passes that
    stop in an overlap, slower (36 mm/s) and a sample later."""
    from cnc.planner import sections

    text = _round_part(kerf_by_controller=False, feed=feed)
    gentle_corner = np.asarray(ROUND_PART_FIRST_CHORD_END)
    config = machine_config(**NO_CONNECTION)  # the stop's overlap, as the rule was weighed against

    def speed_at_gentle_corner(records) -> float:  # lowest within 0.3 mm (the sharp corner is 1.4 mm away)
        first_pass = records[: len(records) * 3 // 5]  # before the circle closes (the rapid is a share)
        near = np.hypot(*(first_pass["position"][:, :2] - gentle_corner).T) < 0.3
        return float(speed(first_pass)[near].min())

    program, _, records, planned = run(text, config, chunk=29)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    assert speed_at_gentle_corner(records) > gentle_mm_s, "passed near the feed"

    monkeypatch.setattr(sections, "_blend_own_cap", lambda *args: 0.0)  # every blend weighed as a sharp one, as before
    _, _, stopping, _ = run(text, config, chunk=29)
    if feed == 4800:
        assert speed_at_gentle_corner(stopping) < 1.0, "a stop before (overlapped by a few ms)"
        assert len(stopping) - len(records) >= 20
    else:
        assert speed_at_gentle_corner(stopping) < speed_at_gentle_corner(records) - 2.0
        assert len(stopping) > len(records)


@pytest.mark.parametrize("kerf_by_controller", [False, True])
@pytest.mark.parametrize("feed", [2400, 4800])
def test_a_gentle_corner_kept_beside_a_sharp_one_is_weighed_again_and_never_slows_a_part(monkeypatch, kerf_by_controller, feed):
    """The gentle corners kept beside a stopped sharp one are weighed again once it is a stop. With
    the kerf by CAM the round part runs sooner for them (by tens of ms at F4800; at F2400, where the
    stop is passed in a longer overlap, `limits.smoothing_for`, by a sample); with G41 the compensated
    path near the lead-in still caps the gentle blend, and weighed again it is a stop as before (kept
    blended, the part took 98 ms longer). Neither is slower than without the rule, and the timing is
    the run."""
    from cnc.planner import sections

    text = _round_part(kerf_by_controller, feed)
    config = machine_config(**NO_CONNECTION)  # the stop's overlap, as the rule was weighed against
    program, _, records, planned = run(text, config, chunk=53)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    monkeypatch.setattr(sections, "_blend_own_cap", lambda *args: 0.0)  # no gentle corner kept
    _, _, without, planned_without = run(text, config, chunk=53)
    assert len(without) == planned_without
    if kerf_by_controller:
        assert len(records) <= len(without)
    else:
        assert len(without) - len(records) >= (20 if feed == 4800 else 1)


def _random_cam_parts(seed: int, jet: bool = False) -> tuple[str, int]:
    """One to three round parts as CAM writes them: a lead-in at a random heading, the contour
    starting up to 17 degrees off square to it in chords and arcs (R3-20), a lead-out, a rapid to
    the next; a random feed (5-200 mm/s) and P; and the take size to run it with. `jet`: each part
    cut with the jet (opened and pierced before its lead-in, closed before the rapid); the same
    geometry."""
    rng = random.Random(seed)
    feed = rng.choice([300, 1200, 2400, 6000, 12000])
    lines = [f"G21 G90 G64 P{rng.choice([0.005, 0.05, 0.2]):g}", "G0 X0 Y0"]
    x = y = 0.0
    for _ in range(rng.randint(1, 3)):
        heading, lead = rng.uniform(0.0, 2.0 * math.pi), rng.uniform(1.0, 5.0)
        x, y = x + lead * math.cos(heading), y + lead * math.sin(heading)
        lines += ["M3", "G4 P0.1"] if jet else []
        lines.append(f"G1 X{x:.4f} Y{y:.4f} F{feed}")
        radius, chords, side = rng.uniform(3.0, 20.0), rng.randint(12, 60), rng.choice([-1, 1])
        outward = heading + side * math.pi / 2 + rng.uniform(-0.3, 0.3) + math.pi  # from the centre to the lead-in's end
        cx, cy = x - radius * math.cos(outward), y - radius * math.sin(outward)
        for k in range(1, chords + 1):
            a = outward + side * 2.0 * math.pi * k / chords
            x, y = cx + radius * math.cos(a), cy + radius * math.sin(a)
            arc = k % 3 == 0 and rng.random() < 0.7
            lines.append(f"{('G3' if side > 0 else 'G2') if arc else 'G1'} X{x:.4f} Y{y:.4f}" + (f" R{radius:.4f}" if arc else ""))
        out = rng.uniform(0.0, 2.0 * math.pi)
        x, y = x + rng.uniform(1.0, 3.0) * math.cos(out), y + rng.uniform(1.0, 3.0) * math.sin(out)
        lines.append(f"G1 X{x:.4f} Y{y:.4f}")
        x, y = x + rng.uniform(-40.0, 40.0), y + rng.uniform(-40.0, 40.0)
        lines += ["M5"] if jet else []
        lines.append(f"G0 X{x:.4f} Y{y:.4f}")
    return "\n".join(lines + ["M2"]) + "\n", rng.choice([1, 7, 50, 997])


@pytest.mark.parametrize("seed", range(6))
def test_random_cam_parts_with_lead_ins_off_square_keep_every_limit_and_time_exactly(seed):
    """Where the jerk reserve and the gentle corners act (lead-ins into round parts in chords and
    arcs), plain and, for every third seed, under the operator's controls at random: 300 seeds of
    this generator run clean."""
    text, chunk = _random_cam_parts(seed)
    runs_clean(text, chunk, seed if seed % 3 == 0 else None)


@pytest.mark.parametrize("seed", [10, 12, 17, 23])  # F2400-F12000, P0.005-0.05
def test_random_cam_parts_on_machines_of_other_limits_keep_them_and_time_exactly(seed):
    """The same parts on machines whose X and Y limits differ (`_machine_at_random`: speeds 100-1000
    mm/s, accelerations 500-10000 mm/s², jerks 2e4-1e6 mm/s³ per axis): every axis keeps its own
    limits and every record P, plain and under the operator's controls at random, and the program's
    timing (`ProgramTiming`, as `waterjet check` makes it) is the run's to the servo period. 400
    seeds of this ran clean, every other one also under the operator's controls (2026-12-07)."""
    from cnc.planner.steps import ProgramTiming

    from .test_planner_motion import _machine_at_random

    text, chunk = _random_cam_parts(seed)
    overrides, limits = _machine_at_random(seed + 100000)
    config = machine_config(**overrides)
    program, _, records, planned = run(text, config, chunk=chunk)
    within_limits(records, limits)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned == ProgramTiming.of(program, config).total_ticks
    program, records, _, events = _operator_at_random(seed, config, text=text)
    within_limits(records, limits)
    assert (within_tolerance(program, records) <= 1e-9).all(), events


def _part_turned_back(feed: int) -> str:
    """`_lead_in_and_chords` left by a lead-out turned back at 45 degrees (into the scrap, as CAM
    writes it): the last chord runs along +X into the corner, the lead-out goes off down-left."""
    return _lead_in_and_chords(feed=feed).replace("M2\n", "G1 X-2 Y1\nM2\n")


def _sections_of(text: str) -> list:
    from cnc.planner.sections import Section, iter_steps

    config = machine_config()
    return [s for s in iter_steps(interpret(text, dialect_for(config)), config) if isinstance(s, Section)]


@pytest.mark.parametrize("feed,sooner", [(2400, 5), (4800, 0)])
def test_a_lead_out_turned_back_eases_both_ramps_where_that_passes_it_sooner(monkeypatch, feed, sooner):
    """At a turn back the contour's first braking jerk and the lead-out's first add on X, so at
    their own jerk the lead-out starts only once the contour has braked about halfway. At F2400
    both ramps eased to `SHARP_TURN_ACCEL_SHARE` overlap until P holds them, and the part ends
    sooner, passing the corner at about twice the speed; at F4800 the overlap is near its cap
    already and easing would cost more than it gains, so the corner is left as it was. Either
    way every axis keeps its limits, every record stays within P, the planned time is the one run."""
    from cnc.planner import sections

    text = _part_turned_back(feed)
    program, _, records, planned = run(text, chunk=41)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    eased = [s.eased_ends for s in _sections_of(text)]
    monkeypatch.setattr(sections, "SHARP_TURN_ACCEL_SHARE", 1.0)
    _, _, whole, planned_whole = run(text, chunk=41)
    assert len(whole) == planned_whole
    corner = [(0.0, 3.0)]
    second_half = slice(len(records) // 2, None)  # the circle closes at the lead-in's corner
    if sooner:
        assert eased == [(1.0, 1.0), (1.0, 0.7), (0.7, 1.0)], "the lead-in's right angle is not eased"
        assert len(whole) - len(records) >= sooner
        assert corner_speeds(records[second_half], corner)[0] > 1.5 * corner_speeds(whole[len(whole) // 2:], corner)[0]
    else:
        assert eased == [(1.0, 1.0)] * 3
        assert len(whole) == len(records)


def test_eased_ramps_keep_a_hold_at_the_whole_acceleration_and_the_same_stretch_at_any_override():
    """The contour's end and the lead-out's start ramp at 0.7 of their acceleration over the
    stretch a braking from the fastest they may run takes, whatever the override (a motion planned
    again under a raise finds the accelerations it braked at); a hold brakes at the whole."""
    from cnc.planner.limits import section_zones
    from cnc.planner.sections import SHARP_TURN_ACCEL_SHARE

    lead_in, contour, lead_out = _sections_of(_part_turned_back(2400))
    for section, eased_at_end in ((contour, True), (lead_out, False)):
        length = section.length_mm
        stretches = []
        for controls in ((1.0, 1.0, False), (2.0, 1.0, True), (0.3, 1.0, False)):
            own = section_zones(section.path, section.limits, 0.0, length, False, *controls)
            zones = section.zones(False, *controls)
            near = length - 1e-3 if eased_at_end else 1e-3
            far = 1e-3 if eased_at_end else length - 1e-3

            def accel(z, s):  # noqa: ANN001, ANN202
                return float(z.accel[min(np.searchsorted(z.edges, s, side="right") - 1, len(z.accel) - 1)])

            assert accel(zones, near) == pytest.approx(SHARP_TURN_ACCEL_SHARE * accel(own, near), rel=1e-12)
            assert accel(zones, far) == accel(own, far), "only the end at the corner is eased"
            stretch = [e for e in zones.edges if 0.0 < e < length and e not in own.edges]
            assert len(stretch) == 1
            stretches.append(stretch[0])
            held = section.zones(True, *controls)
            assert np.array_equal(held.accel, section_zones(section.path, section.limits, 0.0, length, True,
                                                            *controls).accel), "a hold brakes at the whole acceleration"
        assert len(set(stretches)) == 1, "the eased stretch is the same at every override"
    assert lead_in.eased_ends == (1.0, 1.0)


@pytest.mark.parametrize("control", ["hold", "override 200", "override 10", "stop"])
def test_a_control_anywhere_in_eased_ramps_keeps_every_limit_and_ends_where_programmed(control):
    """Holds (resumed 30 samples later), raises to 200 %, drops to 10 % and stops every 13 samples
    from 60 samples before the contour's eased braking to the lead-out's end: every axis within
    its limits, every record within P of the program, and the part ends at the lead-out's end (a
    stop: at rest on the path)."""
    text = _part_turned_back(2400)
    program, _, undisturbed, _ = run(text, chunk=41)
    lead_out_line = int(undisturbed["line"][-1])
    start = int(np.flatnonzero(undisturbed["line"] == lead_out_line)[0])
    for at in range(start - 60, len(undisturbed) - 5, 13):
        actions = {at: CONTROLS[control]}
        if control == "hold":
            actions[at + 30] = lambda r: r.resume()
        _, runner, records, _ = run(text, chunk=23, actions=actions)
        within_limits(records)
        assert (within_tolerance(program, records) <= 1e-9).all(), f"control at {at}"
        if control == "stop":
            assert speed(records)[-1] == 0.0
        else:
            assert runner.state == RunState.DONE
            assert records["position"][-1] == pytest.approx([-2.0, 1.0], abs=1e-9), f"control at {at}"


RECTANGLE_PART = ["G0 X570 Y62", "G4 P0.1", "G1 X570 Y65 F2400", *[f"G1 X{570 + 2.758 * k:.3f} Y65" for k in range(1, 13)],
                  "G3 X605.152 Y67.054 I0 J2.054", "G1 X605.152 Y86.341", "G3 X603.098 Y88.395 I-2.054 J0",
                  "G1 X572.054 Y88.395", "G3 X570 Y86.341 I0 J-2.054", "G1 X570 Y65", "G1 X568 Y63"]


def test_a_lead_in_and_a_lead_out_corner_move_along_the_contour_by_their_own_share():
    """A rounded rectangle of the comparison nest: its lead-in's corner moves back along the
    contour's first line and its lead-out's corner on along the last one, by `[planner]
    lead_move_share` of P (0.7), not `corner_move_share` (0.5, between two lone lines); the
    part keeps every limit and P and ends a sample sooner than at 0.5."""
    text = "\n".join(["G21 G90 G17 G64 P0.05", *RECTANGLE_PART, "M2"]) + "\n"
    config = machine_config()
    assert (config.planner.lead_move_share, config.planner.corner_move_share) == (0.7, 0.5)
    _, lead_in, contour, lead_out = _sections_of(text)
    moved = 0.7 * 0.05
    assert lead_in.elements[-1].end[:2] == pytest.approx((570.0 - moved, 65.0), abs=1e-12)
    assert contour.elements[0].start == lead_in.elements[-1].end
    assert contour.elements[-1].end[:2] == pytest.approx((570.0, 65.0 - moved), abs=1e-12)
    assert lead_out.elements[0].start == contour.elements[-1].end
    assert lead_in.elements[-1].programmed[0].end[:2] == (570.0, 65.0), "measured against the corner as programmed"
    program, _, records, planned = run(text, chunk=41)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    _, _, half, planned_half = run(text, machine_config(**{"planner.lead_move_share": 0.5}), chunk=41)
    assert len(half) == planned_half and len(half) > len(records)
    for bad in (-0.1, 0.95, "most"):
        with pytest.raises(ConfigError, match=r"lead_move_share"):
            machine_config(**{"planner.lead_move_share": bad})
