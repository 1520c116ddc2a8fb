"""Interpretation is linear in the program, whatever its shape: a CAM nest of 2N parts costs at
most 2.3 times one of N parts, counted in work done (characters the fast path converts in bulk,
blocks the general path executes, O-word entries searched), not in wall time. The shapes: plain parts (one bulk run), a
comment per part, every third part in inches (two lines per such part need the general path),
every part an O-word subroutine call, and an O-word `if` per part with one label throughout."""

from __future__ import annotations

import pytest

from bench.nests import cam_nest
from gcode.dialect import Dialect
from gcode.interp import Interpreter

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

DIALECT = Dialect(axes="xyz", tool_diameters_mm={1: 0.8}, default_tolerance_mm=0.05)
N = 300


def _if_per_part(parts: int) -> str:
    """Every part behind `o1 if` (the same label all through the program), as some posts write a skip flag."""
    lines = cam_nest(parts).splitlines()
    out, part = [], 0
    for line in lines:
        if line.startswith("G0 X") and line != "G0 X0 Y0":
            part += 1
            out += [f"#<skip> = {part % 2}", "o1 if [#<skip> EQ 0]"]
        out.append(line)
        if line == "M5":
            out.append("o1 endif")
    return "\n".join(out) + "\n"


SHAPES = {
    "plain": lambda n: cam_nest(n),
    "comment per part": lambda n: cam_nest(n, comments=True),
    "inch every 3rd part": lambda n: cam_nest(n, inch_every=3),
    "subroutine per part": lambda n: cam_nest(n, subroutines=True),
    "if per part": _if_per_part,
}


def _work(text: str) -> tuple[int, int, int]:
    """(characters converted in bulk, general-path blocks plus O-word entries searched, moves)."""
    ip = Interpreter(DIALECT, "nest.ngc")
    program = ip.run(text)
    return ip.fast.converted, ip.blocks_run - ip.fast.taken + ip.oword_steps, len(program.segments)


@pytest.mark.parametrize("shape", list(SHAPES))
def test_a_nest_of_twice_the_parts_costs_at_most_2_3_times_the_work(shape):
    make = SHAPES[shape]
    small, large = make(N), make(2 * N)
    (conv1, general1, seg1), (conv2, general2, seg2) = _work(small), _work(large)
    assert seg2 >= 1.9 * seg1 > 0, "the larger nest has about twice the moves"
    assert conv2 <= 2.3 * max(conv1, 1) and general2 <= 2.3 * max(general1, 1), (conv1, conv2, general1, general2)
    assert conv2 <= 4 * len(large), "the fast path converts each character a bounded number of times"


@pytest.mark.parametrize("shape", ["plain", "subroutine per part", "if per part"])
def test_an_interpretation_leaves_nothing_for_the_cyclic_collector(shape):
    """The interpreter pauses the cyclic collector while it runs (`interp._collector_paused`):
    that is only sound if it makes no reference cycles, which the collector would find here."""
    import gc

    text = SHAPES[shape](60)
    gc.collect()
    gc.disable()
    try:
        program = Interpreter(DIALECT, "p.ngc").run(text)
        assert program.stats.pierces == (30 if shape == "if per part" else 60)
        del program
        try:
            Interpreter(DIALECT, "p.ngc").run(text.replace("M2", "G7.5\nM2"))
        except Exception as err:  # noqa: BLE001 - the error's own objects are the point
            assert "G7.5" in str(err)
        found = gc.collect()
    finally:
        gc.enable()
    assert found == 0


def test_the_collector_is_resumed_after_an_interpretation_as_it_was_before():
    import gc

    from gcode.errors import GCodeError

    assert gc.isenabled()
    Interpreter(DIALECT, "p.ngc").run(cam_nest(3))
    assert gc.isenabled()
    with pytest.raises(GCodeError):
        Interpreter(DIALECT, "p.ngc").run("G1 X1 F100\nG7.5\nM2\n")
    assert gc.isenabled()
    gc.disable()
    try:
        Interpreter(DIALECT, "p.ngc").run(cam_nest(3))
        assert not gc.isenabled(), "a collector that was off stays off"
    finally:
        gc.enable()
