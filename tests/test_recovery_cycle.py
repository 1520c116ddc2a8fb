"""Cut recovery in the whole controller (the PLC simulator over a real pty, the virtual clock): a cut
interrupted by a door fault continues, after the reset, from where the jet stopped, backed up by
the overlap, with the material in place (no transport); the job record keeps where the jet was;
a part and a line can be started too; what cannot be continued is refused with the reason."""

from __future__ import annotations

import math
import os
import re
import signal

import numpy as np
import pytest

from cnc.bus.messages import CycleStart, JetTest, LoadProgram, Pump, Recover, Reset, SetMode, Stop
from cnc.data.layout import PlannerState, RunResult, ServoState
from cnc.gateway.jobs import CutPoints, jobs_path
from cnc.logic.states import CyclePhase, MachineState
from cnc.runtime.supervisor import Supervisor
from gcode.canon import ARC, LINE

from .conftest import logic, press_button_when_asked
from .test_logic_process import command, jet_open, ready_in_auto, refusal
from .test_mdi import run_mdi

# one long straight cut along X at Y100 (100 mm/s), then a second part: the door opens on the first
LONG = """(two parts)
G21 G90 G64 P0.05 F6000
G0 X100 Y100
M3
G1 X300
M5
G0 X100 Y150
M3
G1 X140
G1 Y190
G1 X100
G1 Y150
M5
G0 X60 Y60
M2
"""


def head_xy(sup: Supervisor) -> tuple[float, float]:
    x, y = sup.servo()["commanded_mm"][:2]
    return float(x), float(y)


def step_until(sup: Supervisor, condition, limit: int, what: str) -> int:
    """Advance the paused virtual clock a tick at a time until `condition()`; the tick it held at."""
    for _ in range(limit):
        tick = sup.run_ticks(1)
        if condition():
            return tick
    raise AssertionError(f"{what}: not within {limit} ticks")


def continue_and_pierce(sup: Supervisor, answer: str) -> tuple[float, float]:
    """Continue the interrupted cut (the reply saying `answer`); where the head is when the jet opens."""
    assert answer in command(sup, Recover("continue"))
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 30.0, "the pump, then the cut (no transport)")
    sup.pause_virtual_clock()
    step_until(sup, lambda: jet_open(sup), 20000, "the jet to open again")
    at = head_xy(sup)
    sup.resume_virtual_clock()
    return at


def test_a_cut_stopped_by_a_door_or_the_e_stop_continues_an_overlap_back_from_where_the_jet_stopped(plc_controller,
                                                                                                  tmp_path):
    sup = plc_controller
    ready_in_auto(sup, tmp_path, LONG)
    assert "no interrupted cut of nest.ngc is known" in refusal(sup, Recover("continue"))
    for fault, cleared in (({"doors_open": 1}, {"doors_open": 0}), ({"estop_pressed": 1}, {"estop_pressed": 0})):
        command(sup, CycleStart(cycles=1))
        press_button_when_asked(sup, lambda: jet_open(sup) and 150.0 < head_xy(sup)[0] < 250.0, 60.0, "the first cut under way")
        sup.pause_virtual_clock()
        sup.set_sim(**fault)
        last_cut = [head_xy(sup)]  # the setpoint of the last tick with the jet open
        step_until(sup, lambda: not jet_open(sup) or last_cut.append(head_xy(sup)), 50, "the jet to close at the fault")
        stopped_at = last_cut[-1]
        sup.resume_virtual_clock()
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT and logic(sup)["state"] in (
            MachineState.FAULT, MachineState.ESTOP), 30.0, "the fault")
        # written every few mm while it cut, and once more where the jet closed: wait for that one
        sup.wait_until(lambda: _stored_x(sup) >= stopped_at[0] - 0.2, 10.0, "where the jet closed, in the job record")
        stored = _stored(sup)
        assert stored.program == "nest.ngc" and stored.line == 5
        # where the jet last cut, to the tick (the board's read-back of the valve lags the servo by one: 0.1 mm here)
        assert stored.y_mm == pytest.approx(100.0) and -1e-6 <= stopped_at[0] - stored.x_mm <= 0.1 + 1e-6, (stored, stopped_at)
        # and roughly how far into its segment (from X100), from the planner's progress: an arc's turn
        assert abs(stored.segment_mm - (stored.x_mm - 100.0)) <= 2.0, stored

        sup.set_sim(**cleared)
        sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 20.0, "every alarm to reset")
        sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.STOPPED), 20.0, "ready after reset")
        assert "overlap_mm 500 is out of range" in refusal(sup, Recover("continue", overlap_mm=500.0))
        resumed_at = continue_and_pierce(sup, "nest.ngc: continue the cut of line 5, 2 mm back")
        overlap = sup.config.cycle.recovery_overlap_mm
        assert abs(resumed_at[1] - 100.0) < 1e-6 and abs(resumed_at[0] - (stored.x_mm - overlap)) < 1e-6, resumed_at
        sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.UNLOAD or logic(sup)["phase"] == CyclePhase.NONE, 120.0,
                       "the rest of the program")
        sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY, 60.0,
                       "the unload")
        m = sup.motion()
        assert m["run_result"] == RunResult.DONE and m["state"] == PlannerState.IDLE
        sup.wait_until(lambda: _stored(sup) is None, 10.0, "the cut point cleared once the program ran to its end")
        assert "no interrupted cut" in refusal(sup, Recover("continue"))


