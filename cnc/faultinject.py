"""Fault injection on the simulated machine: a fault put on it in the middle of a cut, and how
fast the machine reached its safe state, read off the board's own record in base ticks.

Used by the tests (`tests/test_fault_injection.py`) and `bench/faults.py`, and by an integrator
commissioning a machine file on the simulated board. Each `Fault` says how to inject it, how to
take it away again, which alarm must stand in the history, and the bounds (in ticks) within
which the jet must be closed and the axes stand still. `inject_during_cut` measures one;
`recover` takes the fault away, resets, and starts the cycle again to prove the machine can go on.

The reaction is measured from the tick the fault was injected at: to the tick the board's jet
valve closed (`hw.jet_off_tick`) and to the last tick an encoder still moved
(`hw.last_motion_tick`). Faults that the controller learns of in wall time (a process dying, the
PLC's serial link) count their detection in too: on the real-time clock a tick is a millisecond.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from plc_link.sim_model import PlantTimes

from .alarms import AlarmHistory
from .bus.messages import CycleStart, Home, LoadProgram, Reset, SetMode
from .hw.board import DigitalOut
from .layout import LinkState, PlannerState, ServoState
from .logic.states import CyclePhase, MachineState
from .supervisor import Supervisor

# A cut long enough for every fault to land in its middle: a 400 x 300 mm frame, cut three times.
CUT_PROGRAM = """(fault injection: a long frame cut; every fault lands in its middle)
G21 G90 G64 P0.05 F3000
G0 X100 Y100
M3
G1 X500
G1 Y400
G1 X100
G1 Y100
G1 X500
G1 Y400
G1 X100
G1 Y100
G1 X500
G1 Y400
G1 X100
G1 Y100
M5
G0 X60 Y60
M2
"""
STILL_FOR_TICKS = 200  # the axes stand still when no encoder moved for this long
# Settings the fault scenarios need on the shipped machine: the cycle skips the guided transport
# procedure (nobody presses the station's button), the table starts near home.
# A transport system and a pump that are quick about it: faults land in cuts, not in waits.
FAST_PLANT = PlantTimes(feed_s=0.3, gripper_s=0.1, unload_s=0.3, pneumatic_s=0.1, ramp_bar_s=20000.0)
SCENARIO_OVERRIDES = {
    "cycle.transport_procedure": "",
    "sim.axes.x.start_position_mm": 30.0, "sim.axes.y.start_position_mm": 30.0,
}


@dataclass(frozen=True)
class Fault:
    """One fault: how to put it on the machine and take it away, what it must raise, its bounds."""

    name: str
    inject: Callable[[Supervisor], None]
    clear: Callable[[Supervisor], None]
    alarm: str  # the alarm id the history must hold
    jet_ticks: int  # the jet is closed within this many ticks of the injection
    stop_ticks: int  # the axes stand still within this many
    process: str = ""  # the process it kills (restarted by the supervisor unless its policy says never)
    # when the controller has learnt of it, for faults it learns of in wall time (None: at once);
    # called with the supervisor and what `_before` read just before the injection
    detected: Callable[[Supervisor, dict], bool] | None = None


@dataclass
class Reaction:
    """What one injection did: ticks to jet off and to standstill, the state reached, the alarm."""

    fault: str
    jet_off_ticks: int
    stopped_ticks: int
    state: str
    alarm: str
    restarted: str = ""
    detect_ms: float | None = None  # virtual clock: wall time until the controller knew (not in the ticks)
    notes: list[str] = field(default_factory=list)


def _kill(name: str) -> Callable[[Supervisor], None]:
    def inject(sup: Supervisor) -> None:
        os.kill(sup.children[name].process.pid, signal.SIGKILL)
    return inject


def _nothing(sup: Supervisor) -> None:
    return None


def _before(sup: Supervisor) -> dict:
    plc = sup.area.reader("plc").read_dict()
    return {"lost_seq": sup.control.get("lost_seq"), "input_seq": plc["input_seq"]}


def _supervisor_noticed(sup: Supervisor, before: dict) -> bool:
    return sup.control.get("lost_seq") > before["lost_seq"] or sup.failed is not None


def _link_lost(sup: Supervisor, before: dict) -> bool:
    return sup.area.reader("plc").read_dict()["state"] == LinkState.LOST


def _pressure_drop_read(sup: Supervisor, before: dict) -> bool:
    """The PLC link has read an input image since the simulated line lost its pressure."""
    if "dropped_at_seq" not in before:
        set_bar = sup.plc_sim.outputs()["pump_pressure_set"]
        if sup.plc_sim.inputs()["pump_pressure"] >= set_bar - sup.config.pump.drop_bar:
            return False
        before["dropped_at_seq"] = sup.area.reader("plc").read_dict()["input_seq"]
    return sup.area.reader("plc").read_dict()["input_seq"] >= before["dropped_at_seq"] + 2


def _plc_fault(name: str, on: bool) -> Callable[[Supervisor], None]:
    return lambda sup: sup.plc_sim.inject(name, on)


def _friction(scale: float) -> Callable[[Supervisor], None]:
    return lambda sup: sup.set_sim(friction_scale=[scale] * len(sup.config.axis_names))


# Bounds in base ticks (1 ms on the shipped machine), from the tick the controller knew of the
# fault: the logic's next scan (every 4 ticks) closes the jet and stops the cut on the path (from
# 50 mm/s at 5 m/s^2 with the jerk limit: some 50 ticks); the servo closes the jet itself on an
# e-stop, a trip or a FIFO run dry (the FIFO holds fifo_high_ms = 40 ms of motion: it takes that
# long to run dry). The board makes the servo's death safe (watchdog), and the supervisor the
# planner's or the logic's in mid-motion (the board's safe state): drives off, the axes coast.
COAST_TICKS = 1000  # drives off (e-stop, servo lost or tripped): the axes coast to rest on the plant's friction


def catalogue() -> list[Fault]:
    """Every fault of issue 9, in the order the tests inject them (the hardware server last: the
    controller cannot run without it)."""
    kills = [
        Fault(f"kill -9 {name}", _kill(name), _nothing, "process_lost", jet, stop, process=name,
              detected=_supervisor_noticed)
        for name, jet, stop in (
            ("gateway", 10, 300), ("logger", 10, 300), ("plc_link", 10, 300), ("planner", 10, COAST_TICKS),
            ("logic", 10, COAST_TICKS), ("servo", 10, COAST_TICKS),
        )
    ]
    others = [
        Fault("e-stop pressed", lambda s: s.set_sim(estop_pressed=1), lambda s: s.set_sim(estop_pressed=0),
              "estop", 2, COAST_TICKS),
        Fault("door opened", lambda s: s.set_sim(doors_open=1), lambda s: s.set_sim(doors_open=0),
              "doors_open", 10, 300),
        Fault("PLC link cut", _plc_fault("link_dead", True), _plc_fault("link_dead", False),
              "plc_link_lost", 10, 300, detected=_link_lost),
        Fault("pump pressure drop", _plc_fault("pump_pressure_drop", True), _plc_fault("pump_pressure_drop", False),
              "pump_pressure_fault", 10, 300, detected=_pressure_drop_read),
        Fault("friction spike (following error)", _friction(400.0), _friction(1.0), "following_error", 50, COAST_TICKS),
        Fault("FIFO starved", lambda s: s.set_sim(planner_stall=1), lambda s: s.set_sim(planner_stall=0),
              "fifo_underrun", 60, 300),
    ]
    return [*others, *kills, Fault("kill -9 hardware", _kill("hardware"), _nothing, "process_lost", 0, 0,
                                   process="hardware", detected=_supervisor_noticed)]


# -- driving the machine ----------------------------------------------------------------------
def logic_block(sup: Supervisor) -> dict:
    return sup.area.reader("logic").read_dict()


def jet_on(sup: Supervisor) -> bool:
    return bool(sup.hw()["digital_out"] & DigitalOut.JET_VALVE)


def ask(sup: Supervisor, msg, what: str, timeout_s: float = 20.0) -> None:
    """Send a command to the control logic until it is accepted (a restarted logic may not answer yet)."""
    reasons: list[str] = []

    def accepted() -> bool:
        try:
            reply = sup.logic.request(msg)
        except Exception as exc:  # noqa: BLE001 - no logic yet: Zenoh's timeout or no route
            reasons.append(str(exc))
            return False
        reasons.append(reply.reason)
        return reply.ok
    try:
        sup.wait_until(accepted, timeout_s, what)
    except TimeoutError as exc:
        raise TimeoutError(f"{exc}: {reasons[-1] if reasons else 'no reply'}") from None


def reset_until_clear(sup: Supervisor, timeout_s: float = 30.0) -> None:
    """The PLC link up, then reset until nothing waits for one and the drives are on: a cause
    that has just gone (a released e-stop, a link that came up late on a busy host) may still be
    seen by the scan that serves the first reset."""
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, timeout_s, "the PLC link")

    def reset_done() -> bool:
        ask(sup, Reset(), "the reset")
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            if not logic_block(sup)["blocking"] and sup.servo()["state"] == ServoState.HOLDING:
                return True
            time.sleep(0.01)
        return False
    sup.wait_until(reset_done, timeout_s, "the reset: drives on, no alarm waiting")


def ready_to_cut(sup: Supervisor, program: Path) -> None:
    """From any state: reset, drives on, homed, the program loaded, AUTO, READY."""
    reset_until_clear(sup)
    if sup.servo()["homed_mask"] != (1 << len(sup.config.axis_names)) - 1:
        ask(sup, Home(), "homing")
    sup.wait_until(lambda: logic_block(sup)["state"] == MachineState.READY
                   and sup.motion()["state"] == PlannerState.IDLE, 60.0, "READY, homed")
    ask(sup, LoadProgram(str(program)), "the program to load")
    ask(sup, SetMode("AUTO"), "AUTO mode")


def start_cut(sup: Supervisor) -> None:
    """Cycle start, then wait until the jet is on and the head moves along the cut."""
    ask(sup, CycleStart(cycles=1), "cycle start")
    sup.wait_until(lambda: logic_block(sup)["phase"] == CyclePhase.CUTTING and jet_on(sup)
                   and sup.servo()["state"] == ServoState.TRACKING, 60.0, "cutting with the jet on")
    tick = sup.hw()["tick"]

    def moving() -> bool:
        hw = sup.hw()
        return hw["tick"] > tick + 100 and hw["tick"] - hw["last_motion_tick"] <= 2 and jet_on(sup)
    sup.wait_until(moving, 30.0, "the head cutting along the frame")


def _history_has(history_path: str, alarm_code: int, after_seq: int) -> bool:
    with AlarmHistory(history_path, readonly=True) as history:
        return any(e.code == alarm_code and e.action == "raised" for e in history.after(after_seq, 1000).entries)


def cutting_now(sup: Supervisor) -> bool:
    """The jet is on and the head moves along the cut."""
    return jet_on(sup) and sup.servo()["state"] == ServoState.TRACKING


def inject_during_cut(sup: Supervisor, fault: Fault, timeout_s: float = 30.0) -> Reaction:
    """Inject `fault` into a running cut (jet on, head moving) and wait for the safe state: jet
    closed, axes still, the alarm raised. For the hardware server the supervisor gives up (its
    policy); the reaction then reads what the board had recorded before it died."""
    assert cutting_now(sup), "inject during a cut"
    code = next(a.code for a in sup.config.alarm if a.id == fault.alarm)
    with AlarmHistory(sup.history_path, readonly=True) as history:
        seq0 = history.last_seq()
    old_pid = sup.children[fault.process].process.pid if fault.process else 0
    before = _before(sup)
    virtual = sup.clock == "virtual"
    t0 = sup.pause_virtual_clock() if virtual else sup.hw()["tick"]
    started = time.monotonic()
    fault.inject(sup)
    detect_ms = None
    if virtual:
        # ticks are not wall time here: what the controller learns of in wall time is waited for
        # with the clock stopped, and reported apart, so that the ticks count the reaction only
        if fault.detected is not None and fault.process != "hardware":  # without it the supervisor gives up
            sup.wait_until(lambda: fault.detected(sup, before), timeout_s, f"the controller to notice {fault.name}")
            detect_ms = (time.monotonic() - started) * 1000.0
        sup.resume_virtual_clock()
    if fault.process == "hardware":
        deadline = time.monotonic() + timeout_s
        while sup.failed is None and time.monotonic() < deadline:
            sup.poll()
            time.sleep(0.002)
        detect_ms = (time.monotonic() - started) * 1000.0
        alarm_seen = _wait_for(lambda: _history_has(sup.history_path, code, seq0), 5.0)
        # no tick source and no board: a real board's own watchdog drops its outputs when the host
        # stops refreshing them; the simulated board (and the machine it simulates) ended with the process
        return Reaction(fault.name, -1, -1, "controller gives up (policy: never restart): exit 1",
                        _alarm_text(sup, code, alarm_seen), "not restarted", detect_ms,
                        notes=[str(sup.failed), f"safe state requested: {sup.control.get('safe_state')}"])

    def safe() -> bool:
        hw = sup.hw()
        return not hw["digital_out"] & DigitalOut.JET_VALVE and hw["tick"] - hw["last_motion_tick"] > STILL_FOR_TICKS
    sup.wait_until(safe, timeout_s, f"the safe state after {fault.name}")
    sup.wait_until(lambda: _history_has(sup.history_path, code, seq0), 10.0, f"alarm {code} ({fault.alarm}) in the history")
    hw = sup.hw()
    restarted = ""
    if fault.process:
        sup.wait_until(lambda: fault.process in sup.children and sup.children[fault.process].process.pid != old_pid
                       and sup.children[fault.process].process.is_alive(), 30.0, f"a new {fault.process} process")
        restarted = f"{fault.process} restarted"
    state = f"{MachineState(logic_block(sup)['state']).name}, servo {ServoState(sup.servo()['state']).name}"
    return Reaction(fault.name, hw["jet_off_tick"] - t0, max(0, hw["last_motion_tick"] - t0), state,
                    _alarm_text(sup, code, True), restarted, detect_ms)


def _wait_for(predicate: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def _alarm_text(sup: Supervisor, code: int, seen: bool) -> str:
    text = next(a.text for a in sup.config.alarm if a.code == code)
    return f"{code} {text}" if seen else f"{code} {text}: NOT in the history"


def recover(sup: Supervisor, fault: Fault, program: Path) -> None:
    """Take the fault away, reset, and start the cut again: the machine goes on."""
    fault.clear(sup)
    ready_to_cut(sup, program)
    start_cut(sup)


def table(reactions: list[Reaction], bounds: dict[str, Fault] | None = None, tick_ms: float = 1.0) -> str:
    """The fault table: fault, jet off and standstill in ticks (and their bounds), the state reached, the alarm."""
    rows = [("fault", "noticed", "jet off", "stopped", "bound", "state reached", "alarm", "supervisor")]
    for r in reactions:
        b = bounds.get(r.fault) if bounds else None
        noticed = "-" if r.detect_ms is None else f"{r.detect_ms:.0f} ms"
        rows.append((r.fault, noticed, _ticks(r.jet_off_ticks), _ticks(r.stopped_ticks),
                     f"{b.jet_ticks}/{b.stop_ticks}" if b and b.jet_ticks else "-", r.state, r.alarm, r.restarted or "-"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.append(f"(jet off, stopped: ticks of {tick_ms:g} ms from the injection, or on the virtual clock from when the"
                 " controller noticed a fault it learns of in wall time ('noticed', not in the ticks); bound: jet/stop ticks)")
    return "\n".join(lines)


def _ticks(n: int) -> str:
    return "-" if n < 0 else str(n)
