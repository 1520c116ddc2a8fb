"""The cutting model: material, thickness and quality set the speed along the path.

The jet-lag caps keep the bottom of the cut within each quality's deviation (checked against the
model's forward direction, and tight); the program's `(MATERIAL, ...)` and `(QUALITY, ...)`
comments are read with their units, and bad ones name the line and column; the planner never
runs faster than the model anywhere (straights, corners, arcs, lead-ins; property-tested over
generated contours); "feed" mode keeps F; `waterjet check` reports both cycle times.
"""

from __future__ import annotations

import json
import math
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cnc.cli import main
from cnc.config import load_machine
from cnc.cutmodel import CutModel, CutSetup, model_for
from cnc.machine_dialect import dialect_for
from cnc.materials import MaterialError, parse_material, record_calibration, render_material
from cnc.planner.geometry import PathArrays
from cnc.planner.path import Element
from cnc.planner.quality import CutPlan, CutPlanError, cut_plan_for
from cnc.planner.sections import Section, iter_steps, pierce_dwell_s
from cnc.planner.steps import ProgramTiming
from cnc.planner.stream import SectionStream
from gcode.canon import ARC, LINE
from gcode.errors import GCodeError
from gcode.interp import Interpreter

from .conftest import MACHINE_FILE

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

# test data, as a calibration on the machine would write it: not a shipped material
HIDE = """[material]
name = "Test hide"
kind = "water"
source = "test data"

[quality]
corner_mm = [0.5, 0.3, 0.2, 0.1, 0.05]

[[chart]]
thickness_mm = 2.0
separation_mm_min = 6000.0
pierce_s = 0.3
kerf_mm = 0.2
quality_mm_min = [6000.0, 4800.0, 3600.0, 2400.0, 1200.0]
lag_mm = [1.0, 0.7, 0.45, 0.25, 0.1]

[[chart]]
thickness_mm = 4.0
separation_mm_min = 3000.0
pierce_s = 0.6
kerf_mm = 0.25
quality_mm_min = [3000.0, 2400.0, 1800.0, 1200.0, 600.0]
lag_mm = [1.6, 1.1, 0.7, 0.4, 0.15]
"""


