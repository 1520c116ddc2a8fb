"""Contours of the general path offset in batches give exactly what the per-move compensator gives:
the same pieces in the same order, the same events between them, the same first error."""

from __future__ import annotations

import re

import numpy as np
import pytest

from bench.nests import cam_nest
from gcode import kerf_batch
from gcode.errors import GCodeError
from gcode.interp import Interpreter
from tests.test_gcode_fastpath import NEST_DIALECT, _nest, _same

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)


def _both(text: str, counts: dict | None = None):
    """The program interpreted per move (no fast path, no batches) and as the interpreter runs it;
    `counts` gets the stretches offset in bulk and replayed per move."""
    out = []
    for fast in (False, True):
        ip = Interpreter(NEST_DIALECT, "p.ngc", fast=fast)
        try:
            out.append(ip.run(text))
        except GCodeError as err:
            out.append(err)
    if counts is not None:
        counts.update(bulk=ip.kerf.offset_in_bulk, replayed=ip.kerf.replayed)
    return out


def _general(text: str, every: int = 1, messages: bool = False) -> str:
    """Every `every`-th part's coordinates written as expressions, so that the general path runs
    them (the fast path takes no brackets); the other parts stay plain for the fast path.
    `messages`: a message before each part and a nozzle change before every fifth."""
    parts = re.split(r"(?m)^(?=G0 X)", text)
    coord = re.compile(r"([XYIJR])(-?\d+\.?\d*)")
    out = []
    for k, p in enumerate(parts):
        if messages and k:
            out.append(f"(MSG, part {k})\n" + (f"T{1 + k % 2} M6\n" if k % 5 == 0 else ""))
        out.append(coord.sub(r"\1[\2 + 0]", p) if k % every == 0 else p)
    return "".join(out)


def _segments_equal(slow, fast) -> None:
    _same(slow, fast)
    if not isinstance(slow, GCodeError):
        assert slow.stats.cut_length_mm == pytest.approx(fast.stats.cut_length_mm, rel=1e-12)
        assert np.allclose(slow.stats.bounds_min, fast.stats.bounds_min)
        assert np.allclose(slow.stats.bounds_max, fast.stats.bounds_max)


def test_a_subroutine_nest_batched_equals_the_per_move_compensator():
    counts = {}
    slow, fast = _both(cam_nest(150, subroutines=True, comments=True), counts)
    assert not isinstance(slow, GCodeError), str(slow)
    _segments_equal(slow, fast)
    assert counts == {"bulk": 150, "replayed": 0}
    assert slow.stats.pierces == 150 and len(slow.segments) > 150 * 26


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("every, messages", [(1, False), (2, False), (1, True)])
def test_general_path_nests_batched_equal_the_per_move_compensator(seed, every, messages):
    """Both sides, nozzle-table and direct diameters, lines and arcs, events inside contours and
    bare G40s (replayed per move), parts of the fast path between them (`every` = 2), messages
    and nozzle changes between the parts."""
    counts = {}
    slow, fast = _both(_general(_nest(seed), every, messages), counts)
    assert not isinstance(slow, GCodeError), str(slow)
    _segments_equal(slow, fast)
    if messages:
        kinds = [m.kind for m in fast.messages]
        assert kinds.count("message") >= 60 and kinds.count("tool") >= 12
    assert counts["bulk"] > 60 / every / 2 and counts["bulk"] + counts["replayed"] <= 60


@pytest.mark.parametrize("seed", range(3))
def test_a_gouge_is_reported_as_the_per_move_compensator_reports_it(seed):
    slow, fast = _both(_general(_nest(seed, gouge_at=20 + seed * 7)))
    assert isinstance(slow, GCodeError) and slow.code == "kerf-concave-corner", str(slow)
    _segments_equal(slow, fast)


def test_a_queued_gouge_comes_before_a_later_error_of_the_interpreter():
    """The gouge's contour still waits in the queue when the interpreter meets an unknown G code
    lines later: the gouge, the earlier line, is the error reported."""
    text = _general(_nest(1, gouge_at=5)).replace("G0 X0 Y0\nM2", "G0 X0 Y0\nG7.5 X1\nM2")
    slow, fast = _both(text)
    assert isinstance(fast, GCodeError) and fast.code == "kerf-concave-corner", str(fast)
    _segments_equal(slow, fast)


