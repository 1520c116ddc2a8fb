"""The control logic in the whole controller on the virtual clock, with the PLC simulator over a
real pty: the automatic cycle, guided procedures, refusals, interlocks, PLC link loss and the
alarm history across killed processes."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest

from cnc.alarms import AlarmHistory
from cnc.bus.keys import Keys
from cnc.bus.messages import (
    AlarmEvent, AlarmList, CycleStart, Drives, GoTo, Hold, HistoryPage, Jog, JetTest, LoadProgram, ProcedureConfirm,
    ProcedureEnd, ProcedureStart, ProcedureState, ProcedureStop, Pump, Reply, Reset, Resume, SetMode, Stop, decode,
)
from cnc.hw.board import DigitalOut
from cnc.data.layout import LinkState, PlannerState, RunResult, ServoFault, ServoState
from cnc.logic.states import CyclePhase, MachineState
from cnc.runtime.supervisor import Supervisor
from cnc.sim.operator import ScriptError

from .conftest import logic, press_button_when_asked, reset_and_home
from .test_stale_motion import slow_to_prepare


PART = """(a part: pierce, a square with a rounded corner, jet off)
G21 G90 G64 P0.05 F6000
G0 X100 Y100
M3
G1 X140
G1 Y130
G3 X130 Y140 R10
G1 X100
G1 Y100
M5
G0 X60 Y60
M2
"""


class Events:
    """Everything the controller publishes on its alarm and procedure keys, as a subscriber sees it."""

    def __init__(self, sup: Supervisor) -> None:
        keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
        self.alarms: list[AlarmEvent] = []
        self.procedures: list[ProcedureState] = []
        self.lock = threading.Lock()
        self.subs = [
            sup.router.declare_subscriber(keys.event_alarm, lambda s: self._add(self.alarms, decode(s.payload.to_bytes(), AlarmEvent))),
            sup.router.declare_subscriber(keys.procedure, lambda s: self._add(self.procedures, decode(s.payload.to_bytes(), ProcedureState))),
        ]

    def _add(self, into: list, item) -> None:
        with self.lock:
            into.append(item)

    def codes(self, action: str = "raised") -> list[int]:
        with self.lock:
            return [e.code for e in self.alarms if e.action == action]

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()


def command(sup: Supervisor, msg) -> str:
    """Ask the control logic; insist it accepts; returns the reply's remark."""
    reply = sup.logic.request(msg)
    assert reply.ok, reply.reason
    return reply.reason


def refusal(sup: Supervisor, msg) -> str:
    reply = sup.logic.request(msg)
    assert not reply.ok, f"{msg} was accepted"
    return reply.reason


def ready_in_auto(sup: Supervisor, tmp_path, program: str | None = None) -> None:
    """Drives on, homed, a program loaded, AUTO: READY for cycle start."""
    reset_and_home(sup, sup.logic.request)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                   60.0, "homing")
    path = tmp_path / "nest.ngc"
    path.write_text(program or PART)
    command(sup, LoadProgram(str(path)))
    command(sup, SetMode("AUTO"))


def jet_open(sup: Supervisor) -> bool:
    return bool(sup.hw()["digital_out"] & DigitalOut.JET_VALVE)


def cutting_in_auto(sup: Supervisor, tmp_path, start=None) -> None:
    """READY in AUTO, one cycle started (by `start()`, default the logic's own request), the
    transport station's button pressed when asked, until the head cuts with the jet open."""
    ready_in_auto(sup, tmp_path)
    if start is None:
        command(sup, CycleStart(cycles=1))
    else:
        reply = start()
        assert reply.ok, reply.reason
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING and jet_open(sup)
                            and max(map(abs, sup.servo()["commanded_velocity_mm_s"])) > 20.0, 60.0,
                            "cutting with the jet on")