# LONG written in G91: where it cuts depends on where the head stood when the run started
RELATIVE = """(two parts, incremental)
G21 G91 G64 P0.05 F6000
G0 X70 Y70
M3
G1 X200
M5
G0 X-200 Y50
M3
G1 X40
G1 Y40
G1 X-40
G1 Y-40
M5
G0 X-40 Y-90
M2
"""


def test_an_incremental_program_continues_where_its_run_cut_not_shifted_to_where_the_head_stopped(plc_controller,
                                                                                                   tmp_path):
    """A G91 program moves with the start of its run. Continuing it after a door fault is a start
    with the head elsewhere (where it stopped); the restart takes the program as that run cut it,
    and pierces on the cut an overlap back from where the jet stopped (the start used to shift it
    by where the head stood, and so the continued cut, off the part, by the same)."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path, RELATIVE)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: jet_open(sup) and sup.motion()["line"] == 5 and head_xy(sup)[0] > 0.0
                            and sup.motion()["segment_mm"] > 80.0, 60.0, "the first cut under way")
    sup.set_sim(doors_open=1)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.FAULT and not sup.motion()["state"], 30.0, "the fault")
    sup.wait_until(lambda: _stored(sup) is not None and _stored(sup).segment_mm > 80.0, 10.0, "the cut point stored")
    stored = _stored(sup)
    assert stored.line == 5, stored
    sup.set_sim(doors_open=0)
    sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 20.0, "every alarm to reset")
    sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.STOPPED), 20.0, "ready after reset")
    resumed_at = continue_and_pierce(sup, "nest.ngc: continue the cut of line 5, 2 mm back")
    overlap = sup.config.cycle.recovery_overlap_mm
    assert resumed_at == pytest.approx((stored.x_mm - overlap, stored.y_mm), abs=1e-6), (resumed_at, stored)
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY, 120.0,
                   "the rest of the program and the unload")
    assert sup.motion()["run_result"] == RunResult.DONE


# the second part pierces with a dwell, as CAM posts write it (M3, G4): the door opens while it pierces
PIERCED = LONG.replace("G0 X100 Y150\nM3\n", "G0 X100 Y150\nM3\nG4 P0.5\n")


def test_a_cut_stopped_while_piercing_continues_by_piercing_there_again(plc_controller, tmp_path):
    """A door opened while the second part pierces (the jet open, the head standing in its G4
    dwell): the job record keeps that dwell as where the jet last was, and "continue" pierces
    there again and cuts the whole part, where it used to refuse ("the jet was not cutting there")."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path, PIERCED)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: jet_open(sup) and 150.0 < head_xy(sup)[0] < 250.0, 60.0, "the first cut under way")
    sup.pause_virtual_clock()  # the door opens in the tick asked for, however late the host looks
    step_until(sup, lambda: jet_open(sup) and head_xy(sup) == pytest.approx((100.0, 150.0)), 20000,
               "the second part's pierce")
    sup.run_ticks(100)  # into the pierce
    assert jet_open(sup) and head_xy(sup) == pytest.approx((100.0, 150.0))
    sup.set_sim(doors_open=1)
    step_until(sup, lambda: not jet_open(sup), 50, "the jet to close at the fault")
    sup.resume_virtual_clock()
    _, at = _door_closed_reset_and_continued(sup, 9, "nest.ngc: pierce again at line 9")
    assert at == pytest.approx((100.0, 150.0)), "pierced again where it was piercing"
    _ends_done(sup, "the part cut whole, and the unload")