CONTOUR = "G1 X[20 + #1] Y[10]\nG1 X[20 + #1] Y[20]\nG3 X[10 + #1] Y[30] I[-10] J[0]\nG1 X[#1] Y[30]\nG1 X[#1] Y[10]\n"


@pytest.mark.parametrize("inside, what", [
    ("G0 X[25 + #1] Y[20]\n", "a rapid inside the contour"),
    ("G1 Z-1\n", "a pure Z move"),
    ("G4 P0.5\n", "a dwell"),
    ("(MSG, inside the contour)\n", "a message"),
    ("M0\n", "a program stop (flush)"),
    ("G2 X[20 + #1] Y[20] I[0] J[5] P2\n", "a multi-turn arc"),
    ("G2 X[20 + #1] Y[20] I[0] J[0.2]\n", "an inside arc smaller than the jet"),
])
def test_what_only_the_per_move_compensator_handles_gives_its_result(inside, what):
    """Each of these inside a contour sends the stretch back to the per-move compensator, in its
    place among the stretches before and after it (three parts: the middle one has it)."""
    body = CONTOUR.split("\n")
    odd = "\n".join(body[:2]) + "\n" + inside + "\n".join(body[2:])
    parts = []
    for k, contour in enumerate((CONTOUR, odd, CONTOUR)):
        parts += [f"#1 = {k * 50}", "G0 X[#1 - 3] Y[7]", "M3", f"G41 D1 G1 X[#1] Y[10]", contour.rstrip(), "G40 G1 X[#1 - 4] Y[6]", "M5"]
    text = "G21 G90 G17 F2400\n" + "\n".join(parts) + "\nG0 X0 Y0\nM2\n"
    counts = {}
    slow, fast = _both(text, counts)
    _segments_equal(slow, fast)
    if not isinstance(slow, GCodeError):
        assert counts == {"bulk": 2, "replayed": 1}, what


@pytest.mark.parametrize("case, code", [
    ("G41 D1 G3 X[#1] Y[10] I[3] J[0]\n" + CONTOUR + "G40 G1 X[#1 - 4] Y[6]\n", None),  # an entry arc
    ("G41 D1 G1 X[#1] Y[10]\n" + CONTOUR + "G40\nG41 D1 G1 X[#1 + 1] Y[9]\nG40 G1 X[#1 - 4] Y[6]\n", None),  # G41 before the exit
    ("G41 D1 G1 X[#1] Y[10]\n" + CONTOUR + "G40 G2 X[#1 - 4] Y[6] R5\n", "kerf-exit"),  # an arc exit
    ("G41 D1 G1 X[#1] Y[10]\nG40 G1 X[#1 - 4] Y[6]\n", None),  # an entry, then G40 at once
    ("G41 D1 G1 X[#1 + 0.3] Y[10]\n" + CONTOUR + "G40 G1 X[#1 - 4] Y[6]\n", None),
    ("G41 D1 G1 X[#1 - 3.2] Y[7]\n" + CONTOUR + "G40 G1 X[#1 - 4] Y[6]\n", "kerf-entry"),  # entry shorter than the radius
    ("G41 D1 G1 X[#1] Y[10]\nG41 D1 G1 X[#1] Y[12]\n", "kerf-state"),  # G41 twice
    ("G41 D1 G1 X[#1] Y[10]\n" + CONTOUR, "kerf-state"),  # no G40: the next part's G41 is refused
])
def test_odd_stretches_of_the_general_path_give_the_per_move_result(case, code):
    text = "G21 G90 G17 F2400\n#1 = 0\nG0 X[#1 - 3] Y[7]\nM3\n" + case + "M5\n#1 = 60\nG0 X57 Y7\nG41 D1 G1 X60 Y10\n" \
        + CONTOUR + "G40 G1 X56 Y6\nG0 X0 Y0\nM2\n"
    slow, fast = _both(text)
    if code is not None:
        assert isinstance(slow, GCodeError) and slow.code == code, str(slow)
    else:
        assert not isinstance(slow, GCodeError), str(slow)
    _segments_equal(slow, fast)


def test_a_contour_still_compensated_at_the_program_end_ends_at_its_offset_end():
    text = "G21 G90 G17 F2400\n#1 = 0\nG0 X-3 Y7\nM3\nG41 D1 G1 X[#1] Y[10]\n" + CONTOUR + "M2\n"
    slow, fast = _both(text)
    assert not isinstance(slow, GCodeError), str(slow)
    _segments_equal(slow, fast)


