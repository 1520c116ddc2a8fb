"""Pre-flight: refuse to start unhomed or beyond travel, naming the line and the axis."""

from __future__ import annotations

import pytest

from gcode.dialect import Dialect
from gcode.interp import interpret

from cnc.planner.preflight import PreflightError, preflight

from .conftest import machine_config

HOMED = {"x": True, "y": True}


def segments(text: str, axes: str = "xy"):
    return interpret(text + "M2\n", Dialect(axes=axes)).segments


def test_a_program_within_travel_on_a_homed_machine_may_start():
    preflight(segments("G0 X100 Y100\nG1 X1500 Y1100 F3000\nG2 X1500 Y900 R100\n"), machine_config(), HOMED)


def test_an_unhomed_machine_refuses_naming_the_axes():
    with pytest.raises(PreflightError, match="part.ngc cannot start: axis Y not homed") as err:
        preflight(segments("G0 X10 Y10\n"), machine_config(), {"x": True, "y": False}, "part.ngc")
    assert err.value.axis == "y"


def test_a_move_beyond_travel_is_refused_with_its_line_axis_and_value():
    with pytest.raises(PreflightError) as err:
        preflight(segments("G0 X10 Y10\nG1 X20 Y20 F100\nG1 X1650 Y20\n"), machine_config(), HOMED, "part.ngc")
    assert str(err.value) == "part.ngc:3: X reaches 1650.000 mm, outside the travel 0 to 1600 mm"
    assert (err.value.line, err.value.axis) == (3, "x")


def test_an_arc_bulging_beyond_travel_is_caught_though_its_ends_are_inside():
    preflight(segments("G0 X100 Y50\nG2 X300 Y50 R100 F600\n"), machine_config(), HOMED, "p")  # bulges up to Y150
    with pytest.raises(PreflightError, match=r"p:2: Y reaches -50\.000 mm") as err:
        preflight(segments("G0 X100 Y50\nG3 X300 Y50 R100 F600\n"), machine_config(), HOMED, "p")  # down to Y-50
    assert (err.value.line, err.value.axis) == (2, "y")


def test_a_program_below_zero_after_a_work_offset_is_refused():
    with pytest.raises(PreflightError, match=r"p:2: X reaches -5\.000 mm, outside the travel 0 to 1600 mm"):
        preflight(segments("G10 L2 P1 X-10 Y0\nG0 X5 Y5\n"), machine_config(), HOMED, "p")
