"""The G-code interpreter: dialect, output in machine mm, exact errors, control flow."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gcode.canon import ARC, DWELL, LINE, RAPID
from gcode.dialect import Dialect
from gcode.errors import GCodeError
from gcode.interp import interpret

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

XY = Dialect(axes="xy", tool_diameters_mm={1: 2.0, 2: 0.5})
XYZ = Dialect(axes="xyz")


def run(text: str, dialect: Dialect = XYZ):
    """Interpret; programs here end with M2 unless they test the ending themselves."""
    if isinstance(text, str) and "M2" not in text and "%" not in text:
        text += "M2\n"
    return interpret(text, dialect, file="part.ngc")


def ends(prog) -> list[tuple[float, ...]]:
    return [tuple(round(v, 6) for v in s["end"]) for s in prog.segments if s["kind"] != DWELL]


def error(text: str, dialect: Dialect = XYZ) -> GCodeError:
    with pytest.raises(GCodeError) as err:
        run(text, dialect)
    return err.value


# -- motion and modes ------------------------------------------------------------------------
def test_lines_rapids_and_feeds_come_out_in_machine_mm_and_mm_per_min():
    p = run("G21 G90 G0 X10 Y5\nG1 X20 F600\nG20 G1 X1 Y1 F10\nM2\n")
    seg = p.segments
    assert list(seg["kind"]) == [RAPID, LINE, LINE]
    assert ends(p) == [(10, 5, 0), (20, 5, 0), (25.4, 25.4, 0)]
    # F on the G20 line is read before the units change (LinuxCNC's order of execution, checked
    # against rs274 by the conformance program order_feed_before_units.ngc): 10 mm/min
    assert math.isnan(seg["feed"][0]) and seg["feed"][1] == 600 and seg["feed"][2] == pytest.approx(10.0)
    assert list(seg["start"][1]) == [10, 5, 0], "each start is the previous end"


def test_incremental_distance_mode_adds_to_the_current_point():
    assert ends(run("G91 G1 X1 Y2 F100\nX1\nY-5\nG90 X0\n")) == [(1, 2, 0), (2, 2, 0), (2, -3, 0), (0, -3, 0)]


def test_modal_motion_continues_on_lines_with_only_axis_words():
    p = run("G1 X1 F100\nX2\nG0 X3\nY1\n")
    assert list(p.segments["kind"]) == [LINE, LINE, RAPID, RAPID]


def test_arcs_with_centre_radius_full_circle_turns_and_helix():
    p = run(
        "G1 X10 Y0 F100\n"
        "G3 X0 Y10 I-10 J0\n"  # quarter circle CCW about the origin
        "G2 X10 Y0 R10\n"  # back CW, short arc
        "G2 X10 Y0 I-10 J0 P3\n"  # full circle plus two more turns
        "G3 X0 Y10 Z5 R-10\n"  # 270 degrees CCW, helix
    )
    arcs = p.segments[p.segments["kind"] == ARC]
    assert np.allclose(arcs["center"][:3], 0.0, atol=1e-12)
    assert list(arcs["cw"]) == [False, True, True, False]
    assert list(arcs["turns"]) == [0, 0, 2, 0]
    assert tuple(arcs[3]["center"]) == pytest.approx((10, 10)) and arcs[3]["end"][2] == 5


def test_absolute_arc_centres_with_g90_1_and_work_offsets():
    p = run("G10 L2 P1 X100 Y100\nG54 G1 X10 Y0 F100\nG90.1 G3 X0 Y10 I0 J0\n")
    assert tuple(p.segments[-1]["center"]) == (100, 100) and tuple(p.segments[-1]["end"]) == (100, 110, 0)


def test_work_offsets_g54_to_g59_3_g10_l2_l20_and_g53():
    p = run(
        "G10 L2 P2 X100 Y50\nG55 G0 X1 Y1\n"  # G55 origin at 100,50
        "G10 L20 P3 X0 Y0\nG56 G0 X5\n"  # G56: the current point (101,51) becomes 0,0
        "G53 G0 X7 Y8\n"  # machine coordinates, this line only
        "G0 X0 Y0\n"  # back in G56
        "G59.3 G0 X2\n"
    )
    assert ends(p) == [(101, 51, 0), (106, 51, 0), (7, 8, 0), (101, 51, 0), (2, 51, 0)]


def test_g92_offsets_set_cancel_suspend_and_restore():
    p = run("G0 X10 Y10\nG92 X0 Y0\nG0 X1\nG92.2\nG0 X1\nG92.3\nG0 X2\nG92.1\nG0 X3\n")
    assert ends(p) == [(10, 10, 0), (11, 10, 0), (1, 10, 0), (12, 10, 0), (3, 10, 0)]


def test_inverse_time_feed_becomes_mm_per_min_for_each_move():
    p = run("G93 G1 X30 Y40 F2\nG94 G1 X0 F300\n")
    assert p.segments["feed"][0] == pytest.approx(50.0 * 2.0) and p.segments["feed"][1] == 300


def test_g64_tolerance_and_exact_stop_travel_with_the_segments():
    p = run("G1 X1 F100\nG64 P0.2\nX2\nG61\nX3\nG64\nX4\n", Dialect(axes="xyz", default_tolerance_mm=0.05))
    assert list(p.segments["tolerance"]) == pytest.approx([0.05, 0.2, 0.0, 0.05])


def test_dwell_is_a_segment_with_its_seconds():
    p = run("G0 X1\nG4 P1.5\nG0 X2\n")
    assert list(p.segments["kind"]) == [RAPID, DWELL, RAPID] and p.segments["dwell"][1] == 1.5
    assert p.stats.dwell_s == 1.5


# -- jet, outputs, messages -------------------------------------------------------------------
def test_jet_state_travels_with_segments_and_pierces_are_counted():
    p = run("G0 X1\nM3\nG1 X2 F100\nX3\nM5\nG0 X10\nM3\nG1 X11\nM5\nM2\n")
    assert list(p.segments["jet"]) == [False, True, True, False, True]
    assert p.stats.pierces == 2 and p.stats.cut_length_mm == pytest.approx(3.0)
    assert p.stats.rapid_length_mm == pytest.approx(8.0)


def test_mcode_map_of_the_machine_decides_what_switches_the_jet():
    dialect = Dialect(axes="xy", mcodes={10: ("jet_on",), 11: ("jet_off",)})
    p = run("M10\nG1 X1 F100\nM11\nG1 X2\n", dialect)
    assert list(p.segments["jet"]) == [True, False]
    assert "M3 is not used on this machine" in str(error("M3\n", dialect))


def test_abrasive_and_synchronised_outputs_are_per_segment_and_immediate_outputs_are_messages():
    p = run("M7\nM62 P3\nG1 X1 F100\nM9 M63 P3\nG1 X2\nM64 P1\nG1 X3\n")
    assert list(p.segments["aux"]) == [1, 0, 0]
    assert list(p.segments["outputs"]) == [8, 0, 2]
    assert [(m.kind, m.segment, m.data["output"]) for m in p.messages if m.kind == "output"] == [("output", 2, 1)]


def test_operator_messages_and_stops_are_kept_with_their_place():
    p = run("G0 X1\n(MSG, Load the leather)\nM0\nG0 X2\nM1\nM2\nG0 X99\n")
    kinds = [(m.kind, m.segment, m.text.strip()) for m in p.messages]
    assert kinds == [("message", 1, "Load the leather"), ("stop", 1, "M0"), ("optional_stop", 2, "M1")]
    assert ends(p)[-1] == (2, 0, 0), "nothing after M2 runs"


# -- text handling -----------------------------------------------------------------------------
def test_comments_spaces_case_line_numbers_and_block_delete():
    p = run("n10 g 1 x 1 0 f 1 0 0 (comment) ; rest\n/G0 X99\nN20 G0 Y5 (a)(b)\n")
    assert ends(p) == [(10, 0, 0), (99, 0, 0), (99, 5, 0)], "block delete switch off: '/' lines run"
    skipped = interpret("G0 X1\n/G0 X99\nG0 X2\nM2\n", Dialect(axes="xyz", block_delete=True))
    assert ends(skipped) == [(1, 0, 0), (2, 0, 0)]


def test_tape_markers_crlf_and_latin1_text():
    p = interpret(b"%\r\n(Leder \xfcber)\r\nG0 X1\r\n%\r\nG0 X99\r\n", XYZ)  # after the closing % nothing runs
    assert ends(p) == [(1, 0, 0)]


def test_a_file_must_end_with_m2_m30_or_a_closing_percent_as_in_linuxcnc():
    err = error_raw("G0 X1\nG0 X2\n\n")
    assert (err.line, err.code) == (2, "program-end")
    assert ends(interpret("%\nG0 X1\n%\n", XYZ)) == [(1, 0, 0)]
    err = error_raw("G0 X1\n%\nM2\n")
    assert (err.line, err.code) == (2, "bad-character")


def error_raw(text: str) -> GCodeError:
    with pytest.raises(GCodeError) as err:
        interpret(text, XYZ, file="part.ngc")
    return err.value


def test_binary_files_are_refused_with_where():
    err = error(b"G0 X1\nG\x00 X2\n")
    assert err.code == "binary" and (err.line, err.column) == (2, 2)


# -- parameters and O-words ---------------------------------------------------------------------
def test_parameters_and_expressions_feed_the_words():
    p = run("#1 = 10\n#<side> = [#1 * 2]\nG1 X#1 Y[#<side> / 4 + SIN[90]] F100\n")
    assert ends(p) == [(10, 6, 0)]


def test_parameter_settings_take_effect_after_the_line_is_read():
    assert ends(run("#1=1\n#1=2 G0 X#1\nG0 X#1\n")) == [(1, 0, 0), (2, 0, 0)]


def test_subroutines_with_arguments_and_return_values():
    p = run(
        "o<square> sub\n"
        "  G1 X[#1] Y0 F100\n  G1 Y[#1]\n  G1 X0\n  G1 Y0\n"
        "o<square> endsub [#1 * 4]\n"
        "o<square> call [5]\n"
        "G0 X[#<_value>]\n"
    )
    assert ends(p) == [(5, 0, 0), (5, 5, 0), (0, 5, 0), (0, 0, 0), (20, 0, 0)]


def test_if_elseif_else_while_do_repeat_break_and_continue():
    p = run(
        "#1 = 2\n"
        "o1 if [#1 EQ 1]\nG0 X1\no1 elseif [#1 EQ 2]\nG0 X2\no1 else\nG0 X3\no1 endif\n"
        "#2 = 0\no2 while [#2 LT 3]\n#2 = [#2 + 1]\nG0 Y#2\no2 endwhile\n"
        "o3 do\nG0 Z1\no3 while [0]\n"
        "o4 repeat [3]\nG0 X[10 + #<_x>]\no4 endrepeat\n"
        "#3 = 0\no5 while [1]\n#3 = [#3 + 1]\no6 if [#3 EQ 2]\no5 continue\no6 endif\no7 if [#3 GT 3]\no5 break\no7 endif\nG0 Y[100 + #3]\no5 endwhile\n"
    )
    assert ends(p) == [
        (2, 0, 0), (2, 1, 0), (2, 2, 0), (2, 3, 0), (2, 3, 1),
        (12, 3, 1), (22, 3, 1), (32, 3, 1), (32, 101, 1), (32, 103, 1),
    ]


def test_an_endless_loop_is_stopped_with_an_error_not_a_hang():
    err = error("o1 while [1]\nG0 X1\no1 endwhile\nM2\n", Dialect(axes="xyz", max_blocks=10_000))
    assert err.code == "runaway" and "endless loop" in err.message


def test_an_endless_loop_is_stopped_by_the_interpretation_time_limit_too():
    err = error("o1 while [1]\nG0 X1\no1 endwhile\nM2\n", Dialect(axes="xyz", max_seconds=0.3))
    assert err.code == "runaway" and "after 0.3 s of interpretation" in err.message and err.line in (1, 2, 3)


# -- errors: where and what -----------------------------------------------------------------------
@pytest.mark.parametrize(
    "text, line, column, code, message",
    [
        ("G0 X1\nG0 G1 X2\n", 2, 4, "modal-group", "two G codes from the same modal group: G0 and G1"),
        ("G1 X1 X2 F100\n", 1, 7, "duplicate-word", "multiple X words on one line"),
        ("G1 X1\n", 1, 1, "feed", "G1 with zero feed rate"),
        ("G1 X10 F100\nG2 X0 Y0 I5 J1\n", 2, 4, "arc-radius", "radius to the end point"),
        ("G2 X10 Y0 R2\n", 1, 11, "arc-radius-too-small", "arc radius 2.0000 mm is too small"),
        ("G18\n", 1, 1, "unsupported", "G18 (XZ plane)"),
        ("G0 A5\n", 1, 4, "axis", "A word: the machine has no A axis"),
        ("G92\n", 1, 1, "words", "G92 needs at least one axis word"),
        ("G4\n", 1, 1, "words", "G4 needs a P word"),
        ("G0 X1 E5\n", 1, 7, "bad-character", "bad character 'e' used"),
        ("G0 X1 (open\n", 1, 7, "comment", "comment '(' is not closed"),
        ("G1 X[1/0] F100\n", 1, None, "division-by-zero", ""),
        ("G0 X#<nope>\n", 1, None, "parameter", "#<nope>"),
        ("M3 M5\n", 1, 4, "modal-group", "two M codes from the same modal group: M3 and M5"),
        ("G77\n", 1, 1, "unknown-code", "unknown G code G77"),
        ("o<x> call\n", 1, 1, "o-word", "no subroutine o<x>"),
        ("G2 X1 Y1 I1 R1 F10\n", 1, 13, "words", "both R and I/J"),
    ],
)
def test_errors_name_line_column_code_and_what(text, line, column, code, message):
    err = error(text)
    assert err.file == "part.ngc" and err.line == line and err.code == code, (str(err), err.code)
    if column is not None:
        assert err.column == column, str(err)
    assert message in err.message, err.message


def test_axis_words_the_machine_lacks_are_errors_naming_the_word():
    err = error("G0 X1 Z5\n", XY)
    assert (err.line, err.column) == (1, 7) and "Z word: the machine has no Z axis (axes: X, Y)" in err.message


def test_error_render_shows_the_source_line_and_a_caret():
    err = error("G0 X1\nG1 X2 X3 F1\n")
    assert err.render().splitlines() == [
        "part.ngc:2:7: error: multiple X words on one line",
        "     2 | G1 X2 X3 F1",
        "       |       ^",
    ]


def test_statistics_bounds_include_arc_extremes():
    p = run("G0 X10 Y0\nM3\nG3 X-10 Y0 I-10 J0 F100\nM5\n")
    assert p.stats.bounds_min[:2] == pytest.approx((-10, 0)) and p.stats.bounds_max[:2] == pytest.approx((10, 10))
    assert p.stats.cut_length_mm == pytest.approx(math.pi * 10) and p.stats.pierces == 1


def test_segments_chain_and_serialise_to_the_exchange_format(tmp_path):
    import io
    import json

    p = run("G0 X1 Y1\nG1 X5 F120\nG2 X5 Y5 R2\nG4 P0.25\nG0 X0 Y0\n")
    assert np.allclose(p.segments["start"][1:][p.segments["kind"][1:] != DWELL][0], p.segments["end"][0])
    buf = io.StringIO()
    p.write_segments_jsonl(buf)
    recs = [json.loads(line) for line in buf.getvalue().splitlines()]
    assert recs[0] == {"kind": "rapid", "start": [0.0, 0.0, 0.0], "end": [1.0, 1.0, 0.0], "feed": None, "line": 1}
    assert recs[2]["kind"] == "arc" and recs[2]["cw"] is True and recs[2]["turns"] == 0 and len(recs[2]["center"]) == 2
    assert recs[3] == {"kind": "dwell", "seconds": 0.25, "line": 4}


def test_a_named_parameter_exists_from_the_moment_its_setting_is_read():
    """LinuxCNC: `#<a>=1 #<b>=#<a>` on one line gives b the 0 that a held when the line was read."""
    p = run("#<a>=1 #<b>=#<a>\nG0 X#<b> Y#<a>\n")
    assert ends(p) == [(0, 1, 0)]
