"""A program's timing makes each shape of part once: runs of elements between two pauses that are
the same but for where they are (a nest of the same few parts) are timed from the first of them
(`sections.RunMemo`), to the tick of what the run streams. Counts of runs made, not wall time: the
speed is in bench/timing_memo.py and docs/benchmarks.md."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bench.nests import production_nest, turned_nest
from cnc.machine_dialect import dialect_for
from cnc.planner import sections as sections_module
from cnc.planner.overlap import CornerOverlap
from cnc.planner.path import Element
from cnc.planner.quality import cut_plan_for
from cnc.planner.runner import ProgramRunner
from cnc.planner.sections import KnownRun, RunMemo, iter_steps, run_key, run_keys
from cnc.planner.steps import ProgramTiming, StepSource
from gcode.canon import LINE
from gcode.interp import Interpreter

from .conftest import machine_config
from .test_cut_model import machine as hide_machine

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)


@pytest.fixture(scope="module")
def config():
    return machine_config()


def interpret(text: str, config):
    dialect = dataclasses.replace(dialect_for(config), start_position_mm=(0.0, 0.0, 0.0))
    return Interpreter(dialect, "nest.ngc").run(text.encode())


def timed(program, config, cut=None, memo: RunMemo | None = None) -> ProgramTiming:
    timing = ProgramTiming(config.timing.period_s, CornerOverlap.of(config)).compute(
        iter_steps(program, config, cut, memo=memo))
    assert timing.failure is None, timing.failure
    return timing


def counting_runs(monkeypatch) -> list[int]:
    """The sizes of the runs whose sections are made, from now on."""
    made: list[int] = []
    real = sections_module._sections_of

    def counted(run, *args, **kwargs):  # noqa: ANN001, ANN202
        made.append(len(run))
        return real(run, *args, **kwargs)

    monkeypatch.setattr(sections_module, "_sections_of", counted)
    return made


def streamed_ticks(program, config) -> int:
    """What the planner's runner makes of the program, record by record, to its end."""
    runner = ProgramRunner(None, config, steps=StepSource(iter_steps(program, config)),
                           timing=ProgramTiming(config.timing.period_s, CornerOverlap.of(config)))
    made = 0
    while not runner.finished:
        made += len(runner.take(500)[0])
    assert runner.state.name == "DONE"
    return made


def timed_with_memo(program, config, monkeypatch) -> tuple[ProgramTiming, ProgramTiming, list[int], RunMemo]:
    """The program timed run by run, then with a memo: both timings, the sizes of the runs the memo
    made, the memo; every step's ticks the same."""
    plain = timed(program, config)
    made = counting_runs(monkeypatch)
    memo = RunMemo()
    remembered = timed(program, config, memo=memo)
    assert list(remembered.step_ticks) == list(plain.step_ticks), "every step's ticks as timed one by one"
    return plain, remembered, made, memo


def test_a_nest_of_repeated_parts_is_timed_once_per_shape_and_to_the_tick(config, monkeypatch):
    program = interpret(production_nest(60, shapes=5), config)
    plain, remembered, made, memo = timed_with_memo(program, config, monkeypatch)
    assert remembered.total_mm == pytest.approx(plain.total_mm, rel=1e-12)
    contours = [n for n in made if n > 1]
    assert len(contours) == 5, f"each shape's run of lead-in, contour and lead-out made once, not {len(contours)} times"
    assert memo.hits >= 55
    assert streamed_ticks(program, config) == remembered.total_ticks, "what the run streams"
    assert ProgramTiming.of(program, config).total_ticks == remembered.total_ticks, "`waterjet check`'s timing"


def test_copies_turned_and_mirrored_are_timed_once_per_shape_and_to_the_tick(config, monkeypatch):
    """A nesting program turns parts to fit and pairs left and right ones: each shape's copies come
    in eight orientations (quarter turns, mirrors across X, Y and the diagonals, compensated on the
    other side when mirrored). X and Y have the same limits here, so each orientation is timed as
    the first copy was, and to the tick of timing every copy."""
    program = interpret(turned_nest(96, shapes=6), config)
    _, remembered, made, _ = timed_with_memo(program, config, monkeypatch)
    assert len([n for n in made if n > 1]) == 6, "each shape made once, whichever way it is turned"
    assert streamed_ticks(program, config) == remembered.total_ticks, "what the run streams"


def test_on_a_machine_whose_x_and_y_differ_only_mirrors_and_half_turns_are_taken_for_each_other(monkeypatch):
    """With Y slower than X, a part turned by a quarter runs its long sides on the other axis: its
    own time. Mirrored in X or Y, or turned by a half, each axis keeps what it moved: the same."""
    config = machine_config(**{"axis.y.max_accel_mm_s2": 3000.0})
    program = interpret(turned_nest(96, shapes=6), config)
    _, _, made, _ = timed_with_memo(program, config, monkeypatch)
    assert len([n for n in made if n > 1]) == 12, "each shape made twice: along its sides and across them"
    run = [e for e in iter_steps(program, config)][3].elements  # the first part's contour
    assert len(run_keys(run, None, config)) == 4 and len(run_keys(run, None, machine_config())) == 8