def test_automatic_cycle_runs_transport_cutting_and_unload_for_the_cycles_asked(plc_controller, tmp_path):
    sup = plc_controller
    events = Events(sup)
    ready_in_auto(sup, tmp_path)
    runs = sup.motion()["run_seq"]
    command(sup, CycleStart(cycles=2))
    phases, pressures = set(), set()

    def done() -> bool:
        lo = logic(sup)
        phases.add(CyclePhase(lo["phase"]))
        if lo["phase"] == CyclePhase.CUTTING:
            pressures.add(sup.plc_sim.outputs()["pump_pressure_set"])
        return lo["cycles_done"] == 2 and lo["phase"] == CyclePhase.NONE

    press_button_when_asked(sup, done, 120.0, "two automatic cycles")
    m = sup.motion()
    assert m["run_seq"] == runs + 2 and m["run_result"] == RunResult.DONE
    assert phases >= {CyclePhase.PROCEDURE, CyclePhase.TRANSPORT, CyclePhase.PRESSURE, CyclePhase.CUTTING, CyclePhase.UNLOAD}
    assert {1200.0, 3800.0} <= pressures, "pierce at low pressure, then cut at high pressure"
    assert logic(sup)["state"] == MachineState.READY
    sup.wait_until(lambda: 3001 in events.codes(), 5.0, "the cycle-done message")
    # the transport procedure was walked step by step, each change published
    steps = [p for p in events.procedures if p.id == "transport"]
    assert steps[-1].state == "done" and all(s.state == "done" for s in steps[-1].steps)
    assert [p.seq for p in steps] == sorted({p.seq for p in steps})
    assert any(p.step == 10 and p.instruction.startswith("Press the button") for p in steps)
    assert 2842 in events.codes()  # the paper's "press button" prompt
    sup.wait_until(lambda: sup.plc_sim.outputs()["unload"] == 0.0, 5.0, "the unload output to drop")
    assert sup.plc_sim.outputs()["feed_material"] == 0.0 and sup.plc_sim.outputs()["cnc_cutting"] == 0.0
    events.close()


def test_commands_the_mode_or_state_does_not_allow_are_refused_with_the_reason(plc_controller, tmp_path):
    sup = plc_controller
    events = Events(sup)
    assert "wrong operation mode: cycle start needs AUTO (mode is MANUAL)" in refusal(sup, CycleStart())
    sup.wait_until(lambda: 37 in events.codes(), 5.0, "alarm 37 Wrong operation mode")
    assert "no such" not in refusal(sup, JetTest(True))  # drives off, no pressure
    assert "mode 'TURBO' is not one of: MANUAL, AUTO" in refusal(sup, SetMode("TURBO"))
    ready_in_auto(sup, tmp_path)
    assert "jog needs MANUAL" in refusal(sup, Jog("x", 10.0))
    assert "pump on/off needs MANUAL" in refusal(sup, Pump(True))
    assert "cycles -1 must be 0" in refusal(sup, CycleStart(cycles=-1))
    command(sup, CycleStart(cycles=1))
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.RUNNING, 10.0, "the cycle to run")
    assert "cannot change the operation mode while RUNNING" in refusal(sup, SetMode("MANUAL"))
    assert "cannot start while RUNNING" in refusal(sup, CycleStart())
    command(sup, Stop())
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.STOPPED, 30.0, "the stop")
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    replies = list(sup.router.get(keys.logic("start"), payload=b'{"cycles": "many"}', timeout=5.0))
    assert "malformed command" in decode(replies[0].ok.payload.to_bytes(), Reply).reason
    events.close()


def test_door_opened_during_a_cut_closes_the_jet_in_the_tick_then_the_servo_stops_on_the_path(plc_controller, tmp_path):
    """The door is an interlock of the tick: the jet closes the tick the servo sees the door, the
    servo brings the axes to rest along the path itself, then trips; the logic tells people."""
    sup = plc_controller
    events = Events(sup)
    cutting_in_auto(sup, tmp_path)
    jet = lambda: jet_open(sup)  # noqa: E731
    start = sup.pause_virtual_clock()
    sup.set_sim(doors_open=1)
    jet_off_at = moving_after_jet_off = None
    for _ in range(200):
        tick = sup.run_ticks(1)
        if jet_off_at is None and not jet():
            jet_off_at = tick
        elif jet_off_at is not None and moving_after_jet_off is None:
            moving_after_jet_off = sup.servo()["state"] == ServoState.STOPPING
            break
    sup.resume_virtual_clock()
    assert jet_off_at is not None and jet_off_at - start <= 2, "jet closed within a tick of the door in the image"
    assert moving_after_jet_off, "the jet closed before the axes stopped: the servo runs out its own stop"
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT and sup.motion()["state"] == PlannerState.IDLE,
                   30.0, "the controlled stop")
    s = sup.servo()
    assert s["fault"] == ServoFault.DOORS and s["brake_distance_mm"] > 0.0, "stopped under control, then tripped"
    assert sup.motion()["run_result"] == RunResult.FAULT
    assert logic(sup)["state"] == MachineState.FAULT and not jet()
    sup.wait_until(lambda: 2292 in events.codes(), 5.0, "alarm 2292 in the events")
    assert "2292 Safety door open" in command(sup, Reset())  # the door is still open: not reset
    sup.set_sim(doors_open=0)
    sup.wait_until(lambda: 2292 in events.codes("cleared"), 5.0, "the door alarm to clear")
    assert command(sup, Reset()) == ""
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 10.0, "READY after the reset")
    with AlarmHistory(sup.history_path, readonly=True) as history:
        actions = [(e.code, e.action) for e in history.after(0, 1000).entries if e.code == 2292]
        program_errors = [e for e in history.after(0, 1000).entries if e.code == 1060]
    assert actions == [(2292, "raised"), (2292, "cleared"), (2292, "reset")], "one alarm: the door's, not the trip's too"
    assert program_errors == [], "the servo's stop is not a program error"
    events.close()