def test_a_queue_offset_many_times_over_a_program_equals_one_offset(monkeypatch):
    """The queue is offset whenever it holds `QUEUE_MOVES` moves: at 50 that is every few parts."""
    text = cam_nest(40, subroutines=True)
    whole = Interpreter(NEST_DIALECT, "p.ngc").run(text)
    monkeypatch.setattr(kerf_batch, "QUEUE_MOVES", 50)
    _segments_equal(Interpreter(NEST_DIALECT, "p.ngc", fast=False).run(text), Interpreter(NEST_DIALECT, "p.ngc").run(text))
    _segments_equal(whole, Interpreter(NEST_DIALECT, "p.ngc").run(text))


def _drive(kerf) -> None:
    """Three parts straight into a compensator: rapid, jet on, G41 contour of lines and an arc,
    G40 and its exit, jet off; then the program's end."""
    from gcode.canon import ARC, LINE, RAPID, Event, Move

    here = (0.0, 0.0, 0.0)
    for k in range(3):
        x = 40.0 * k
        pts = [(x + 5, 5), (x + 25, 5), (x + 25, 15)]
        kerf.move(Move(RAPID, here, (x + 2, 2, 0.0), feed=float("nan"), line=10 * k + 1))
        kerf.event(Event("jet", 10 * k + 2, {"on": True}))
        kerf.start(1, 0.4, 10 * k + 3, 1)
        prev = (x + 2, 2, 0.0)
        for j, (px, py) in enumerate(pts):
            end = (px, py, 0.0)
            kerf.move(Move(LINE, prev, end, feed=2400.0, line=10 * k + 3 + j))
            prev = end
        end = (x + 15, 25, 0.0)
        kerf.move(Move(ARC, prev, end, (x + 15, 15), False, 0, 2400.0, 10 * k + 7))
        kerf.move(Move(LINE, end, (x + 5, 5, 0.0), feed=2400.0, line=10 * k + 8))
        kerf.stop(10 * k + 9, 1)
        here = (x + 1, 1, 0.0)
        kerf.move(Move(LINE, (x + 5, 5, 0.0), here, feed=2400.0, line=10 * k + 9))
        kerf.event(Event("jet", 10 * k + 10, {"on": False}))
    kerf.flush()


def test_a_sink_that_is_no_program_builder_gets_the_per_move_items():
    from gcode.canon import Move
    from gcode.kerf import KerfCompensator

    per_move, batched = [], []
    _drive(KerfCompensator(per_move.append))
    kerf = kerf_batch.BatchedKerfCompensator(batched.append)
    _drive(kerf)
    assert kerf.offset_in_bulk == 3 and kerf.replayed == 0
    assert len(per_move) == len(batched) > 20
    for a, b in zip(per_move, batched):
        assert type(a) is type(b)
        if isinstance(a, Move):
            assert (a.kind, a.line, a.cw, a.turns) == (b.kind, b.line, b.cw, b.turns)
            assert np.allclose(a.start, b.start, atol=1e-9) and np.allclose(a.end, b.end, atol=1e-9)
            assert (a.center is None) == (b.center is None)
            if a.center is not None:
                assert np.allclose(a.center, b.center, atol=1e-9)
        else:
            assert (a.kind, a.line, a.data) == (b.kind, b.line, b.data)


def test_a_jet_off_left_alone_at_the_end_of_a_batch_still_makes_the_next_cut_pierce():
    """A queued stretch the bulk rules send back (an entry arc) and the M5 after it are the last
    of a batch that the fast path's next run drains: the jet-off must reach the builder even with
    no segment beside it, or the fast path's first cut after it is not counted as a pierce."""
    part = ("G0 X[-3] Y[7]\nM3\nG4 P0.2\nG41 D1 G3 X[0] Y[10] I[3] J[0]\n" + CONTOUR.replace("#1", "0")
            + "G40 G1 X[-4] Y[6]\nM5 (MSG, part done)\n")
    plain = ["G0 X100 Y100", "M3", "G4 P0.2"] + [f"G1 X{100 + k} Y{100 + (k % 2)} F2400" for k in range(1, 80)] + ["M5"]
    text = "G21 G90 G17 F2400\n" + part + "\n".join(plain) + "\nG0 X0 Y0\nM2\n"
    counts = {}
    slow, fast = _both(text, counts)
    assert not isinstance(slow, GCodeError), str(slow)
    _segments_equal(slow, fast)
    assert slow.stats.pierces == fast.stats.pierces == 2 and counts["replayed"] == 1