def _door_closed_reset_and_continued(sup: Supervisor, line: int, answer: str):
    """After a door opened mid-program: the fault, the cut point of `line` in the job record, the door
    closed, the reset, "continue" answering `answer`; that cut point, and where the jet opens again."""
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT and logic(sup)["state"] == MachineState.FAULT, 30.0,
                   "the fault")
    sup.wait_until(lambda: (p := _stored(sup)) is not None and p.line == line, 10.0, "the cut point, in the job record")
    stored = _stored(sup)
    sup.set_sim(doors_open=0)
    sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 20.0, "every alarm to reset")
    sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.STOPPED), 20.0, "ready after reset")
    return stored, continue_and_pierce(sup, answer)


def _ends_done(sup: Supervisor, what: str) -> None:
    """The rest of the program and the unload: the run DONE, the machine READY."""
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY, 120.0, what)
    assert sup.motion()["run_result"] == RunResult.DONE


# three turns of R20 around (220, 100): every point of the circle is cut three times
TURNS = """(an arc of three turns)
G21 G90 G64 P0.05 F6000
G0 X200 Y100
M3
G2 X200 Y100 I20 J0 P3
M5
G0 X60 Y60
M2
"""


def test_an_arc_of_several_turns_stopped_beyond_its_first_turn_continues_in_the_turn_it_stopped_on(plc_controller,
                                                                                                  tmp_path):
    """The job record keeps roughly how far into the segment the jet stopped, so "continue" backs
    up in the turn it stopped on, not in the first one that passes the same point."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path, TURNS)
    turn = 2.0 * math.pi * 20.0
    command(sup, CycleStart(cycles=1))
    arc = 1  # the program's segments: the rapid there, the arc, the rapid away
    press_button_when_asked(sup, lambda: jet_open(sup) and sup.motion()["segment"] == arc, 60.0, "the arc under way")
    sup.pause_virtual_clock()  # the door opens in the tick asked for, however late the host looks
    step_until(sup, lambda: sup.motion()["segment_mm"] > 1.3 * turn, 20000, "the second turn")
    sup.set_sim(doors_open=1)
    sup.resume_virtual_clock()
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT and logic(sup)["state"] == MachineState.FAULT, 30.0,
                   "the fault")
    # written every few mm while it cut, and once more where the jet closed (off the scan): wait for that one
    # (a few mm behind the progress the door was opened at: the planner's progress is a period ahead)
    sup.wait_until(lambda: (p := _stored(sup)) is not None and p.segment_mm > 1.2 * turn, 10.0,
                   "where the jet closed in the second turn, in the job record")
    stored = _stored(sup)
    assert stored.line == 5 and 1.2 * turn < stored.segment_mm < 3.0 * turn, stored
    sup.set_sim(doors_open=0)
    sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 20.0, "every alarm to reset")
    sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.STOPPED), 20.0, "ready after reset")
    at = continue_and_pierce(sup, "nest.ngc: continue the cut of line 5, 2 mm back")
    assert math.hypot(at[0] - 220.0, at[1] - 100.0) == pytest.approx(20.0, abs=0.01)
    overlap = sup.config.cycle.recovery_overlap_mm
    into = sup.motion()["segment_mm"]  # where the continued run is in the arc: the second turn, 2 mm back
    assert abs(into - (stored.segment_mm - overlap)) < 3.0, (into, stored)
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY, 120.0,
                   "the rest of the arc and the unload")
    assert sup.motion()["run_result"] == RunResult.DONE


def test_a_part_or_a_line_starts_the_cycle_there_and_impossible_starts_are_refused(plc_controller, tmp_path):
    sup = plc_controller
    ready_in_auto(sup, tmp_path, LONG)
    command(sup, CycleStart(cycles=1))  # the material fed and gripped, then the operator stops the cut
    press_button_when_asked(sup, lambda: jet_open(sup), 60.0, "the first cut under way")
    command(sup, Stop())
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.STOPPED, 30.0,
                   "the stopped cycle")
    assert "has 2 parts (pierces): there is no part 3" in refusal(sup, Recover("part", 3)), "refused before the pump ramps"
    assert "nothing moves at or after line 999" in refusal(sup, Recover("line", 999))
    assert logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.STOPPED, "no cycle, no fault"
    assert "must be the part (from 1) or the line" in refusal(sup, Recover("part", 0))
    assert "kind 'resume' is not one of" in refusal(sup, Recover("resume"))
    command(sup, Recover("part", 2))
    sup.wait_until(lambda: jet_open(sup), 60.0, "part 2 cutting")
    x, y = head_xy(sup)
    assert math.isclose(y, 150.0) and 100.0 <= x <= 140.0, "the second part, not the first"
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY, 120.0,
                   "part 2 to its end and the unload")
    assert sup.motion()["run_result"] == RunResult.DONE


def _stored_x(sup: Supervisor) -> float:
    """X of the cut point the job record holds for the loaded program (-inf when none)."""
    stored = _stored(sup)
    return stored.x_mm if stored is not None else -math.inf


def _stored(sup: Supervisor):
    points = CutPoints(jobs_path(sup.history_path), readonly=True)
    try:
        return points.get(sup.motion()["program_hash"])
    finally:
        points.close()


def test_a_cut_stopped_by_the_logics_death_continues_an_overlap_back_from_where_the_jet_stopped(plc_controller, tmp_path):
    """The control logic killed mid-cut: the servo cuts on until the logic's silence trips it, ticks
    the dead logic never saw, so its job record keeps a point up to `recovery_save_mm` short. The
    restarted logic takes the exact last cut point from the servo's block (within the run's
    ticks), and "continue" backs up only the overlap from where the jet last cut."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path, LONG)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: jet_open(sup) and 150.0 < head_xy(sup)[0] < 200.0, 60.0, "the first cut under way")
    sup.pause_virtual_clock()
    # killed a millimetre or more past the point last written (every recovery_save_mm of cut)
    step_until(sup, lambda: head_xy(sup)[0] - _stored_x(sup) >= 1.0, 2000, "a millimetre past the point written")
    os.kill(sup.children["logic"].process.pid, signal.SIGKILL)
    written = _stored_x(sup)
    last_cut = [head_xy(sup)]
    step_until(sup, lambda: not jet_open(sup) or last_cut.append(head_xy(sup)), 20000, "the jet to close at the logic's silence")
    sup.resume_virtual_clock()
    assert last_cut[-1][0] - written >= 1.0
    sup.wait_until(lambda: logic(sup)["state"] in (MachineState.FAULT, MachineState.IDLE) and not sup.motion()["state"],
                   60.0, "the logic back, the planner at rest")
    sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 20.0, "every alarm to reset")
    sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.STOPPED), 20.0, "ready after reset")
    command(sup, SetMode("AUTO"))  # a restarted logic starts in MANUAL
    assert logic(sup)["cut_point_line"] == 5
    resumed_at = continue_and_pierce(sup, "nest.ngc: continue the cut of line 5, 2 mm back")
    overlap = sup.config.cycle.recovery_overlap_mm
    # the board's read-back of the valve lags the servo by a tick: its last jet-on setpoint is one before
    assert abs(resumed_at[1] - 100.0) < 1e-6 and 0.0 <= last_cut[-1][0] - overlap - resumed_at[0] <= 0.1 + 1e-6, (
        resumed_at, last_cut[-1])
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY, 120.0,
                   "the rest of the program and the unload")
    assert sup.motion()["run_result"] == RunResult.DONE


