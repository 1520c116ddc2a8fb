"""Streaming: a program's steps are made as the motion reaches them, within a bounded window, its
cycle time beside it; the first setpoints need only the first steps, whatever the program's size;
a start from a head moved since loading shifts the interpreted program instead of interpreting
it again. Operation counts (steps made, steps held), not wall time: the figures are in
bench/gcode_speed.py and docs/benchmarks.md."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from bench.nests import cam_nest
from cnc.bus.messages import GoTo, LoadProgram, Start
from cnc.data.layout import PlannerState, RunResult
from cnc.machine_dialect import dialect_for
from cnc.planner.process import TIMED_AT_LOAD_SEGMENTS
from cnc.planner.rebase import PROBE_MM, start_shift
from cnc.planner.overlap import CornerOverlap
from cnc.planner.runner import ProgramRunner
from cnc.planner.sections import Section, iter_steps, program_steps
from cnc.planner.steps import STEPS_AHEAD, ProgramTiming, StepSource
from gcode.interp import Interpreter

from .conftest import ask, machine_config, wait_planner_idle


@pytest.fixture(scope="module")
def config():
    return machine_config()


def interpret(text: str, config, start=(0.0, 0.0, 0.0)):
    dialect = dataclasses.replace(dialect_for(config), start_position_mm=tuple(start))
    return Interpreter(dialect, "t.ngc").run(text.encode())


def run_streamed(program, config, burst: int = 200, first: int | None = None):
    """A runner on a step source (as the planner runs a loaded program), taken to its end (or to
    its first `first` records); the source, the records made and how far ahead the steps were."""
    source = StepSource(iter_steps(program, config))
    runner = ProgramRunner(None, config, steps=source, timing=ProgramTiming(config.timing.period_s, CornerOverlap.of(config)))
    made, ahead = 0, 0
    while not runner.finished and (first is None or made < first):
        records, _ = runner.take(burst if first is None else min(burst, first - made))
        made += len(records)
        runner.prepare(0.5)  # what the planner's worker does after each refill
        ahead = max(ahead, source.made - runner.index)
    return source, runner, made, ahead


@pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)
def test_a_long_nest_streams_its_steps_in_a_bounded_window_and_runs_its_planned_time(config):
    program = interpret(cam_nest(40), config)
    steps = program_steps(program, config)
    source, runner, made, ahead = run_streamed(program, config)
    assert runner.state.name == "DONE"
    assert source.made == len(steps) and len(steps) > 4 * STEPS_AHEAD, "every step made, many more than the window"
    assert source.largest_window <= STEPS_AHEAD + 2, "the window holds the step under way and what is made ahead"
    assert ahead <= STEPS_AHEAD + 1
    timing = ProgramTiming(config.timing.period_s, CornerOverlap.of(config)).compute(iter_steps(program, config))
    assert timing.complete and timing.total_ticks == made, "the timing is exactly what the run streams"
    assert timing.total_mm == pytest.approx(sum(s.length_mm for s in steps if isinstance(s, Section)), rel=1e-12)


def test_the_first_setpoints_need_the_same_few_steps_whatever_the_programs_size(config):
    counts = []
    for parts in (10, 200):
        program = interpret(cam_nest(parts), config)
        source, runner, made, _ = run_streamed(program, config, first=300)
        assert made == 300
        counts.append(source.made)
    assert counts[0] == counts[1] <= STEPS_AHEAD + 2, counts


def test_the_eta_is_unknown_until_the_timing_is_made_then_exact(config):
    program = interpret(cam_nest(3), config)
    timing = ProgramTiming(config.timing.period_s, CornerOverlap.of(config))
    runner = ProgramRunner(None, config, steps=StepSource(iter_steps(program, config)), timing=timing)
    runner.take(100)
    assert np.isnan(runner.remaining_s()), "no ETA from a timing still being made"
    timing.compute(iter_steps(program, config))
    left = runner.remaining_s()
    made = 0
    while not runner.finished:
        made += len(runner.take(500)[0])
    assert left == pytest.approx(made * config.timing.period_s, abs=2 * config.timing.period_s)


def _nest_with_awkward_pierces(parts: int) -> tuple[str, int, int]:
    """A CAM nest whose 5th pierce has an M0 before it and whose 9th a zero-length rapid: the two
    pierces at which its timing may not be cut (the numbers of those two parts come back)."""
    lines, pierces, out = cam_nest(parts, inch_every=7, comments=True).splitlines(), 0, []
    for ln in lines:
        if ln == "M3":
            pierces += 1
            if pierces == 5:
                out.append("M0")
            elif pierces == 9:
                out.append(out[-1])  # the rapid to the part once more: a move of length 0
        out.append(ln)
    return "\n".join(out) + "\n", 5, 9


def test_a_programs_timing_in_pieces_cut_at_pierces_is_the_whole_programs_to_the_tick(config, monkeypatch, tmp_path):
    """A large program is timed in pieces cut at pierces, at once by forked processes on a host
    with more than one CPU (`ProgramTiming.of(workers=...)`): the same steps, ticks and path
    length as timed whole. Cut at a pierce with a program stop before it, the pieces would lose
    that stop (the whole program's M0 waits there); the cuts avoid it, and a pierce after a
    zero-length move (which makes no element)."""
    from cnc.planner import steps as steps_module
    from cnc.planner.sections import pierce_boundaries

    text, with_stop, after_nothing = _nest_with_awkward_pierces(40)
    program = interpret(text, config)
    dt = config.timing.period_s
    whole = ProgramTiming.of(program, config)
    at = pierce_boundaries(program)
    jet_on = np.flatnonzero(program.segments["jet"][1:] & ~program.segments["jet"][:-1]) + 1
    assert len(jet_on) == 40 and len(at) == 38, "every pierce but the two"
    assert jet_on[with_stop - 1] not in at and jet_on[after_nothing - 1] not in at
    cut = int(jet_on[with_stop - 1])
    split = [*iter_steps(program, config, None, 0, cut), *iter_steps(program, config, None, cut)]
    assert len(split) == len(whole.step_ticks) - 1, "cut at the M0's pierce, its program stop is lost"

    monkeypatch.setattr(steps_module, "PIECE_SEGMENTS", 100)  # many pieces of a small program
    spans = steps_module._pieces(program, 3)
    assert len(spans) >= 8 and spans[0][0] == 0 and spans[-1][1] == len(program.segments)
    assert all(a == b for (_, a), (b, _) in zip(spans[:-1], spans[1:])), "the pieces cover the program"
    by_piece = [t for a, b in spans
                for t in ProgramTiming(dt, CornerOverlap.of(config)).compute(iter_steps(program, config, None, a, b)).step_ticks]
    assert by_piece == list(whole.step_ticks)
    # forked, as `waterjet check` and the timing process do it: in a process of its own (this one
    # has threads, Zenoh's and Qt's, and a fork copies none of them but their locks)
    path = tmp_path / "nest.ngc"
    path.write_text(text)
    code = (
        "import dataclasses, json, sys\n"
        "from cnc.config import load_machine\n"
        "from cnc.machine_dialect import dialect_for\n"
        "from cnc.planner import steps\n"
        "from gcode.interp import Interpreter\n"
        "steps.PIECE_SEGMENTS = 100\n"
        "config = load_machine(sys.argv[1])\n"
        "dialect = dataclasses.replace(dialect_for(config), start_position_mm=(0.0, 0.0, 0.0))\n"
        "program = Interpreter(dialect, 't.ngc').run(open(sys.argv[2], 'rb').read())\n"
        "t = steps.ProgramTiming.of(program, config, workers=2)\n"
        "print(json.dumps({'failure': repr(t.failure), 'ticks': list(t.step_ticks), 'mm': t.total_mm}))\n"
    )
    res = subprocess.run([sys.executable, "-c", code, str(config.source), str(path)], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parent.parent, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    forked = json.loads(res.stdout)
    assert forked["failure"] == "None" and forked["ticks"] == list(whole.step_ticks)
    assert forked["mm"] == pytest.approx(whole.total_mm, rel=1e-12)


SHIFTABLE = {
    "absolute nest": cam_nest(2),
    "first move names X only": "G21 G90\nG1 X50 F3000\nG1 Y40\nM3\nG1 X80\nM5\nM2\n",
    "incremental program": "G21 G91\nG1 X10 Y5 F3000\nG3 X10 Y0 I5 J0\nG90 G1 X100 Y100\nM2\n",
    "G92 at the start": "G21 G90\nG92 X0 Y0\nG1 X20 Y10 F3000\nG2 X40 Y10 I10 J0\nM2\n",
    "dwell where the head stands": "G21 G90\nG4 P0.5\nM3\nG1 X30 Y30 F3000\nM5\nM2\n",
}


@pytest.mark.parametrize("name", sorted(SHIFTABLE))
def test_a_program_started_from_a_moved_head_is_the_program_interpreted_from_there(config, name):
    text = SHIFTABLE[name]
    here, there = (120.0, 80.0, 0.0), (333.25, 17.5, 0.0)
    program = interpret(text, config, here)
    probe = interpret(text, config, tuple(a + b for a, b in zip(here, PROBE_MM[:2] + (0.0,))))
    shift = start_shift(program, probe, PROBE_MM[:2] + (0.0,))
    assert shift is not None, f"{name}: a pure shift of its start"
    moved = shift.apply(program, tuple(b - a for a, b in zip(here, there)))
    truth = interpret(text, config, there).segments
    for field in ("start", "end", "center"):
        np.testing.assert_allclose(moved.segments[field], truth[field], atol=1e-9, err_msg=f"{name}: {field}")
    for field in ("kind", "line", "jet", "cw", "turns"):
        assert np.array_equal(moved.segments[field], truth[field]), f"{name}: {field}"
    np.testing.assert_array_equal(program.segments["start"], interpret(text, config, here).segments["start"])


def test_a_program_whose_shape_depends_on_the_start_is_not_shifted(config):
    text = "G21 G90\nG2 X50 Y0 R40 F3000\nM2\n"  # an R arc from wherever the head is: its centre is not a shift
    here = (10.0, 0.0, 0.0)
    program = interpret(text, config, here)
    probe = interpret(text, config, (10.375, 0.25, 0.0))
    assert start_shift(program, probe, (0.375, 0.25, 0.0)) is None


def test_a_loaded_program_started_after_the_head_moved_runs_from_there_and_keeps_its_planned_time(homed, tmp_path):
    sup = homed
    text = "G21 G90 G64 P0.05\nG1 X200 F6000\nG1 Y150\nM3\nG1 X260\nM5\nM2\n"  # the first move keeps Y, the second X
    path = tmp_path / "moved.ngc"
    path.write_text(text)
    ask(sup, LoadProgram(str(path)))
    sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 60.0, "the cycle time")
    ask(sup, GoTo({"x": 60.0, "y": 90.0}))
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE and sup.servo()["commanded_mm"] == [60.0, 90.0], 60.0,
                   "the go-to")
    pushed = sup.motion()["records_pushed"]
    sup.pause_virtual_clock()
    try:
        ask(sup, Start())
        planned = sup.motion()["planned_s"]
        sup.run_ticks(20)
        first_y = sup.servo()["commanded_mm"][1]
    finally:
        sup.resume_virtual_clock()
    m = wait_planner_idle(sup)
    assert m["run_result"] == RunResult.DONE
    # (within the hair its corner moved outward tilts it by: `sections._move_stop_corners`)
    assert first_y == pytest.approx(90.0, abs=1e-3), "the first move keeps the Y the head was moved to"
    assert sup.servo()["commanded_mm"] == pytest.approx([260.0, 150.0], abs=1e-6)
    sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 60.0, "the cycle time from there")
    assert (m["records_pushed"] - pushed) * sup.config.timing.period_s == pytest.approx(sup.motion()["planned_s"], abs=1e-9)
    assert planned == sup.motion()["planned_s"] > 0.0, "a program this short is timed before the start answers"


def timing_dirs() -> set[str]:
    return {p.name for p in Path(tempfile.gettempdir()).glob("wjcnc-timing-*")}


def timing_processes(planner_pid: int) -> list[int]:
    """The processes timing a program for this planner: its timing process and the pieces it forked
    (they carry its command line, which names the planner's directory)."""
    from cnc.planner.timing_process import DIR_PREFIX

    found = []
    for d in Path("/proc").iterdir():
        try:
            cmd = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"cnc.planner.timing_process" in cmd and any(f"{DIR_PREFIX}{planner_pid}-".encode() in c for c in cmd):
            found.append(int(d.name))
    return found


def test_a_large_programs_cycle_time_is_planned_in_a_process_of_its_own_exactly(homed, tmp_path):
    """Beyond TIMED_AT_LOAD_SEGMENTS the cycle time is planned by a child process (in pieces, by
    processes it forks, on a host with more than one CPU); it is the same profile the run streams,
    a replaced program's timing is stopped, its pieces too, and nothing is left behind."""
    sup = homed
    before = timing_dirs()
    big, bigger = tmp_path / "big.ngc", tmp_path / "bigger.ngc"
    big.write_text(cam_nest(60))
    bigger.write_text(cam_nest(400))
    ask(sup, LoadProgram(str(bigger)))
    ask(sup, LoadProgram(str(big)))  # replaces it while its timing is under way
    sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 120.0, "the cycle time")
    start = sup.servo()["commanded_mm"]
    program = interpret(big.read_text(), sup.config, (start[0], start[1], 0.0))
    assert len(program.segments) > TIMED_AT_LOAD_SEGMENTS
    timing = ProgramTiming(sup.config.timing.period_s, CornerOverlap.of(sup.config)).compute(iter_steps(program, sup.config))
    m = sup.motion()
    assert m["planned_s"] == pytest.approx(timing.total_ticks * sup.config.timing.period_s, abs=1e-9)
    assert m["total_mm"] == pytest.approx(timing.total_mm, rel=1e-12)
    sup.wait_until(lambda: timing_dirs() <= before, 30.0, "the timing processes' files removed")
    sup.wait_until(lambda: not timing_processes(sup.children["planner"].process.pid), 30.0, "the timing processes ended")


def test_timing_files_a_killed_planner_left_are_removed_and_a_living_ones_kept(tmp_path):
    from cnc.planner.timing_process import DIR_PREFIX, remove_stale

    dead = 4_000_000  # above Linux's pid_max: never a living process
    assert not Path(f"/proc/{dead}").exists()
    stale = Path(tempfile.mkdtemp(prefix=f"{DIR_PREFIX}{dead}-"))
    living = Path(tempfile.mkdtemp(prefix=f"{DIR_PREFIX}{os.getpid()}-"))
    (stale / "segments.npy").write_bytes(b"x")
    try:
        remove_stale()
        assert not stale.exists() and living.exists()
    finally:
        shutil.rmtree(living, ignore_errors=True)
        shutil.rmtree(stale, ignore_errors=True)


def test_a_section_at_zero_percent_before_it_began_is_planned_as_standing_still_not_forever():
    """A section whose motion has not begun while the override is 0 % (or a hold): asked to be
    planned some periods ahead (as the runner asks of the next section at a corner), it stands at
    its start. Its planning looped for ever there, and the planner process hung, answering nothing
    (found by an operator pressing everything at random, an override of 0 % among it). Raised again
    (or resumed), it runs to its end."""
    from cnc.planner.stream import SectionStream

    config = machine_config()
    program = Interpreter(dialect_for(config), "zero.ngc").run(b"G21 G90 G64 P0.05\nG1 X100 F6000\nM2\n")
    section = next(s for s in iter_steps(program, config) if isinstance(s, Section))
    for stop, go in ((lambda st: st.set_override(0.0, 0.0), lambda st: st.set_override(1.0, 1.0)),
                     (lambda st: st.hold(), lambda st: st.resume())):
        stream = SectionStream(section)
        stop(stream)
        stream.plan_until(112)  # returns
        assert not len(stream.pieces) and not stream.final
        positions, _ = stream.take(50)
        assert len(positions) == 0 or np.allclose(positions[:, 0], 0.0), "standing at its start"
        go(stream)
        last = None
        while not stream.done:
            positions, _ = stream.take(500)
            last = positions[-1] if len(positions) else last
        assert last[0] == pytest.approx(100.0)