def test_a_late_plc_answer_costs_one_exchange_but_a_lost_link_is_an_alarm_after_its_lost_cycles_and_a_safe_stop(plc_controller, tmp_path):
    sup = plc_controller
    events = Events(sup)
    # the part at F300: half a minute of cut, so that it is still cutting when the link (which
    # lives in wall time, where the virtual clock runs the controller flat out) is lost; at F6000
    # the cut could end first (it did once its corners were overlapped)
    ready_in_auto(sup, tmp_path, PART.replace("F6000", "F300"))
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 60.0, "the cutting phase")
    link = sup.area.reader("plc")
    # one answer later than the master's timeout (a PLC busy with its scan): one exchange, not the link
    late_from = link.read_dict()
    sup.plc_sim.answer_late(2, 1.5 * sup.config.plc.timeout_ms / 1000)
    sup.wait_until(lambda: link.read_dict()["exchanges"] >= late_from["exchanges"] + 3, 10.0, "exchanges after the late answer")
    after_late = link.read_dict()
    assert after_late["state"] == LinkState.OK and after_late["losses"] == late_from["losses"]
    assert 1020 not in events.codes() and logic(sup)["phase"] == CyclePhase.CUTTING
    before = link.read_dict()
    sup.plc_sim.inject("link_dead", True)
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.LOST, 5.0, "the link to be lost")
    plc = sup.area.reader("plc").read_dict()
    assert plc["failed"] - before["failed"] == sup.config.plc.lost_after_cycles, "lost after exactly lost_after_cycles failed exchanges"
    sup.wait_until(lambda: 1020 in events.codes(), 5.0, "alarm 1020 PLC link lost")
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE and sup.servo()["state"] == ServoState.FAULT
                   and logic(sup)["state"] == MachineState.FAULT, 30.0, "the safe stop")  # the logic's next scan says so
    assert sup.servo()["fault"] == ServoFault.PLC_LINK, "the tick stopped the cut itself: the PLC's inputs went stale"
    assert not sup.hw()["digital_out"] & DigitalOut.JET_VALVE
    assert logic(sup)["phase"] == CyclePhase.NONE
    sup.plc_sim.inject("link_dead", False)
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 10.0, "the reconnection")
    sup.wait_until(lambda: 1020 in events.codes("cleared"), 5.0, "the link alarm to clear")
    command(sup, Reset())
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 10.0, "READY after the reset")
    events.close()


def test_emergency_stop_trips_everything_and_reset_waits_for_its_release(plc_controller, tmp_path):
    sup = plc_controller
    ready_in_auto(sup, tmp_path)
    sup.set_sim(estop_pressed=1)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.ESTOP, 5.0, "ESTOP")
    assert sup.servo()["state"] == ServoState.FAULT
    assert "1001 Emergency stop" in command(sup, Reset())
    assert "alarms wait for reset: 1001 Emergency stop" in refusal(sup, CycleStart())
    sup.set_sim(estop_pressed=0)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.FAULT, 5.0, "the e-stop released, its alarm latched")
    command(sup, Reset())
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 10.0, "READY after the reset")


