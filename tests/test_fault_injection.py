"""Every fault through the real processes (`cnc.sim.faultinject.catalogue()`), each at least once, at
50 and 500 mm/s: put on the simulated machine while it cuts, the jet closes within a tick of the
tick that acted, the axes stop within the bound, the right alarm is in the history, the
supervisor restarts what it may, and the machine is reset and cuts again without a restart. One
controller for the module, on the virtual clock; each test clears its own fault whatever happens,
so one failure never cascades into the next. The table is printed at the end of the run; every
fault in every state is in `test_safety_matrix.py` (the tick rig)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from cnc.alarms import AlarmHistory
from cnc.bus.keys import Keys
from cnc.bus.messages import Drives, Jog, Reset, SetMode, Stop
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.sim.faultinject import (
    SCENARIO_OVERRIDES, Fault, ask, catalogue, cutting_now, inject_during_cut, logic_block, pause_on_the_straight,
    program_path, ready_to_cut, recover, reset_until_clear, start_cut,
)
from cnc.hw.board import DigitalOut
from cnc.interlock import DRIVES_HELD_OFF
from cnc.data.layout import PlannerState, ServoFault, ServoState
from cnc.logic.states import CyclePhase, MachineState
from cnc.runtime.supervisor import Supervisor

from .conftest import FAULT_REACTIONS, NEAR_HOME, fast_plant, machine_config

FAULTS = catalogue()
RESTARTABLE = [f for f in FAULTS if f.process != "hardware"]
HARDWARE = next(f for f in FAULTS if f.process == "hardware")


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("faults")


@pytest.fixture(scope="module")
def config():
    return machine_config(**{**NEAR_HOME, **SCENARIO_OVERRIDES})


@pytest.fixture(scope="module")
def controller(config, workdir):
    """The controller with the PLC simulator, ready to cut."""
    with Supervisor(config, clock="virtual", history_path=workdir / "history.sqlite", plc_sim_times=fast_plant()) as sup:
        yield sup


@pytest.mark.parametrize("fault", RESTARTABLE, ids=[f.name for f in RESTARTABLE])
def test_a_fault_during_a_cut_closes_the_jet_stops_within_the_bound_raises_its_alarm_and_the_machine_cuts_again(
        controller, workdir, fault: Fault):
    sup = controller
    pause_on_the_straight(sup, workdir, fault.speed_mm_s)
    try:
        reaction = inject_during_cut(sup, fault)
    finally:
        fault.clear(sup)
    FAULT_REACTIONS.append(reaction)
    servo = sup.servo()
    if fault.trip == ServoFault.CONTROL_PROGRAM:  # the alarm names the program and what it did
        with AlarmHistory(sup.history_path, readonly=True) as history:
            raised = [e for e in history.after(history.last_seq() - 50, 100).entries
                      if e.id == "control_program" and e.action == "raised"]
        assert raised and raised[-1].detail.startswith("control program fault_injection (Faulty) "), raised
        assert "the servo's own PI-P stopped the axes on the path" in raised[-1].detail
    if fault.trip is not None:
        assert ServoFault(servo["trip_fault"]) == fault.trip, reaction.state
    if fault.hold:
        assert sup.motion()["state"] == PlannerState.HELD and servo["state"] == ServoState.HOLDING, reaction.state
        assert logic_block(sup)["state"] == MachineState.HOLD
    else:
        assert logic_block(sup)["state"] in (MachineState.FAULT, MachineState.ESTOP), reaction.state
    assert 0 <= reaction.jet_off_ticks <= 1 or fault.trip is None, f"jet closed {reaction.jet_off_ticks} ticks after"
    if reaction.bound_mm is not None:
        assert reaction.stop_mm <= reaction.bound_mm, f"{reaction.stop_mm:.2f} mm, bound {reaction.bound_mm:.2f} mm"
    if fault.process:
        assert reaction.restarted == f"{fault.process} restarted"
    if fault.process == "planner":  # its program went with it: the status must not offer a cycle start
        assert sup.motion()["program_name"] == ""
    assert sup.failed is None
    recover(sup, fault, workdir, fault.speed_mm_s)  # reset, the program again: the jet is on, the head moves
    assert cutting_now(sup)


def test_a_reset_pressed_while_the_axes_run_out_a_stop_changes_nothing(controller, workdir):
    """An operator who presses reset at once: the jet stays closed, the stop runs out, the trip
    stays latched; once the door is shut, a reset recovers."""
    sup = controller
    pause_on_the_straight(sup, workdir, 500.0)
    try:
        t0 = sup.hw()["tick"]
        sup.set_sim(doors_open=1)
        sup.run_ticks(5)
        assert sup.servo()["state"] == ServoState.STOPPING
        reply = sup.logic.request(Reset())
        assert not reply.ok and "still stopping" in reply.reason, reply.reason
        for _ in range(10):
            sup.run_ticks(2)
            assert not sup.hw()["digital_out"] & DigitalOut.JET_VALVE
        sup.resume_virtual_clock()
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT, 10.0, "the end of the stop")
        assert sup.servo()["fault"] == ServoFault.DOORS and sup.hw()["jet_off_tick"] - t0 <= 2
        reply = sup.logic.request(Reset())
        assert "still present: 2292" in reply.reason and sup.servo()["state"] == ServoState.FAULT
    finally:
        sup.set_sim(doors_open=0)
    ready_to_cut(sup, program_path(workdir, 50.0))
    start_cut(sup, 50.0)


HELD_OFF = [f for f in FAULTS if f.name in ("e-stop pressed", "door opened", "mains loss")]


@pytest.mark.parametrize("drives_on", [True, False], ids=["drives on", "drives off"])
@pytest.mark.parametrize("fault", HELD_OFF, ids=[f.name for f in HELD_OFF])
def test_a_reset_while_the_board_still_shows_the_cause_leaves_the_drives_off_and_trips_nothing(
        controller, workdir, fault: Fault, drives_on: bool):
    """An operator who presses reset before closing the door (releasing the e-stop, switching the
    mains on): the drives stay off, the answer says why, nothing trips or brakes in the ticks after
    it; with the cause gone, a reset switches them on. (Switched on, they would trip in the next
    tick: a stop of a machine at rest, and a reset refused until it had run out.)"""
    sup = controller
    if logic_block(sup)["phase"] != CyclePhase.NONE:
        ask(sup, Stop(), "a stop of the cycle under way")
        sup.wait_until(lambda: logic_block(sup)["phase"] == CyclePhase.NONE, 120.0, "the cycle to end")
    reset_until_clear(sup)  # at rest, drives on, nothing waiting
    if not drives_on:
        ask(sup, Drives(False), "the drives off")
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.DISABLED, 10.0, "the drives off")
    with AlarmHistory(sup.history_path, readonly=True) as history:
        seq0 = history.last_seq()
    fault.inject(sup)
    try:
        def raised() -> bool:
            with AlarmHistory(sup.history_path, readonly=True) as history:
                return any(e.id == fault.alarm and e.action == "raised" for e in history.after(seq0, 1000).entries)
        sup.wait_until(lambda: raised() and sup.servo()["state"] != ServoState.STOPPING
                       and sup.servo()["stop_causes"] & DRIVES_HELD_OFF, 30.0, f"{fault.name}: its alarm, the axes at rest")
        trips = sup.servo()["trip_seq"]
        sup.pause_virtual_clock()
        reply = sup.logic.request(Reset())
        assert reply.ok and "the drives stay off while" in reply.reason and "still present: " in reply.reason, reply.reason
        for _ in range(60):  # 15 scans of the logic: it has written the drives off, the servo has read them
            sup.run_ticks(1)
            servo = sup.servo()
            assert servo["state"] in (ServoState.DISABLED, ServoState.FAULT), ServoState(servo["state"]).name
            assert servo["trip_seq"] == trips, "a trip after the reset"
        assert logic_block(sup)["drives_on"] == 0
    finally:
        sup.resume_virtual_clock()
        fault.clear(sup)
    sup.wait_until(lambda: not sup.servo()["stop_causes"] & DRIVES_HELD_OFF, 10.0, "the cause gone from the tick")
    reset_until_clear(sup)  # drives on, holding, nothing waiting
    assert sup.servo()["trip_seq"] == trips, "a trip at the reset that switched the drives on"
    with AlarmHistory(sup.history_path, readonly=True) as history:
        actions = [e.action for e in history.after(seq0, 1000).entries if e.id == fault.alarm]
    assert actions.count("raised") == 1, actions


def test_losing_the_lock_holders_station_holds_the_cut_and_stops_a_jog(controller, workdir):
    """The station that commands is gone (its screen crashed, its cable pulled): a cut holds on the
    path (the jet closes at rest), a jog it was steering stops."""
    sup = controller
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    session = open_client([f"tcp/127.0.0.1:{sup.config.zenoh.listen[0].rsplit(':', 1)[1]}"])
    try:
        pause_on_the_straight(sup, workdir, 50.0)
        sup.resume_virtual_clock()
        station = OperatorStation(session, keys, "bench-1")
        sup.wait_until(lambda: station.take_lock().ok, 10.0, "the command lock")
        with AlarmHistory(sup.history_path, readonly=True) as history:
            seq0 = history.last_seq()
        station.close()

        def lost_recorded() -> bool:  # the alarm is recorded once the output is safe, not before
            with AlarmHistory(sup.history_path, readonly=True) as history:
                return any(e.code == 1070 for e in history.after(seq0, 100).entries)
        sup.wait_until(lambda: sup.motion()["state"] == PlannerState.HELD and not sup.hw()["digital_out"] & DigitalOut.JET_VALVE
                       and lost_recorded(), 30.0, "the hold after the station was lost, and its alarm 1070 in the history")
        FAULT_REACTIONS.append(_note("station lost (cut)", "held on the path, jet closed at rest", "1070 Operator station lost"))
        ask(sup, Stop(), "a stop of the held cycle")  # end it, then jog
        sup.wait_until(lambda: logic_block(sup)["phase"] == CyclePhase.NONE, 60.0, "the cycle to end")
        ask(sup, SetMode("MANUAL"), "MANUAL")
        station = OperatorStation(session, keys, "bench-2")
        sup.wait_until(lambda: station.take_lock().ok, 10.0, "the command lock")
        assert station.request(Jog("x", 50.0)).ok
        sup.wait_until(lambda: sup.motion()["state"] == PlannerState.JOGGING, 10.0, "jogging")
        station.close()  # no refresh, no jog stop: the dead-man and the lost station both end it
        sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE and sup.servo()["state"] == ServoState.HOLDING,
                       30.0, "the jog to stop")
        FAULT_REACTIONS.append(_note("station lost (jog)", "jog stopped", "-"))
    finally:
        session.close()
    ready_to_cut(sup, program_path(workdir, 50.0))
    start_cut(sup, 50.0)


def _note(fault: str, state: str, alarm: str):
    from cnc.sim.faultinject import Reaction

    return Reaction(fault, 0.0, -1, -1, 0.0, None, state, alarm)


def test_the_history_kept_every_entry_of_the_faults_in_sequence(controller):
    with AlarmHistory(controller.history_path, readonly=True) as history:
        page = history.after(0, 1000)
    seqs = [e.seq for e in page.entries]
    assert seqs == list(range(1, len(seqs) + 1)), "no entry lost across the restarts"
    lost = [e.detail for e in page.entries if e.code == 1098 and e.action == "raised"]
    for name in ("gateway", "logger", "plc_link", "planner", "logic", "servo"):
        assert any(d.startswith(f"{name} process exited with code -9; restarted") for d in lost), (name, lost)


def test_killing_the_hardware_server_ends_the_controller_and_a_new_one_resets_and_cuts(controller, config, workdir):
    """The board's owner may not be restarted under a running servo: the supervisor gives up, the
    history says why, and a controller started again on the same history cuts again."""
    pause_on_the_straight(controller, workdir, HARDWARE.speed_mm_s)
    reaction = inject_during_cut(controller, HARDWARE)
    FAULT_REACTIONS.append(reaction)
    assert controller.failed and "hardware process exited with code -9" in controller.failed
    assert reaction.alarm == "1098 Controller process lost"
    controller.stop()
    with Supervisor(config, clock="virtual", history_path=workdir / "history.sqlite", plc_sim_times=fast_plant()) as sup:
        with AlarmHistory(sup.history_path, readonly=True) as history:
            details = [e.detail for e in history.after(0, 1000).entries if e.code == 1098]
        assert any(d.startswith("hardware process exited with code -9; not restarted") for d in details)
        ready_to_cut(sup, program_path(workdir, 50.0))
        start_cut(sup, 50.0)
        assert time.monotonic() > 0 and cutting_now(sup)