def hide_library(directory: Path) -> Path:
    """A material library holding the test hide (`[cutting] materials_dir` points there)."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "hide.toml").write_text(HIDE)
    return directory


def hide_model(thickness: float = 2.0, quality: int = 3, mode: str = "quality") -> CutModel:
    return CutModel(parse_material(tomllib.loads(HIDE), "hide", "hide.toml"), CutSetup("hide", thickness, quality, mode))


def machine(tmp_path: Path):
    return load_machine(MACHINE_FILE, {"cutting.materials_dir": str(hide_library(tmp_path / "materials"))})


def interpret(text: str, config, name: str = "nest.ngc"):
    return Interpreter(dialect_for(config), name).run(text.encode())


@settings(max_examples=300, deadline=None)
@given(st.floats(0.02, 500.0), st.floats(0.001, 2 * math.pi), st.integers(1, 5), st.floats(2.0, 4.0))
@example(0.25, 1.59375, 2, 3.5)  # the lag at the cap exactly r theta: the edge between the settled and corner figures
@example(0.5, 2.0, 1, 2.0)  # r = the deviation allowed: the arc never strays further, the cap is that hair below F
def test_the_lag_caps_keep_the_bottom_of_the_cut_within_each_quality_and_are_tight(radius, sweep, quality, thickness):
    model = hide_model(thickness)
    e = model.corner_mm[quality]
    straight = model.speed(quality)
    for r in (radius, math.inf):  # an arc, and a corner of the same turn
        cap = float(model.arc_cap(quality, r, sweep)) if math.isfinite(r) else float(model.turn_cap(quality, sweep))
        v = min(cap, straight)
        assert model.bottom_deviation(v, r, sweep) <= e * (1.0 + 1e-9) + 1e-12, (r, sweep, quality, v)
        # the cap binds (not only by the hair it keeps below the settled edge, where the lag curve,
        # flat beyond the chart's fastest speed, cannot stray further): a little faster strays beyond
        if cap < straight * (1.0 - 1e-6):
            assert model.bottom_deviation(cap * 1.01, r, sweep) > e, (r, sweep, quality, cap)


def test_slower_qualities_and_sharper_turns_get_lower_caps_and_a_chart_without_lag_caps_no_corner():
    model = hide_model()
    turns = np.radians([5.0, 30.0, 60.0, 90.0, 135.0])
    for q in range(1, 6):
        caps = np.minimum(model.turn_cap(q, turns), model.speed(q))
        assert np.all(np.diff(caps) <= 1e-12), f"quality {q}: a sharper corner is never faster"
    assert model.turn_cap(5, math.pi / 2) < model.turn_cap(1, math.pi / 2)
    assert model.arc_cap(3, 2.0, 2 * math.pi) < model.arc_cap(3, 50.0, 2 * math.pi), "a small circle is slower"
    bare = parse_material(tomllib.loads(HIDE.replace("corner_mm = [0.5, 0.3, 0.2, 0.1, 0.05]\n", "")), "hide", "hide.toml")
    plain = CutModel(bare, CutSetup("hide", 2.0, 3))
    assert not plain.corners_modelled and math.isinf(plain.turn_cap(3, math.pi / 2)) and plain.speed(3) == 60.0


def test_lag_and_corner_figures_are_checked_written_back_and_recorded(tmp_path):
    m = parse_material(tomllib.loads(HIDE), "hide", "hide.toml")
    assert parse_material(tomllib.loads(render_material(m)), "hide", "hide.toml") == m
    assert m.cut(3.0, 3).lag_mm == pytest.approx(0.575), "between rows the trail-back is interpolated"
    cases = {
        "lag_mm = [1.0, 0.7, 0.45, 0.25, 0.1]": ("", "[[chart]] 2 mm: lag_mm: missing while other rows give it"),
        "lag_mm = [1.6, 1.1, 0.7, 0.4, 0.15]": ("lag_mm = [1.6, 1.1, 0.7, 0.4, 1.15]", "[[chart]] #2 lag_mm: quality 5"),
        "corner_mm = [0.5, 0.3, 0.2, 0.1, 0.05]": ("corner_mm = [0.5, 0.3]", "[quality] corner_mm: expected five numbers"),
    }
    for old, (new, why) in cases.items():
        with pytest.raises(MaterialError) as exc:
            parse_material(tomllib.loads(HIDE.replace(old, new, 1)), "hide", "lib/hide.toml")
        assert "lib/hide.toml: material 'hide'" in str(exc.value) and why in str(exc.value), str(exc.value)

    path = tmp_path / "materials" / "hide.toml"
    hide_library(tmp_path / "materials")
    recorded = record_calibration(path, 6.0, 2000.0, [2000, 1600, 1200, 800, 400], 1.0, 0.3, "test",
                                  lag_mm=[2.0, 1.5, 1.0, 0.6, 0.2])
    assert recorded.chart[-1].lag_mm == (2.0, 1.5, 1.0, 0.6, 0.2) and recorded.corner_mm == m.corner_mm
    shutil.copy(MACHINE_FILE, tmp_path / "machine.toml")
    assert main(["materials", "--machine", str(tmp_path / "machine.toml"), "record", "hide", "--thickness", "8",
                 "--separation", "1500", "--quality", "1500,1200,900,600,300", "--pierce", "1.5", "--kerf", "0.3",
                 "--lag", "2.5,2,1.5,1,0.3"]) == 0
    assert model_for(CutSetup("hide", 8.0, 3), load_machine(tmp_path / "machine.toml")).speed(3) == 15.0


def test_cut_comments_are_read_in_the_program_s_units_and_bad_ones_name_line_and_column(tmp_path):
    config = machine(tmp_path)
    program = interpret("(MATERIAL, hide, THICKNESS=0.1, QUALITY=2, MODE=FEED)\nG20\nG0 X1\n(QUALITY, 4)\nG0 X2\nM2\n", config)
    material, quality = [m for m in program.messages if m.kind in ("material", "quality")]
    assert material.data == {"text": "MATERIAL, hide, THICKNESS=0.1, QUALITY=2, MODE=FEED", "material": "hide",
                             "thickness_mm": 0.1, "quality": 2, "mode": "feed"}, "mm: G20 comes after the comment's line"
    assert quality.data["quality"] == 4 and quality.segment == 1
    inch = interpret("G20\n(material, hide, thickness=0.1, quality=3)\nG0 X1\nM2\n", config)
    assert inch.messages[0].data["thickness_mm"] == pytest.approx(2.54), "in the units in force"
    assert interpret("G20\n(MATERIAL, hide, THICKNESS=2mm, QUALITY=3)\nM2\n", config).messages[0].data["thickness_mm"] == 2.0
    assert [m.kind for m in interpret("(material: hide)\n(MSG, quality, 3)\nM2\n", config).messages] == ["message"]
    bad = {  # the line, the field the error points at, and why
        "(MATERIAL, hide, THICKNESS=2, QUALITY=6)": ("QUALITY=6", "quality 6 is not 1 (separation) to 5"),
        "G0 X1 (MATERIAL, hide, THICK=2, QUALITY=3)": ("THICK=2", "unknown field 'THICK'"),
        "(MATERIAL, hide, QUALITY=3)": ("QUALITY=3", "THICKNESS= is missing"),
        "(MATERIAL, hi de, THICKNESS=2, QUALITY=3)": ("hi de", "is not a material id"),
        "(MATERIAL, hide, THICKNESS=-2, QUALITY=3)": ("THICKNESS=-2", "expected a positive length"),
        "(MATERIAL, hide, THICKNESS=2, QUALITY=3, MODE=FAST)": ("MODE=FAST", "MODE=FAST: expected QUALITY"),
        "(QUALITY, fine)": ("fine", "a quality is a whole number"),
    }
    for line, (field, why) in bad.items():
        with pytest.raises(GCodeError) as exc:
            interpret("G21\n" + line + "\nM2\n", config)
        assert (exc.value.line, exc.value.column) == (2, line.index(field) + 1), (line, str(exc.value))
        assert why in exc.value.message, (line, str(exc.value))


NEST = """(MATERIAL, hide, THICKNESS=2, QUALITY=3)
G21 G90 G64 P0.05 F6000
G0 X100 Y100
M3
G4 P0.2
G41 D1 G1 X105 Y100
G1 X160
G1 Y140
G2 X150 Y150 I-10 J0
G1 X110
G3 X105 Y145 I0 J-5
G1 X105 Y100
G40 G1 X100 Y98
M5
(QUALITY, 5)
G0 X200 Y100
M3
G4 P0.2
G1 X205 Y100
G1 X240 Y101
G1 X270 Y100
G1 X270 Y130
M5
G0 X60 Y60
M2
"""


def test_quality_mode_slows_corners_arcs_and_lead_ins_and_feed_mode_keeps_the_programmed_f(tmp_path):
    config = machine(tmp_path)
    program = interpret(NEST, config)
    plan, text = cut_plan_for(program, None, config, "nest.ngc")
    assert text == "hide 2 mm quality 3, by the program"
    seg = program.segments
    cutting = [i for i in range(len(seg)) if seg["jet"][i] and seg["kind"][i] in (LINE, ARC)]
    opened = [i for i in range(1, len(seg)) if seg["jet"][i] and not seg["jet"][i - 1]]
    lead_ins = [min(c for c in cutting if c >= o) for o in opened]
    assert len(lead_ins) == 2 and plan.quality[lead_ins].tolist() == [5, 5], "the lead-in after each pierce: pierce quality"
    second = seg["line"] >= 15
    assert set(plan.quality[[c for c in cutting if c not in lead_ins and not second[c]]]) == {3}
    assert set(plan.quality[[c for c in cutting if c not in lead_ins and second[c]]]) == {5}, "(QUALITY, 5) from line 15"
    at_f = ProgramTiming.of(program, config).total_ticks
    modelled = ProgramTiming.of(program, config, plan).total_ticks
    assert modelled > at_f * 1.3, "3600 mm/min and slower corners against F6000"
    feed_plan, feed_text = cut_plan_for(program, CutSetup("hide", 2.0, 3, "feed"), config, "nest.ngc")
    assert "feed as programmed" in feed_text and "by the operator" in feed_text
    pierces = 2 * round((0.3 - config.jet.pierce_dwell_s) / config.timing.period_s)  # the chart's pierce time, not [jet]'s
    assert ProgramTiming.of(program, config, feed_plan).total_ticks == at_f + pierces, "feed mode: the speeds stay F's"
    finer = cut_plan_for(program, CutSetup("hide", 2.0, 4), config, "nest.ngc")[0]
    assert ProgramTiming.of(program, config, finer).total_ticks > modelled

    with pytest.raises(CutPlanError, match=r"nest.ngc:1: cutting job: .*thickness 9 mm is outside its chart \(2 to 4 mm\)"):
        cut_plan_for(interpret(NEST.replace("THICKNESS=2", "THICKNESS=9"), config), None, config, "nest.ngc")
    with pytest.raises(CutPlanError, match=r"material 'steel' is not in the library .*materials \(known: hide\)"):
        cut_plan_for(program, CutSetup("steel", 2.0, 3), config, "nest.ngc")
    two = NEST.replace("(QUALITY, 5)", "(MATERIAL, hide, THICKNESS=4, QUALITY=5)")
    with pytest.raises(CutPlanError, match=r"line 15: .* names another material or thickness than line 1"):
        cut_plan_for(interpret(two, config), None, config, "nest.ngc")


def test_a_cutting_job_pierces_for_its_chart_s_pierce_time_in_the_run_the_timing_and_a_re_pierce(tmp_path):
    from cnc.planner.runner import ProgramRunner
    from cnc.planner.sections import Pause, pierce_dwell_s

    config = machine(tmp_path)
    assert config.jet.pierce_dwell_s != 0.6
    program = interpret(NEST, config)
    for setup, chart_s in ((CutSetup("hide", 2.0, 3), 0.3), (CutSetup("hide", 4.0, 3, "feed"), 0.6), (None, None)):
        plan = cut_plan_for(program, setup, config, "nest.ngc")[0] if setup else None
        want = chart_s if setup else config.jet.pierce_dwell_s
        assert pierce_dwell_s(config, plan) == want
        pierces = [s for s in iter_steps(program, config, plan) if isinstance(s, Pause) and s.kind == "pierce"]
        assert len(pierces) == 2 and all(p.seconds == pytest.approx(config.jet.on_delay_s + want) for p in pierces)
        runner = ProgramRunner(None, config, steps=iter_steps(program, config, plan), pierce_s=pierce_dwell_s(config, plan))
        while not runner.flags_now & 1:  # into the first cut
            runner.take(16)
        runner.hold()
        while runner.state.name != "HELD":
            runner.take(16)
        runner.resume()
        assert runner.repierce == round((config.jet.on_delay_s + want) / config.timing.period_s), "a re-pierce: the same dwell"


def _whole_elements(elements: list[Element]) -> tuple[list[Element], np.ndarray]:
    """A section's elements with the pieces the planner cuts a long arc into (side by side, the
    same segment) joined into the arc again, and the whole element of each one."""
    out, origin = [], []
    for e in elements:
        prev = out[-1] if out else None
        if (prev is not None and e.kind == ARC and prev.kind == ARC and not e.blend and not prev.blend
                and e.segment == prev.segment):
            joined = Element(ARC, prev.start, e.end, prev.center, prev.cw, 0, prev.feed_mm_s, prev.tolerance_mm, prev.jet,
                             prev.aux, prev.outputs, prev.segment, prev.line, prev.dwell_s, prev.blend)
            joined._sweep = prev.sweep_rad + e.sweep_rad  # a full circle's ends are one point: keep its sweep
            out[-1] = joined
        else:
            out.append(e)
        origin.append(len(out) - 1)
    return out, np.array(origin, dtype=np.int64)


def _stream_speeds_against_caps(program, config, plan) -> float:
    """The highest ratio of the head's speed to the model's cap under it, over every sample the
    planner streams (positions after both averages; the cap of the element at the sample's centre)."""
    worst = 0.0
    dt = config.timing.period_s
    for step in iter_steps(program, config, plan):
        if not isinstance(step, Section):
            continue
        whole, origin = _whole_elements(step.elements)  # the model's caps are the programmed arcs', not their pieces'
        caps = plan.caps(whole, PathArrays.of(whole))[origin]
        if not np.isfinite(caps).any():
            continue
        stream = SectionStream(step)
        ys, ss = [], []
        while not stream.done:
            y, s = stream.take(256)
            ys.append(y)
            ss.append(s)
        y, s = np.concatenate(ys), np.concatenate(ss)
        speed = np.hypot(*np.diff(y[:, :2], axis=0).T) / dt
        where = np.clip(np.searchsorted(step.path.s0, s[1:], side="right") - 1, 0, len(caps) - 1)
        ratio = speed / caps[where]
        worst = max(worst, float(np.max(ratio, initial=0.0)))
    return worst


part = st.tuples(
    st.lists(st.tuples(st.floats(3.0, 40.0), st.floats(-170.0, 170.0), st.booleans(), st.floats(1.0, 15.0)),
             min_size=3, max_size=8),
    st.integers(1, 5), st.floats(2.0, 4.0), st.sampled_from([1200, 3000, 6000, 9000]),
)


@settings(max_examples=15, deadline=None)
@given(part)
def test_the_planned_speed_never_exceeds_the_model_anywhere(tmp_path_factory, drawn):
    """Contours of lines and arcs at random turns, at any quality and thickness: no sample of the
    streamed motion is faster than the model's cap where it is (straights, arcs, corners, lead-in)."""
    moves, quality, thickness, feed = drawn
    config = machine(tmp_path_factory.mktemp("lib"))
    x, y, heading = 100.0, 100.0, 0.0
    lines = [f"(MATERIAL, hide, THICKNESS={thickness:.3f}, QUALITY={quality})", "G21 G90 G64 P0.05", f"G0 X{x} Y{y}",
             "M3", "G4 P0.1", f"G1 X{x + 3:.4f} Y{y:.4f} F{feed}"]
    x += 3.0
    for length, turn, arc, radius in moves:
        heading += math.radians(turn)
        if arc:  # a quarter-ish arc turning left
            cx, cy = x - radius * math.sin(heading), y + radius * math.cos(heading)
            sweep = math.radians(60.0)
            a0 = math.atan2(y - cy, x - cx)
            x, y = cx + radius * math.cos(a0 + sweep), cy + radius * math.sin(a0 + sweep)
            heading += sweep
            lines.append(f"G3 X{x:.4f} Y{y:.4f} R{radius:.4f}")
        else:
            x, y = x + length * math.cos(heading), y + length * math.sin(heading)
            lines.append(f"G1 X{x:.4f} Y{y:.4f}")
    lines += ["M5", "M2"]
    program = interpret("\n".join(lines) + "\n", config)
    plan, _ = cut_plan_for(program, None, config, "t.ngc")
    worst = _stream_speeds_against_caps(program, config, plan)
    assert worst <= 1.0 + 1e-6, f"the head ran {worst:.6f} x the model's cap"


def test_waterjet_check_reports_the_job_and_both_cycle_times_and_refuses_what_the_chart_cannot_answer(tmp_path, capsys):
    shutil.copy(MACHINE_FILE, tmp_path / "machine.toml")
    hide_library(tmp_path / "materials")
    nest = tmp_path / "nest.ngc"
    nest.write_text(NEST)
    machine_file = str(tmp_path / "machine.toml")
    assert main(["check", str(nest), "--machine", machine_file]) == 0
    out = capsys.readouterr().out
    assert "cutting job      hide 2 mm quality 3, by the program" in out
    assert "q1 6000, q2 4800, q3 3600, q4 2400, q5 1200 mm/min straight; slower in corners and arcs (jet lag)" in out
    modelled = float(out.split("cycle time")[1].split()[0])
    at_f = float(out.split("at programmed F")[1].split()[0])
    assert modelled > at_f
    assert main(["check", str(nest), "--machine", machine_file, "--material", "hide", "--thickness", "3",
                 "--quality", "1", "--json", "-"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures["cut"] == "hide 3 mm quality 1, by the operator"
    assert figures["programmed_feed_cycle_time_s"] == pytest.approx(at_f, abs=0.005)
    assert main(["check", str(nest), "--machine", machine_file, "--material", "hide", "--thickness", "5",
                 "--quality", "1"]) == 1
    assert "thickness 5 mm is outside its chart (2 to 4 mm)" in capsys.readouterr().err


def _overlap_speeds(program, config, plan) -> tuple[np.ndarray, np.ndarray]:
    """Each record's path speed as the runner streams the program under its cutting job, and whether
    it is a corner overlap's (the sum of two moves: `ProgramRunner.overlap_left`)."""
    from cnc.planner.runner import ProgramRunner

    runner = ProgramRunner(None, config, steps=iter_steps(program, config, plan), pierce_s=pierce_dwell_s(config, plan))
    positions, summed = [], []
    while not runner.finished:
        in_overlap = runner.overlap_left > 0
        records, _ = runner.take(1)
        positions += list(records["position"][:, :2])
        summed += [in_overlap] * len(records)
    xy = np.asarray(positions)
    speed = np.concatenate(([0.0], np.hypot(*np.diff(xy, axis=0).T))) / config.timing.period_s
    return speed, np.asarray(summed, dtype=bool)


def test_a_corner_passed_in_an_overlap_keeps_the_model_s_cap_for_its_turn(tmp_path, monkeypatch):
    """Stopped at, a corner needs no cap: the bottom of the jet catches up while the head stands.
    Passed in a corner overlap, the head turns at speed: under a cutting job every summed sample
    keeps the model's cap of the turn (`sections._overlap_cap`), which at the finest quality is
    below what the overlap would otherwise pass at."""
    from cnc.planner import sections

    config = machine(tmp_path)
    text = ("(MATERIAL, hide, THICKNESS=2, QUALITY=5)\nG21 G90 G64 P0.05\nG0 X100 Y100\nM3\nG4 P0.1\n"
            "G1 X103 Y100 F6000\nG1 X103 Y140\nG1 X143 Y140\nM5\nM2\n")
    program = interpret(text, config)
    plan, _ = cut_plan_for(program, None, config, "corner.ngc")
    cap = float(plan.model.turn_cap(5, math.pi / 2.0))
    speed, summed = _overlap_speeds(program, config, plan)
    assert summed.any(), "the corner is still overlapped"
    assert speed[summed].max() <= cap * (1.0 + 1e-6)
    straight = float(plan.model.speed_mm_s[5])
    with monkeypatch.context() as m:
        m.setattr(sections, "_overlap_cap", lambda a, b, cut: math.inf)
        uncapped, summed_uncapped = _overlap_speeds(program, config, plan)
    assert uncapped[summed_uncapped].max() > cap, "without the cap the overlap would turn faster than the model allows"
    assert uncapped[summed_uncapped].max() > straight, "... and pass a hair over the quality's speed"

    # a chart without trail-back: no corner cap, yet the sum never passes over the quality's speed
    no_lag = "\n".join(ln for ln in HIDE.splitlines() if not ln.startswith(("lag_mm", "corner_mm")))
    (tmp_path / "materials" / "hide.toml").write_text(no_lag)
    program = interpret(text, config)
    plan, _ = cut_plan_for(program, None, config, "corner.ngc")
    assert not plan.model.corners_modelled
    speed, summed = _overlap_speeds(program, config, plan)
    assert summed.any() and speed[summed].max() <= straight * (1.0 + 1e-6)


@pytest.mark.parametrize("seed", [7, 10, 29, 38])  # a hold, a raise to 200 %, a stop, a hold; F2400-F12000
def test_random_cam_parts_cut_under_the_model_keep_its_caps_the_limits_p_and_their_timing(tmp_path, seed):
    """Round CAM parts with lead-ins off square (`test_planner_overlap._random_cam_parts`, each cut
    with the jet) under a cutting job of random thickness and quality: no streamed sample runs
    faster than the model's cap where it is; run, every axis keeps its limits and every record P,
    and the job's timing is the run's to the servo period; with a hold, an override change or a stop
    at a random moment, the limits and P still hold. 300 seeds of this ran clean (2026-12-07)."""
    import random

    from .test_planner_motion import records_of, within_limits, within_tolerance
    from .test_planner_overlap import _random_cam_parts

    rng = random.Random(seed)
    config = machine(tmp_path)
    text, chunk = _random_cam_parts(seed, jet=True)
    text = f"(MATERIAL, hide, THICKNESS={rng.choice([2, 3, 4])}, QUALITY={rng.randint(1, 5)})\n{text}"
    program = interpret(text, config)
    plan, _ = cut_plan_for(program, None, config, "parts.ngc")
    assert _stream_speeds_against_caps(program, config, plan) <= 1.0 + 1e-6
    records = records_of(program, config, chunk, cut=plan)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == ProgramTiming.of(program, config, plan).total_ticks
    event = (rng.randint(20, len(records) - 20), rng.choice(["hold", 0.3, 1.5, 2.0, "stop"]))
    records = records_of(program, config, chunk, event, plan)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all(), event