def test_guided_procedure_walks_its_steps_publishes_each_change_and_can_be_stopped(plc_controller):
    sup = plc_controller
    events = Events(sup)
    command(sup, ProcedureStart("startup"))
    sup.wait_until(lambda: any(p.id == "startup" and p.step == 3 for p in events.procedures), 10.0, "steps 1-3 done")
    awaited = [p for p in events.procedures if p.id == "startup"][-1]
    assert awaited.steps[3].text == "Drives on" and awaited.instruction == "Reset the machine to switch the drives on"
    assert [s.state for s in awaited.steps] == ["done", "done", "done", "awaited", "pending"]
    assert "while it runs; stop it first" in refusal(sup, ProcedureEnd())
    reset_and_home(sup, sup.logic.request)
    sup.wait_until(lambda: events.procedures[-1].state == "done", 60.0, "the start-up procedure to finish")
    command(sup, ProcedureEnd())
    sup.wait_until(lambda: events.procedures[-1].state == "idle", 5.0, "the window to close")
    command(sup, ProcedureStart("pump_warmup"))
    sup.wait_until(lambda: events.procedures[-1].instruction.startswith("Move the head over the catcher"), 5.0, "a confirm step")
    command(sup, ProcedureConfirm())
    sup.wait_until(lambda: events.procedures[-1].step == 1, 5.0, "the confirm to count")
    command(sup, ProcedureStop())
    sup.wait_until(lambda: 2131 in events.codes(), 5.0, "alarm 2131 procedure stop")
    sup.wait_until(lambda: events.procedures[-1].state == "stopped", 5.0, "the procedure window to say stopped")
    events.close()


