"""What an operator reads is a sentence: the status line's label of every command, and the alarm
texts, never a message's repr."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from cnc.bus.operator import OPERATOR_COMMANDS
from cnc.config import load_machine
from hmi.commands import describe
from tests.test_fuzz_commands import VALID

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

REPR = re.compile(r"[A-Z][a-z]+[A-Z]\w*|\w+=|\(\)")  # CamelCase class names, field=value, empty brackets


@pytest.mark.parametrize("msg", [m for m in VALID if type(m) in OPERATOR_COMMANDS.values()], ids=lambda m: type(m).__name__)
def test_every_operator_command_reads_as_words(msg):
    text = describe(msg)
    assert text[:1].isupper() and not REPR.search(text), text


def test_every_operator_command_kind_is_covered_here():
    assert set(OPERATOR_COMMANDS.values()) <= {type(m) for m in VALID}


def test_the_words_say_what_the_command_does():
    from cnc.bus.messages import (
        CalibrationLadder, CalibrationRecord, ControlRun, ControlSelect, DeleteProgram, GoTo, Hold, Jog, LockRequest, Mdi,
        Override, SetCut,
    )

    assert describe(LockRequest(take=True)) == "Take the command lock"
    assert describe(Hold(why="")) == "Feed hold"
    assert describe(Jog("y", -50.0, 2.0)) == "Jog Y- 2 mm at 50 mm/s"
    assert describe(GoTo({"x": 10.0, "y": 20.5}, 50.0)) == "Go to X10 Y20.5"
    assert describe(Override(80.0)) == "Feed override 80 %"
    assert describe(Mdi("G0 X10\nG1 X20 F600")) == "MDI: G0 X10 / G1 X20 F600"
    assert describe(ControlRun("circle", 10.0)) == "Control run: circle for 10 s"
    assert describe(ControlSelect("cross_coupled")) == "Select control program cross_coupled (from the next start)"
    assert describe(SetCut("leather", 2.5, 3)) == "Cutting job: leather 2.5 mm quality 3"
    assert describe(SetCut("leather", 2.5, 3, mode="feed")) == "Cutting job: leather 2.5 mm quality 3, feed as programmed"
    assert describe(SetCut()) == "Cutting job: the program's own"
    assert describe(CalibrationLadder("felt", 3.0, 600.0, 6000.0)) == "Speed ladder for felt 3 mm"
    assert describe(CalibrationRecord("felt", 3.0, 600.0, [600.0] * 5, 1.0, 0.2)) == "Record the calibration of felt 3 mm"
    assert describe(DeleteProgram("part.ngc")) == "Delete program part.ngc"


def test_the_door_alarm_reads_as_what_is_wrong():
    catalogue = {a.code: a.text for a in load_machine(Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml").alarm}
    assert catalogue[2292] == "Safety door open"