def test_the_same_part_at_another_quality_or_feed_is_timed_again(tmp_path, monkeypatch):
    """The cutting model's quality and the feed are part of a run's shape: the same contour cut at
    quality 5 after `(QUALITY, 5)`, or at another F, takes its own time."""
    config = hide_machine(tmp_path)
    lines = production_nest(12, shapes=3).splitlines()
    pierces = [i for i, ln in enumerate(lines) if ln == "M3"]
    lines.insert(pierces[6] - 1, "(QUALITY, 5)")  # before the 7th part's rapid: parts 7-12 at quality 5
    lines.insert(2, "(MATERIAL, hide, THICKNESS=2, QUALITY=3)")
    text = "\n".join(lines) + "\n"
    program = interpret(text, config)
    plan, _ = cut_plan_for(program, None, config, "nest.ngc")
    plain = timed(program, config, plan)
    made = counting_runs(monkeypatch)
    remembered = timed(program, config, plan, RunMemo())
    assert list(remembered.step_ticks) == list(plain.step_ticks)
    assert len([n for n in made if n > 1]) == 6, "three shapes at two qualities"
    ticks = np.asarray(plain.step_ticks)
    per_part = np.add.reduceat(ticks, np.flatnonzero(_pierce_steps(program, config, plan)))
    assert per_part[1] == per_part[4] and per_part[7] == per_part[10], "the same shape, the same quality"
    assert per_part[1] < per_part[7], "quality 5 is slower than 3 for the same part"

    # at F as programmed (no cutting job): the first six parts' lead-ins and contours faster
    faster = interpret(text.replace("F2400.0", "F3000.0", 6), config)
    made.clear()
    remembered = timed(faster, config, None, RunMemo())
    assert len([n for n in made if n > 1]) == 6, "three shapes at two feeds"
    assert list(remembered.step_ticks) == list(timed(faster, config).step_ticks)


def _pierce_steps(program, config, cut) -> np.ndarray:  # noqa: ANN001 - a CutPlan
    """Per step: whether it is a pierce."""
    return np.array([getattr(s, "kind", "") == "pierce" for s in iter_steps(program, config, cut)])


def test_parts_called_as_a_subroutine_at_odd_places_are_remembered_whatever_the_rounding(config, monkeypatch):
    """An O-word part called at origins no binary fraction holds: its points differ from one call to
    the next by the rounding of the additions, not by a micrometre, and each shape is made once."""
    body = ["O100 SUB", "G41 D1 G1 X[#1 + #3] Y#2 F2400", "G1 X[#1 + #3 * 0.5] Y[#2 + #3 * 0.866]",
            "G3 X[#1 - #3] Y#2 R#3", "G1 X[#1 + #3 * 0.2] Y[#2 - #3 * 0.9]", "G2 X[#1 + #3] Y#2 R[#3 * 1.1]",
            "G40 G1 X[#1 + #3 + 2] Y[#2 - 2]", "O100 ENDSUB"]
    text = ["G21 G90 G17 G64 P0.05", "T1 M6", "F3000", *body]
    for k in range(40):
        ox, oy = 40.1 + (k % 8) * 61.37, 30.3 + (k // 8) * 47.91
        text += [f"G0 X{ox + 12.0:.4f} Y{oy - 3:.4f}", "M3", "G4 P0.3", f"O100 CALL [{ox:.4f}] [{oy:.4f}] [{(8.5, 12.25)[k % 2]}]",
                 "M5"]
    program = interpret("\n".join([*text, "G0 X0 Y0", "M2"]) + "\n", config)
    plain = timed(program, config)
    made = counting_runs(monkeypatch)
    memo = RunMemo()
    assert list(timed(program, config, memo=memo).step_ticks) == list(plain.step_ticks)
    assert len([n for n in made if n > 1]) == 2, "two radii, each part made once"


def test_only_runs_between_pauses_without_tiny_elements_are_remembered_and_the_memo_stays_bounded(config, monkeypatch):
    """A run joined to its neighbour by a corner overlap shares samples with it: never remembered.
    Nor is a run with an element shorter than a micrometre (its direction is the rounding), and the
    memo holds at most its size, dropping the oldest."""
    here = (10.0, 10.0, 0.0)

    def line(a, b):  # noqa: ANN001, ANN202
        return Element(LINE, a, b, None, False, 0, 40.0, 0.05, True, 0, 0, 0, 0)
    assert run_key([line(here, (20.0, 10.0, 0.0))]) == run_key([line((110.0, 50.0, 0.0), (120.0, 50.0, 0.0))])
    assert run_key([line(here, (20.0, 10.0, 0.0)), line((20.0, 10.0, 0.0), (20.0, 10.0, 5e-4))]) is None

    # the abrasive switched on after the lead-in and off before the lead-out, the jet staying open: the
    # three runs of each part meet at stops a corner overlap may join, with no pause between them
    lines = []
    for ln in production_nest(8, shapes=2).splitlines():
        lines += [ln, "M7"] if ln.startswith(("G41", "G42")) else ["M9", ln] if ln.startswith("G40") else [ln]
    program = interpret("\n".join(lines) + "\n", config)
    plain = timed(program, config)
    made = counting_runs(monkeypatch)
    assert list(timed(program, config, memo=RunMemo()).step_ticks) == list(plain.step_ticks)
    assert len([n for n in made if n > 1]) == 8, "every part's contour made: none remembered"
    made.clear()

    program = interpret(production_nest(30, shapes=3), config)
    plain = timed(program, config)
    small = RunMemo(size=2)
    made = counting_runs(monkeypatch)
    assert list(timed(program, config, memo=small).step_ticks) == list(plain.step_ticks)
    assert len(small.kept) == 2 and len([n for n in made if n > 1]) == 30, "three shapes in turn through two places"
    assert len(small.runs) == 2 * 8, "each kept under its key in the eight orientations of a machine with X and Y alike"
    memo = RunMemo()
    timed(program, config, memo=memo)
    assert any(isinstance(s, KnownRun) for s in iter_steps(program, config, memo=memo)), "known runs come whole"