def test_a_cycle_stopped_or_faulted_while_its_procedure_waits_ends_that_procedure_too(plc_controller, tmp_path):
    """The transport procedure the cycle opened waits for the station's button; the operator stops
    the cycle, or a door opens: the procedure ends with the cycle (stopped, saying why), and the next
    cycle start is taken. It used to run on, asking for the button of a cycle that had ended, and
    the next start was refused ("a procedure is running: end it first"): found by an operator
    pressing everything at random."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path)
    events = Events(sup)
    for end in ("stop", "door"):
        command(sup, CycleStart(cycles=1))
        sup.wait_until(lambda: logic(sup)["procedure"] == "transport" and logic(sup)["procedure_state"] == "running",
                       10.0, "the transport procedure waiting for the button")
        if end == "stop":
            command(sup, Stop())
        else:
            sup.set_sim(doors_open=1)
        sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["procedure_state"] == "stopped",
                       10.0, "the cycle and its procedure ended")
        if end == "door":
            sup.set_sim(doors_open=0)
            sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 20.0, "every alarm to reset")
            sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 20.0, "ready after the reset")
    sup.wait_until(lambda: sum(a.code == 2131 for a in events.alarms if a.action == "raised") >= 2, 5.0, "procedure_stop twice")
    assert any("stopped: the cycle was stopped" in a.detail for a in events.alarms if a.code == 2131)
    assert any("stopped: the cycle stopped at a fault" in a.detail for a in events.alarms if a.code == 2131)
    command(sup, CycleStart(cycles=1))  # taken: no procedure left running
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 60.0, "the next cycle under way")
    command(sup, Stop())
    events.close()


def test_manual_mode_runs_the_pump_and_the_jet_test_only_at_pressure(plc_controller):
    sup = plc_controller
    command(sup, Reset())
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 10.0, "drives on")
    assert "the jet test needs at least 1050 bar" in refusal(sup, JetTest(True))
    command(sup, Pump(True, pressure_bar=2000.0))
    sup.wait_until(lambda: abs(sup.plc_sim.inputs()["pump_pressure"] - 2000.0) < 50, 10.0, "the pump at 2000 bar")
    sup.wait_until(lambda: sup.logic.request(JetTest(True)).ok, 10.0, "the jet test to be allowed at pressure")
    sup.wait_until(lambda: sup.hw()["digital_out"] & DigitalOut.JET_VALVE, 5.0, "the jet to open")
    assert "jet test off" in refusal(sup, Pump(False))
    command(sup, JetTest(False))
    sup.wait_until(lambda: not sup.hw()["digital_out"] & DigitalOut.JET_VALVE, 5.0, "the jet to close")
    command(sup, Pump(False))
    command(sup, Drives(False))
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.DISABLED, 5.0, "drives off")


def test_alarm_history_loses_nothing_when_its_writer_is_killed(plc_controller):
    """The control logic writes the history: killed, the new one goes on from where it stopped
    (every other process killed during a cut: tests/test_fault_injection.py)."""
    sup, victim = plc_controller, "logic"
    events = Events(sup)
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    sup.set_sim(doors_open=1)  # an active alarm the restarted logic must remember
    sup.wait_until(lambda: 2292 in events.codes(), 5.0, "the door alarm")
    for _ in range(5):
        refusal(sup, CycleStart())  # wrong mode: one history entry each
    before = sup.children[victim].process.pid
    os.kill(before, signal.SIGKILL)
    sup.wait_until(lambda: victim in sup.children and sup.children[victim].process.pid != before, 30.0, f"a new {victim}")
    sup.wait_until(lambda: sup.logic.request(Reset()).ok, 30.0, "the logic to answer")
    for _ in range(3):
        refusal(sup, CycleStart())
    active = decode(list(sup.router.get(keys.alarms_active, timeout=5.0))[0].ok.payload.to_bytes(), AlarmList)
    assert any(a.code == 2292 and a.active for a in active.alarms), "the door alarm survived"
    page = decode(list(sup.router.get(f"{keys.alarms_history}?after=0;limit=1000", timeout=5.0))[0].ok.payload.to_bytes(),
                  HistoryPage)
    seqs = [e.seq for e in page.entries]
    assert seqs == list(range(1, len(seqs) + 1)), "sequence numbers increase by one, none lost"
    assert page.last_seq == seqs[-1]
    assert sum(1 for e in page.entries if e.code == 37) == 8
    # a subscriber that saw the events live catches up on anything it missed, by sequence number
    sup.wait_until(lambda: events.alarms and events.alarms[-1].seq == page.last_seq, 5.0, "the last event live")
    seen = {e.seq for e in events.alarms}
    missed = [s for s in seqs if s not in seen]
    catch_up = decode(list(sup.router.get(f"{keys.alarms_history}?after={min(missed) - 1 if missed else page.last_seq}",
                                          timeout=5.0))[0].ok.payload.to_bytes(), HistoryPage)
    assert set(missed) <= {e.seq for e in catch_up.entries}
    assert sup.failed is None
    events.close()


def test_closing_the_pty_cuts_the_plc_link_mid_cut_and_a_new_simulator_is_reconnected(plc_controller, tmp_path):
    """The cable cut for real: the simulator and its pty go away; a new one comes up under the same device name."""
    sup = plc_controller
    events = Events(sup)
    ready_in_auto(sup, tmp_path)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 60.0, "the cutting phase")
    before = sup.area.reader("plc").read_dict()
    sup.plc_sim.stop()  # closes the simulator's end of the pty
    # a script waiting for the cycle's end (the demo, a test) learns why it will not come, at once: the
    # link lost, or first the pump pressure the stopping simulator reported on its way out
    with pytest.raises(ScriptError, match="faulted while waiting for the cycle's end: safe stop: (plc_link_lost|pump_pressure_fault): "):
        press_button_when_asked(sup, lambda: logic(sup)["cycles_done"] == 1, 120.0, "the cycle's end")
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.LOST, 5.0, "the link to be lost")
    assert sup.area.reader("plc").read_dict()["failed"] - before["failed"] <= sup.config.plc.lost_after_cycles
    sup.wait_until(lambda: 1020 in events.codes(), 5.0, "alarm 1020 PLC link lost")
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE and logic(sup)["state"] == MachineState.FAULT,
                   30.0, "the safe stop")
    assert not sup.hw()["digital_out"] & DigitalOut.JET_VALVE
    sup.restart_plc_sim()
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 15.0, "the reconnection")
    sup.wait_until(lambda: 1020 in events.codes("cleared"), 5.0, "the link alarm to clear")
    command(sup, Reset())
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 10.0, "READY after the reset")
    events.close()


def test_feed_hold_in_the_cutting_phase_holds_on_the_path_and_resume_finishes_the_cycle(plc_controller, tmp_path):
    sup = plc_controller
    ready_in_auto(sup, tmp_path)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING
                            and sup.servo()["state"] == ServoState.TRACKING, 60.0, "the cut under way")
    command(sup, Hold())
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.HELD and logic(sup)["state"] == MachineState.HOLD,
                   10.0, "the hold")
    held_at = sup.motion()["done_mm"]
    assert 0.0 < held_at < sup.motion()["total_mm"]
    assert "nothing to hold" in refusal(sup, Hold())
    command(sup, Resume())
    sup.wait_until(lambda: logic(sup)["cycles_done"] == 1 and logic(sup)["phase"] == CyclePhase.NONE, 60.0, "the cycle's end")
    assert sup.motion()["run_result"] == RunResult.DONE and sup.servo()["fault"] == 0


def test_an_interrupted_light_barrier_stops_the_running_cycle(plc_controller, tmp_path):
    sup = plc_controller
    events = Events(sup)
    ready_in_auto(sup, tmp_path)
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 60.0, "the cutting phase")
    sup.plc_sim.inject("barrier_rear", True)
    sup.wait_until(lambda: 1041 in events.codes(), 5.0, "alarm 1041 safety barrier interrupted")
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.FAULT and sup.motion()["state"] == PlannerState.IDLE,
                   30.0, "the safe stop")
    assert [e.detail for e in events.alarms if e.code == 1041][0] == "rear barrier interrupted"
    sup.plc_sim.inject("barrier_rear", False)
    sup.wait_until(lambda: 1041 in events.codes("cleared"), 5.0, "the barrier alarm to clear")
    command(sup, Reset())
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 10.0, "READY after the reset")
    events.close()


def test_a_door_opened_while_the_start_is_planned_voids_it_and_a_reset_goes_on(plc_controller, tmp_path):
    """The cycle's start waits behind a long re-plan when a door opens: the logic's stop voids it
    (its epoch is past), nothing moves, and once the door is shut and reset the cycle runs."""
    sup = plc_controller
    ready_in_auto(sup, tmp_path, program=slow_to_prepare())
    command(sup, SetMode("MANUAL"))
    command(sup, GoTo({"x": 45.0, "y": 45.0}))  # the head moves away: the start interprets the program again
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE and sup.servo()["state"] == ServoState.HOLDING
                   and logic(sup)["state"] == MachineState.READY, 30.0, "the go-to (and the logic's next scan seeing it)")
    command(sup, SetMode("AUTO"))
    runs = sup.motion()["run_seq"]
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING, 60.0,
                            "the cutting phase: the start is planned")
    sup.set_sim(doors_open=1)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.FAULT and logic(sup)["phase"] == CyclePhase.NONE, 30.0,
                   "the safe stop")
    time.sleep(1.0)  # longer than the start's planning could still have taken to run
    assert sup.motion()["run_seq"] == runs, "the start never ran"
    assert sup.servo()["state"] in (ServoState.HOLDING, ServoState.FAULT) and sup.fifo.fill() == 0
    sup.set_sim(doors_open=0)

    def reset_to_ready() -> bool:
        sup.logic.request(Reset())
        return logic(sup)["state"] == MachineState.READY
    sup.wait_until(reset_to_ready, 30.0, "READY after the reset")
    command(sup, CycleStart(cycles=1))
    press_button_when_asked(sup, lambda: sup.motion()["run_seq"] == runs + 1, 120.0, "the cycle after the reset")
    # leave the machine idle for the next test: its motion is short, the cycle may have ended already
    stopped = sup.logic.request(Stop())
    assert stopped.ok or stopped.reason.startswith("stop: nothing to stop"), stopped.reason
    sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and sup.motion()["state"] == PlannerState.IDLE,
                   60.0, "the cycle stopped")


def test_stop_is_answered_while_a_long_program_load_is_under_way(plc_controller, tmp_path):
    """STOP never queues behind slow work: it has its own lane through the gateway, and the planner
    answers it while it checks and plans a program."""
    from cnc.bus.keys import Keys
    from cnc.bus.operator import OperatorStation
    from cnc.bus.session import open_client

    from cnc.runtime.procs import program_dir

    sup = plc_controller
    path = Path(program_dir(sup.config, sup.runtime.history_path)) / "big.ngc"  # stations load from there
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(slow_to_prepare())  # seconds of interpretation
    session = open_client([sup.config.zenoh.listen[0]])
    station = OperatorStation(session, Keys(sup.config.zenoh.key_prefix, sup.config.machine.name), "panel")
    try:
        assert station.take_lock().ok
        answers: dict[str, object] = {}
        loader = threading.Thread(target=lambda: answers.update(load=station.request(LoadProgram(str(path)))))
        loader.start()
        time.sleep(0.3)  # the load is in the planner's hands
        stop = station.request(Stop())
        still_loading = loader.is_alive()
        loader.join(120.0)
        assert answers["load"].ok, answers["load"].reason
        assert still_loading, "the stop was answered while the load was still under way"
        assert stop.reason.startswith("stop: nothing to stop"), stop.reason
    finally:
        station.close()
        session.close()
