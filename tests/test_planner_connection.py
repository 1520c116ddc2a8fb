"""Corners passed by a connection: both axes planned in time through the corner (`cnc/planner/connection.py`).

Each test runs a program through the real interpreter and the planner's runner and measures the
setpoint records the servo would get: every axis within its limits, every record within G64 P of
the program, the planned cycle time the one run, and the operator's controls in a connection
acting when it ends, the head then at rest on the path within its braking distance.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from gcode.interp import interpret

from cnc.config import ConfigError
from cnc.machine_dialect import dialect_for
from cnc.planner.runner import ProgramRunner, RunState

from .conftest import machine_config
from .test_planner_motion import DT, LIMITS, run, speed, within_limits, within_tolerance
from .test_planner_overlap import CONTROLS, control_after_committed

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

# a slot of the comparison nest (`bench/linuxcnc_compare.py`) and the next part's lead-in: its lead-out
# turns back 135 degrees into the rapid to the next part, where two motions added are held by the jerk
# both put on X; the rapid meets the lead-in at a right angle
SLOT = """G21 G90 G17 G64 P0.05
G0 X20 Y17
G1 X20 Y20 F2400
G1 X53.957 Y20
G3 X53.957 Y26.339 I0 J3.170
G1 X20 Y26.339
G3 X20 Y20 I0 J-3.170
G1 X18 Y18
G0 X75 Y17
G1 X75 Y20 F2400
G1 X80 Y20
M2
"""
TURN_BACK = (18.0, 18.0)  # the lead-out's end, where the rapid starts
NO_CONNECTION = {"planner.corner_connection_ms": 0.0}


@functools.lru_cache(maxsize=None)
def _slot_run(connection: bool, chunk: int = 1):  # noqa: ANN202 - (program, runner, records, planned)
    """The slot run to its end, a record at a time (made once: several tests compare with it)."""
    program, runner, records, planned = run(SLOT, machine_config(**({} if connection else NO_CONNECTION)), chunk=chunk)
    records.flags.writeable = False
    return program, runner, records, planned


def _turn_back_speed(records) -> float:
    """The head's lowest speed within 0.5 mm of the lead-out's end."""
    near = np.hypot(*(records["position"][:, :2] - np.asarray(TURN_BACK)).T) < 0.5
    return float(speed(records)[near].min())


def test_a_lead_out_turned_back_into_a_rapid_is_connected_sooner_than_overlapped_within_every_limit_and_p():
    """Where the overlap's two motions are held by the jerk they add, the connection leaves the
    lead-out while it brakes and joins the rapid as it speeds up: the part runs sooner and passes the
    turn faster, every axis within its limits, every record within P, the planned time the one run."""
    program, _, records, planned = _slot_run(True)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned, "the planned cycle time counts the connection"
    assert records["position"][-1] == pytest.approx([80.0, 20.0], abs=1e-9)
    _, _, overlapped, planned_overlapped = _slot_run(False)
    assert len(overlapped) == planned_overlapped
    assert len(overlapped) - len(records) >= 8, "sooner by several periods"
    assert _turn_back_speed(records) > _turn_back_speed(overlapped), "faster through the turn"


def test_a_connection_is_the_same_whatever_the_take_size_and_only_where_nothing_switches():
    """The records do not depend on how many the servo's feeder takes at a time; with the jet
    switched off at the lead-out's end (a waterjet's part) the corner is a stop, as for an overlap."""
    _, _, one, _ = _slot_run(True)
    _, _, many, _ = run(SLOT, machine_config(), chunk=97)
    assert len(one) == len(many)
    assert np.abs(one["position"] - many["position"]).max() <= 1e-12
    switching = SLOT.replace("G1 X20 Y20 F2400", "M3\nG1 X20 Y20 F2400").replace("G0 X75 Y17", "M5\nG0 X75 Y17")
    _, _, records, _ = run(switching, machine_config(), chunk=50)
    assert _turn_back_speed(records) == 0.0, "at rest where the jet closes"


@pytest.mark.parametrize("into", [2, 20])
@pytest.mark.parametrize("control", list(CONTROLS))
def test_a_control_in_a_connection_acts_when_it_ends_and_every_limit_holds(control, into):
    """A connection's samples are committed: they come out as in a run without the control, then the
    next section's motion obeys it: a hold, a stop or 0 % bring the head to rest on the rapid's line
    within the braking distance of its speed from the connection's end on; 10 % and 200 % go on to
    the program's end. The ETA counts the connection's samples left."""
    program, _, undisturbed, _ = _slot_run(True)
    config = machine_config()
    runner = ProgramRunner(interpret(SLOT, dialect_for(config)), config)
    made = []
    while not runner.connecting:
        made.append(runner.take(1)[0])
    made.append(runner.take(into)[0])
    given, left = sum(len(m) for m in made), runner.overlap_left
    assert left > 0 and runner.connecting
    # the ETA to the record (the newest sample made waits for the next one, as everywhere)
    assert runner.remaining_s() == pytest.approx((len(undisturbed) - given - 1) * DT, abs=1e-9)
    records, shared = control_after_committed(runner, control, made, program, undisturbed, given + left)
    v = speed(records)
    if control in ("hold", "stop", "override 0"):
        assert v[-1] == 0.0
        assert runner.state == {"hold": RunState.HELD, "stop": RunState.ABORTED, "override 0": RunState.RUNNING}[control]
        end = records["position"][-1]
        assert 18.0 < end[0] < 75.0 and abs(end[1] - (18.0 + (end[0] - 18.0) / 57.0 * -1.0)) <= 0.05 + 1e-9, "on the rapid"
        travelled = float(np.hypot(*np.diff(records["position"][shared:], axis=0).T).sum())
        peak, a, j = float(v[shared:].max()), LIMITS["acceleration"], LIMITS["jerk"]
        # the rapid is speeding up: a hold lets the acceleration run out first, then brakes
        assert travelled <= peak * (a / j + 5 * DT) + peak * peak / (2.0 * a) + peak * a / (2.0 * j)
    else:
        assert runner.state == RunState.DONE and records["position"][-1] == pytest.approx([80.0, 20.0], abs=1e-9)


def test_the_connection_is_a_machine_file_key_validated_by_name():
    with pytest.raises(ConfigError, match=r"corner_connection_ms"):
        machine_config(**{"planner.corner_connection_ms": -1.0})
    with pytest.raises(ConfigError, match=r"corner_connection_ms"):
        machine_config(**{"planner.corner_connection_ms": "soon"})
    assert machine_config().planner.corner_connection_ms == 60.0
    _, _, records, planned = run(SLOT, machine_config(**NO_CONNECTION), chunk=50)
    assert _turn_back_speed(records) < 20.0 and len(records) == planned, "0: the overlap, as before"


def test_a_connection_is_searched_only_where_the_limits_or_the_cap_hold_the_overlap(monkeypatch):
    """The search costs milliseconds a corner: it is made where the axis limits hold the overlap
    short (the slot's turn back) or its cap does, not where P does (a right angle between two
    cuts, the corners of a waterjet part): those corners are overlapped as before."""
    from cnc.planner import overlap

    searched = []
    search = overlap.connection_plan
    monkeypatch.setattr(overlap, "connection_plan", lambda *args: searched.append(args[1].section.end) or search(*args))
    square = "G21 G90 G64 P0.05\nG1 X20 Y20 F2400\nG1 X60\nG1 Y60\nG1 X20\nG1 Y20\nM2\n"
    _, _, records, planned = run(square, machine_config(), chunk=50)
    _, _, overlapped, _ = run(square, machine_config(**NO_CONNECTION), chunk=50)
    assert searched == [] and len(records) == planned == len(overlapped)
    run(SLOT, machine_config(), chunk=50)
    assert TURN_BACK in [tuple(float(c) for c in corner[:2]) for corner in searched]


def test_an_override_raised_over_100_percent_just_before_a_connection_acts_from_the_next_section():
    """A first raise over 100 % takes effect in steps (`SectionStream.set_override`), the next one
    some 30 samples later. Raised just before a connection begins, that step fell among the samples
    the connection replaces: it replanned them, fewer came than the connection was planned for, and
    the runner failed (an index out of range). Now the connection's samples are taken as planned
    and the raise acts from the next section on, which starts with it: raised 5 to 45 samples
    before each connection of a CAM part's lead-in and contour (a random part, seed 267 of
    `_random_cam_parts`), the program runs to its end, every axis within its limits, every record
    within P."""
    from cnc.planner import runner as runner_module

    from .test_planner_overlap import _random_cam_parts

    text, _ = _random_cam_parts(267)
    begins = []  # records made when each connection began
    made = [0]

    class Counting(runner_module.ProgramRunner):
        def take(self, n: int):
            out = super().take(n)
            made[0] += len(out[0])
            return out

        def _start_corner(self, plan):
            if plan.is_connection:
                begins.append(made[0])
            return super()._start_corner(plan)

    config = machine_config()
    program = interpret(text, dialect_for(config))
    plain = Counting(program, config)
    while not plain.finished:
        plain.take(7)
    assert len(begins) >= 2
    for begin in begins[:2]:
        for before in (5, 15, 45):
            program, _, records, _ = run(text, actions={begin - before: lambda r: r.set_override(1.5)}, chunk=5)
            assert records["position"][-1] == pytest.approx(program.segments["end"][-1][:2], abs=1e-9)
            within_limits(records)
            assert (within_tolerance(program, records) <= 1e-9).all()


def test_a_connection_next_to_a_blended_corner_keeps_p_of_the_lines_as_programmed():
    """A connection's samples were kept within P of the elements near its corner, a blend among
    them: but a blend lies up to P / 2 off the corner it rounds, so a sample near it could be 1.5 P
    from the lines as programmed (0.211 mm at P 0.2: a random CAM part, seed 135 of
    `_random_cam_parts`, whose contour's first corner after the lead-in is blended). Near a blend
    the check now counts that too (`path.distance_to_programmed`): every record within P."""
    from .test_planner_overlap import _random_cam_parts

    text, chunk = _random_cam_parts(135)
    program, _, records, planned = run(text, chunk=chunk)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