def test_a_restarted_logic_does_not_take_a_jet_test_after_the_run_for_the_programs_cut(plc_controller, tmp_path):
    """The servo notes every tick the jet is open, a jet test's too: a logic restarted after one
    keeps the program's interrupted cut (the job record's), not where the jet was tested."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path, LONG)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: jet_open(sup) and 150.0 < head_xy(sup)[0] < 250.0, 60.0, "the first cut under way")
    command(sup, Stop())
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and not sup.motion()["state"], 30.0, "stopped")
    sup.wait_until(lambda: _stored(sup) is not None and not jet_open(sup), 10.0, "where the jet closed, in the job record")
    stored = _stored(sup)
    command(sup, SetMode("MANUAL"))
    sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 20.0, "the stop reset")
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 20.0, "ready in MANUAL")
    run_mdi(sup, "G0 X250 Y250")
    command(sup, Pump(True, pressure_bar=2000.0))
    sup.wait_until(lambda: sup.logic.request(JetTest(True)).ok, 30.0, "the jet test at pressure")
    sup.wait_until(lambda: jet_open(sup), 5.0, "the jet to open")
    command(sup, JetTest(False))
    sup.wait_until(lambda: not jet_open(sup), 5.0, "the jet to close")
    assert sup.servo()["jet_on_mm"][1] == pytest.approx(250.0)
    killed = sup.children["logic"].process.pid
    os.kill(killed, signal.SIGKILL)
    sup.wait_until(lambda: (child := sup.children.get("logic")) is not None and child.process.pid != killed
                   and sup.logic.request(SetMode("MANUAL")).ok, 30.0, "the logic back, scanning")
    sup.wait_until(lambda: logic(sup)["cut_point_line"] == 5, 10.0, "the program's cut point shown")
    assert tuple(logic(sup)["cut_point_mm"]) == pytest.approx((stored.x_mm, stored.y_mm))
    assert _stored(sup) == stored


def test_after_a_power_loss_the_job_record_continues_the_cut_once_the_program_is_loaded_again(tmp_path):
    """Every process killed mid-cut (a power loss): a new controller, the same program loaded
    again, the material in place, continues from the cut point the job record kept (at most
    `recovery_save_mm` behind where the jet was, plus the overlap)."""
    from .conftest import NEAR_HOME, full_controller, machine_config

    config = machine_config(**NEAR_HOME)
    history = tmp_path / "history.sqlite"
    with full_controller(config, history) as sup:
        ready_in_auto(sup, tmp_path, LONG)
        command(sup, CycleStart(cycles=1))
        press_button_when_asked(sup, lambda: jet_open(sup) and 150.0 < head_xy(sup)[0] < 250.0, 60.0, "the cut under way")
        sup.pause_virtual_clock()
        cut_to = head_xy(sup)
        program_hash = sup.motion()["program_hash"]
        for child in sup.children.values():  # the power goes: nothing is written any more
            os.kill(child.process.pid, signal.SIGKILL)
    points = CutPoints(jobs_path(history), readonly=True)
    stored = points.get(program_hash)
    points.close()
    assert stored is not None and stored.line == 5, "written while it cut"
    # written every recovery_save_mm while it cut; the logic scans in wall time while the virtual clock
    # runs ahead of it on a busy host: a few mm more, never ahead of the head
    assert 0.0 <= cut_to[0] - stored.x_mm <= config.cycle.recovery_save_mm + 5.0, (stored, cut_to)

    with full_controller(config, history) as sup:
        ready_in_auto(sup, tmp_path, LONG)  # the operator loads the same program again
        assert "no material in place" in refusal(sup, Recover("continue")), "the new PLC has no material yet"
        command(sup, CycleStart(cycles=1))  # feed and grip the material, then stop before the cut
        press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.PRESSURE, 60.0, "the material in place")
        command(sup, Stop())
        sup.wait_until(lambda: logic(sup)["state"] == MachineState.STOPPED and not jet_open(sup), 30.0, "stopped")
        resumed_at = continue_and_pierce(sup, "nest.ngc: continue the cut of line 5")
        assert abs(resumed_at[1] - 100.0) < 1e-6
        assert abs(resumed_at[0] - (stored.x_mm - config.cycle.recovery_overlap_mm)) < 1e-6, (resumed_at, stored)
        sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY,
                       180.0, "the rest of the program and the unload")
        assert sup.motion()["run_result"] == RunResult.DONE


def test_after_a_power_loss_an_incremental_program_loaded_elsewhere_continues_where_its_run_cut(tmp_path):
    """A G91 program cut from where the head stood at cycle start, every process killed mid-cut,
    the head brought elsewhere before the program is loaded again (so that it is interpreted from
    there): the job record kept where the interrupted run started with its cut point, and the
    continued cut is placed as that run placed it, an overlap back from where the jet stopped."""
    from cnc.logic.states import Mode
    from .conftest import NEAR_HOME, full_controller, machine_config, reset_and_home

    config = machine_config(**NEAR_HOME)
    history = tmp_path / "history.sqlite"
    with full_controller(config, history) as sup:
        ready_in_auto(sup, tmp_path, RELATIVE)
        run_start = list(sup.servo()["commanded_mm"])
        command(sup, CycleStart(cycles=1))
        press_button_when_asked(sup, lambda: jet_open(sup) and sup.motion()["line"] == 5
                                and sup.motion()["segment_mm"] > 80.0, 60.0, "the first cut under way")
        sup.pause_virtual_clock()
        program_hash = sup.motion()["program_hash"]
        for child in sup.children.values():  # the power goes
            os.kill(child.process.pid, signal.SIGKILL)
    points = CutPoints(jobs_path(history), readonly=True)
    stored = points.get(program_hash)
    points.close()
    assert stored is not None and stored.line == 5, "written while it cut"
    assert stored.start_mm == pytest.approx(run_start), "where the run started, with the cut point"

    with full_controller(config, history) as sup:
        reset_and_home(sup, sup.logic.request)
        sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                       60.0, "homing")
        run_mdi(sup, "G90 G0 X40 Y60")  # the head elsewhere: the program is loaded, and interpreted, from there
        path = tmp_path / "nest.ngc"
        command(sup, LoadProgram(str(path)))
        assert sup.motion()["program_hash"] == program_hash
        assert list(sup.motion()["program_start_mm"]) == pytest.approx([40.0, 60.0])
        command(sup, SetMode(Mode.AUTO.name))
        command(sup, CycleStart(cycles=1))  # feed and grip the material, then stop before the cut
        press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.PRESSURE, 60.0, "the material in place")
        command(sup, Stop())
        sup.wait_until(lambda: logic(sup)["state"] == MachineState.STOPPED and not jet_open(sup), 30.0, "stopped")
        resumed_at = continue_and_pierce(sup, "nest.ngc: continue the cut of line 5")
        assert resumed_at == pytest.approx((stored.x_mm - config.cycle.recovery_overlap_mm, stored.y_mm), abs=1e-6), (
            resumed_at, stored)
        sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY,
                       180.0, "the rest of the program and the unload")
        assert sup.motion()["run_result"] == RunResult.DONE
        assert list(sup.motion()["program_start_mm"]) == pytest.approx(run_start), "placed as the interrupted run"


def _jet_path(program, step_mm: float = 0.05) -> np.ndarray:
    """Points every `step_mm` along the program's moves made with the jet open (XY)."""
    out = []
    for s in program.segments:
        kind = int(s["kind"])
        if not s["jet"] or kind not in (LINE, ARC):
            continue
        a, b = np.array(s["start"][:2]), np.array(s["end"][:2])
        if kind == ARC:
            c = np.array(s["center"][:2])
            r, a0 = float(np.hypot(*(a - c))), math.atan2(a[1] - c[1], a[0] - c[0])
            sweep = (math.atan2(b[1] - c[1], b[0] - c[0]) - a0) % (2.0 * math.pi)
            sweep = sweep - 2.0 * math.pi if s["cw"] else (sweep or 2.0 * math.pi)
            angles = a0 + np.linspace(0.0, sweep, max(2, int(abs(sweep) * r / step_mm)))
            out.append(c + r * np.c_[np.cos(angles), np.sin(angles)])
        else:
            out.append(a + np.linspace(0.0, 1.0, max(2, int(np.hypot(*(b - a)) / step_mm)))[:, None] * (b - a))
    return np.concatenate(out)


