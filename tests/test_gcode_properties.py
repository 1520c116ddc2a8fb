"""Robustness of the interpreter: any text gives a Program or a GCodeError, never a crash or a hang."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from gcode.canon import DWELL
from gcode.dialect import Dialect
from gcode.errors import GCodeError
from gcode.interp import interpret

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

DIALECT = Dialect(axes="xyz", tool_diameters_mm={1: 1.0, 2: 0.4}, max_blocks=20_000)
SETTINGS = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])  # max_blocks and pytest-timeout bound each example

SEED_PROGRAM = """%
(MSG, part 7)
G21 G90 G17 G64 P0.05
#<r> = 5
o<hole> sub
  G0 X[#1 - #<r>] Y#2
  M3
  G2 X[#1 - #<r>] Y#2 I#<r> J0 F900
  M5
o<hole> endsub
G0 X10 Y10
M3
G41.1 D1 G1 X20 Y10 F1200
G1 X20 Y40
G3 X10 Y50 R10
G1 X0 Y50
G40 G1 X-5 Y55
M5
o1 repeat [3]
  o<hole> call [#<_x> + 30] [20]
o1 endrepeat
G4 P0.5
M2
%
"""

_chars = st.sampled_from(list("GMXYZIJRFPNODTSLQKgmxyz0123456789.-+ []#<>_=()/;%\n\t*/ ") + ["sub", "call", "if", "while", "endwhile", "EQ", "SIN", "ATAN", "**", "MOD"])


def _interpret(text: str) -> None:
    try:
        program = interpret(text, DIALECT, file="fuzz.ngc")
    except GCodeError as err:
        assert err.line >= 0 and err.column >= 0 and err.message
        assert str(err).startswith("fuzz.ngc:")
        err.render()
        return
    assert program.segments.dtype.names[0] == "kind"


@SETTINGS
@given(st.text(max_size=300))
@example("O²")  # a character str.isdigit() accepts and int() refuses
@example("N²G1X1")
def test_arbitrary_text_gives_a_program_or_a_gcode_error(text):
    _interpret(text)


@SETTINGS
@given(st.lists(_chars, max_size=120).map("".join))
def test_gcode_like_noise_gives_a_program_or_a_gcode_error(text):
    _interpret(text)


@SETTINGS
@given(st.data())
def test_mutated_valid_programs_give_a_program_or_a_gcode_error(data):
    text = SEED_PROGRAM
    for _ in range(data.draw(st.integers(1, 4))):
        pos = data.draw(st.integers(0, len(text)))
        action = data.draw(st.sampled_from(("insert", "delete", "replace")))
        piece = data.draw(st.text(alphabet="GXYRIJ0123456789.-[]#<>=()\n ;o", min_size=1, max_size=6))
        if action == "insert":
            text = text[:pos] + piece + text[pos:]
        elif action == "delete":
            text = text[:pos] + text[pos + len(piece):]
        else:
            text = text[:pos] + piece + text[pos + len(piece):]
    _interpret(text)


@st.composite
def valid_programs(draw):
    """Programs that are valid by construction: lines, consistent arcs, R arcs that reach, dwells."""
    lines = ["G21 G90 F1000"]
    x = y = 0.0
    for _ in range(draw(st.integers(1, 40))):
        kind = draw(st.sampled_from(("g0", "g1", "arc", "rarc", "dwell", "inc")))
        nx = draw(st.floats(-500, 500, allow_nan=False).map(lambda v: round(v, 3)))
        ny = draw(st.floats(-500, 500, allow_nan=False).map(lambda v: round(v, 3)))
        if kind in ("g0", "g1"):
            lines.append(f"{kind.upper()} X{nx} Y{ny}")
            x, y = nx, ny
        elif kind == "inc":
            lines.append(f"G91 G1 X{nx / 10:.3f} Y{ny / 10:.3f}\nG90")
            x, y = x + round(nx / 10, 3), y + round(ny / 10, 3)
        elif kind == "arc":
            ang = draw(st.floats(0, 2 * math.pi))
            cx, cy = x + round(nx / 10, 3), y + round(ny / 10, 3)
            r = math.hypot(x - cx, y - cy)
            if r < 0.01:
                continue
            ex, ey = cx + r * math.cos(ang), cy + r * math.sin(ang)
            lines.append(f"G{draw(st.sampled_from((2, 3)))} X{ex:.6f} Y{ey:.6f} I{cx - x:.6f} J{cy - y:.6f}")
            x, y = float(f"{ex:.6f}"), float(f"{ey:.6f}")
        elif kind == "rarc":
            chord = math.hypot(nx - x, ny - y)
            if chord < 1e-3:
                continue
            r = chord / 2 * draw(st.floats(1.01, 5)) * draw(st.sampled_from((1, -1)))
            lines.append(f"G{draw(st.sampled_from((2, 3)))} X{nx} Y{ny} R{r:.6f}")
            x, y = nx, ny
        else:
            lines.append(f"G4 P{draw(st.floats(0, 2)):.3f}")
    lines.append("M2")
    return "\n".join(lines) + "\n"


@settings(max_examples=200, deadline=None)
@given(valid_programs())
def test_valid_generated_programs_interpret_to_chained_segments(text):
    program = interpret(text, DIALECT)
    seg = program.segments
    moves = seg[seg["kind"] != DWELL]
    assert np.isfinite(moves["start"]).all() and np.isfinite(moves["end"]).all()
    if len(moves) > 1:
        assert np.allclose(moves["start"][1:], moves["end"][:-1], atol=1e-9), "each start equals the previous end"
    if len(moves):
        assert np.allclose(moves["start"][0], 0.0)