def _moved_into_travel(text: str) -> str:
    """A random CAM part (`_random_cam_parts`, drawn about X0 Y0) moved by 300 mm in X and Y."""
    return re.sub(r"\b([XY])(-?[\d.]+)", lambda m: f"{m.group(1)}{float(m.group(2)) + 300.0:.4f}", text)


def _cut_while(sup: Supervisor, until, limit: int) -> list[tuple[bool, float, float]]:
    """Step the paused clock a tick at a time until `until()`: the jet and the setpoint each tick."""
    seen = []
    step_until(sup, lambda: seen.append((jet_open(sup), *head_xy(sup))) or until(seen), limit, "the condition asked")
    return seen


def test_a_cut_interrupted_again_and_again_is_cut_whole_and_only_the_overlap_twice(plc_controller, tmp_path):
    """Three round CAM parts (lead-ins, chords and arcs, a pierce dwell each) interrupted three
    times, each while continuing the last: a door, the e-stop, the control logic killed; each
    continued. Every point of the program's cut lies on a setpoint cut with the jet open, and each
    continuation pierces at most the overlap before where the jet last cut (there again, where it
    stopped while piercing)."""
    from scipy.spatial import cKDTree

    from gcode.interp import Interpreter
    from cnc.machine_dialect import dialect_for
    from .test_planner_overlap import _random_cam_parts

    sup = plc_controller
    text, _ = _random_cam_parts(12, jet=True)  # F6000, P0.05
    text = _moved_into_travel(text)
    ready_in_auto(sup, tmp_path, text)
    program = Interpreter(dialect_for(sup.config), "nest.ngc").run(text.encode())
    overlap = sup.config.cycle.recovery_overlap_mm
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: jet_open(sup), 60.0, "the first pierce")
    attempts, cut_to, replies = [], [], []
    for after, fault, clear in ((900, {"doors_open": 1}, {"doors_open": 0}), (700, {"estop_pressed": 1}, {"estop_pressed": 0}),
                                (1500, "logic", None)):
        sup.pause_virtual_clock()
        seen = _cut_while(sup, lambda s: s[-1][0] and sum(p[0] for p in s) >= after, 50000)  # cut that long
        if fault == "logic":
            os.kill(sup.children["logic"].process.pid, signal.SIGKILL)
        else:
            sup.set_sim(**fault)
        seen += _cut_while(sup, lambda s: not s[-1][0], 20000)
        attempts.append(seen)
        sup.resume_virtual_clock()
        sup.wait_until(lambda: logic(sup)["state"] in (MachineState.FAULT, MachineState.ESTOP, MachineState.IDLE)
                       and not sup.motion()["state"], 60.0, "the stop")
        if clear:
            sup.set_sim(**clear)
        sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 30.0, "every alarm to reset")
        sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.STOPPED), 20.0, "ready after reset")
        if fault == "logic":
            command(sup, SetMode("AUTO"))  # a restarted logic starts in MANUAL
        cut_to.append(np.array(logic(sup)["cut_point_mm"]))  # the servo's last jet-on setpoint (the board's read-back lags a tick)
        replies.append(command(sup, Recover("continue")))
        assert "continue the cut of line" in replies[-1] or "pierce again at line" in replies[-1], replies[-1]
        sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 30.0, "the pump, then the cut again")
    sup.pause_virtual_clock()
    attempts.append(_cut_while(sup, lambda s: logic(sup)["phase"] != CyclePhase.CUTTING, 100000))
    sup.resume_virtual_clock()
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY, 60.0,
                   "the unload")
    assert sup.motion()["run_result"] == RunResult.DONE

    cut = [np.array([p[1:] for p in a if p[0]]) for a in attempts]
    distance, _ = cKDTree(np.concatenate(cut)).query(_jet_path(program))
    assert distance.max() <= 0.05 + 0.06, "every point of the program cut (P 0.05, 0.1 mm a tick)"
    assert sum("pierce again" in r for r in replies) == 1, replies  # one of the faults came while piercing
    path = _jet_path(program, 0.01)
    along = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))))
    for k in range(1, len(cut)):  # each pierce lies the overlap back along the program from where the jet
        # last cut, or there where it stopped while piercing (it pierces there again); the head then
        # passes where it stopped
        stopped = int(np.argmin(np.hypot(*(path - cut_to[k - 1]).T)))
        near = np.flatnonzero((along <= along[stopped]) & (along >= along[stopped] - 3.0 * overlap))
        pierced = near[int(np.argmin(np.hypot(*(path[near] - cut[k][0]).T)))]
        assert np.hypot(*(path[pierced] - cut[k][0])) < 0.01, "pierced on the program's path"
        back = along[stopped] - along[pierced]
        if "pierce again" in replies[k - 1]:
            assert back < 0.02, (k, back)
        else:  # never more than the overlap cut twice (measured on the program, to the point nearest the stop's
            # setpoint: in a gentle corner's blend, which spans millimetres, that can lie before the planner's)
            assert 0.0 < back <= overlap + 0.05, (k, replies[k - 1], back)
        assert np.hypot(*(cut[k] - cut_to[k - 1]).T).min() < 0.06, "passes where the jet stopped (0.1 mm a tick)"


def test_a_door_opened_in_the_rapid_after_a_part_continues_with_the_next_part_at_its_own_pierce(plc_controller, tmp_path):
    """The first part cut to its end, the jet closed by the program, the door opened in the rapid to
    the second: "continue" starts the second part at its pierce, not 2 mm up the finished one."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path, LONG)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: jet_open(sup), 60.0, "the first part cut")
    sup.pause_virtual_clock()  # the door opens in the tick asked for, however late the host looks
    step_until(sup, lambda: not jet_open(sup) and head_xy(sup)[1] > 110.0, 20000, "the rapid to the second part")
    sup.set_sim(doors_open=1)
    sup.resume_virtual_clock()
    stored, at = _door_closed_reset_and_continued(
        sup, 5, "nest.ngc: the cut of line 5 was complete: start at part 2 of 2 (line 9)")
    assert (stored.x_mm, stored.y_mm) == pytest.approx((300.0, 100.0)), "the first part's end"
    assert at == pytest.approx((100.0, 150.0)), "the second part's own pierce"
    _ends_done(sup, "the second part and the unload")


# A machine whose planner wakes every 20 ms (250 Hz, every 5th tick) and whose slow Y makes a run's
# folded corners long to work out: about a second for one step of the part below (0.2 s for all of
# them since `sections.FOLD_COARSE_STRIDES`)
SLOW_PLANNER = {"timing.base_rate_hz": 250.0, "planner.fifo_low_ms": 50.0, "planner.fifo_high_ms": 300.0,
                "jet.on_delay_s": 0.05, "jet.pierce_dwell_s": 0.0, "planner.corner_overlap_ms": 200.0,
                "planner.corner_connection_ms": 200.0, "planner.corner_programme_ms": 0.0,
                "axis.x.max_velocity_mm_s": 1000.0, "axis.x.max_accel_mm_s2": 20000.0,
                "axis.y.max_velocity_mm_s": 100.0, "axis.y.max_accel_mm_s2": 1000.0, "axis.y.max_jerk_mm_s3": 20000.0}


def test_a_continued_cut_takes_the_steps_its_timing_made_and_the_fifo_never_runs_dry(tmp_path):
    """A continue timed its restart through steps of its own and gave the run new ones, which the
    refill then made while the head moved: on this machine one step took a second to make, and the
    FIFO ran dry 0.6 s into the continued cut (the servo tripped: UNDERRUN), every time. The run
    now takes the steps the timing made, before anything moves, as a loaded program does."""
    from .conftest import NEAR_HOME, full_controller, machine_config
    from .test_planner_overlap import _random_cam_parts

    text, _ = _random_cam_parts(56, jet=True)  # three round parts at F1200, P0.05
    text = _moved_into_travel(text)
    with full_controller(machine_config(**NEAR_HOME, **SLOW_PLANNER), tmp_path / "history.sqlite") as sup:
        ready_in_auto(sup, tmp_path, text)
        command(sup, CycleStart(cycles=1))
        press_button_when_asked(sup, lambda: jet_open(sup), 60.0, "the first pierce")
        sup.pause_virtual_clock()
        _cut_while(sup, lambda s: sum(p[0] for p in s) >= 700, 20000)
        sup.set_sim(doors_open=1)
        sup.resume_virtual_clock()
        sup.wait_until(lambda: logic(sup)["state"] == MachineState.FAULT and not sup.motion()["state"], 60.0, "the stop")
        sup.set_sim(doors_open=0)
        sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 30.0, "every alarm to reset")
        sup.wait_until(lambda: logic(sup)["state"] in (MachineState.READY, MachineState.STOPPED), 20.0, "ready after reset")
        assert "continue the cut of line" in command(sup, Recover("continue"))
        sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE or logic(sup)["state"] == MachineState.FAULT, 120.0,
                       "the end of the continued cut")
        assert sup.servo()["underruns"] == 0, logic(sup)["message"]
        _ends_done(sup, "the unload")
