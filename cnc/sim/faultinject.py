"""Fault injection on the simulated machine: a fault put on it in the middle of a cut, through the
real processes, and how the machine reached its safe state, read off the board's own record.

Used by the tests (`tests/test_fault_injection.py`) and `bench/faults.py`, and by an integrator
commissioning a machine file on the simulated board. Each `Fault` says how to inject it and take
it away again, the cut it lands in (50 or 500 mm/s), the servo trip that must name it (or none:
the control logic stops the cut, or it is a feed hold), and the alarm the history must hold.
`inject_during_cut` measures one; `recover` takes the fault away, resets, and starts the cut
again to prove the machine goes on without a restart.

What is measured, from the tick the fault was put on the machine (`t0`):
- detect: ticks until the tick that acted on it (the servo's trip tick; the hardware server's
  watchdog tick; for a stop the logic decides, the tick the jet closed);
- jet off: ticks from that tick to the board's jet valve closed (`hw.jet_off_tick`);
- stop: the distance from where the head was at `t0` to where it came to rest (the cut lands on a
  long straight line, so the chord is the path), against the bound
  v T_detect + v^2/(2a) + v a/(2j) + 1 mm (and, for a stop the planner runs along the path, the
  FIFO's lead v * fifo_high_ms); category 0 stops (e-stop, mains) coast: their distance is said.
Faults the controller learns of in wall time (a process dying, the supervisor's poll) count that
in too; on the virtual clock ticks then run on while wall time passes, so their detection ticks
say what the virtual clock did, and the real-time figures are `bench/faults.py`'s.
"""

from __future__ import annotations

import math
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plc_link.sim_model import PlantTimes

from ..alarms import AlarmHistory
from ..brake import stop_distance_bound_mm
from ..bus.keys import Keys
from ..bus.messages import CycleStart, Hold, Override, Resume, Stop, StopAll
from ..bus.operator import OperatorStation
from ..bus.session import open_client
from ..data.layout import ServoFault, ServoState
from ..hw.board import DigitalOut
from ..logic.states import CyclePhase, MachineState
from ..runtime.supervisor import Supervisor
from .operator import ask, logic_block, press_button_when_asked, ready_to_cut, reset_until_clear  # noqa: F401 - the scripted operator, for the tests too

# A long straight first cut (every fault lands on it, far from its end), then a frame.
CUT_PROGRAM = """(fault injection: a long straight cut, then a frame; every fault lands on the straight)
G21 G90 G64 P0.05
G0 X100 Y100
M3
G1 X1100 F{feed:.0f}
G1 Y400
G1 X100
G1 Y100
M5
G0 X60 Y60
M2
"""
INJECT_BEFORE_X = 650.0  # the head is past this on the straight: too late to inject, wait for the next cut
STILL_FOR_TICKS = 200  # the axes stand still when no encoder moved for this long
# A transport system and a pump that are quick about it: faults land in cuts, not in waits.
FAST_PLANT = PlantTimes(feed_s=0.3, gripper_s=0.1, unload_s=0.3, pneumatic_s=0.1, ramp_bar_s=20000.0)
SCENARIO_OVERRIDES = {
    "cycle.transport_procedure": "",  # the cycle skips the guided transport procedure (nobody presses its button)
    "control.program": "fault_injection",  # the PI-P, which fails on request (`cnc.control.examples.faulty`)
    "sim.axes.x.start_position_mm": 30.0, "sim.axes.y.start_position_mm": 30.0,  # the table starts near home
}


def program_path(workdir: Path, speed_mm_s: float) -> Path:
    """The cut program at this speed, written into `workdir` once."""
    path = workdir / f"cut{speed_mm_s:g}.ngc"
    if not path.exists():
        path.write_text(CUT_PROGRAM.format(feed=speed_mm_s * 60.0))
    return path


@dataclass(frozen=True)
class Fault:
    """One fault: how to put it on the machine and take it away, the cut it lands in, what it must raise."""

    name: str
    inject: Callable[[Supervisor], None]
    clear: Callable[[Supervisor], None]
    alarm: str  # the alarm id the history must hold
    speed_mm_s: float  # the cut it lands in
    trip: ServoFault | None = None  # the trip that names it (None: the logic stops the cut; a hold)
    category0: bool = False  # the drives lose their power: the axes coast
    process: str = ""  # the process it kills or hangs (restarted by the supervisor unless its policy says never)
    hold: bool = False  # a feed hold, not a fault: the jet closes at rest and the cut resumes


@dataclass
class Reaction:
    """What one injection did."""

    fault: str
    speed_mm_s: float
    detect_ticks: int
    jet_off_ticks: int  # from the tick that acted (-1: the board could not say: the controller ended)
    stop_mm: float
    bound_mm: float | None  # None: category 0 (coasting), or the controller ended
    state: str
    alarm: str
    restarted: str = ""
    detect_ms: float = 0.0  # wall time from the injection to the tick that acted
    notes: list[str] = field(default_factory=list)


def _kill(name: str, sig: int = signal.SIGKILL) -> Callable[[Supervisor], None]:
    def inject(sup: Supervisor) -> None:
        os.kill(sup.children[name].process.pid, sig)
    return inject


def _nothing(sup: Supervisor) -> None:
    return None


def _plc_fault(name: str, on: bool) -> Callable[[Supervisor], None]:
    return lambda sup: sup.plc_sim.inject(name, on)


def _friction(scale: float) -> Callable[[Supervisor], None]:
    return lambda sup: sup.set_sim(friction_scale=[scale] * len(sup.config.axis_names))


def _override(percent: float) -> Callable[[Supervisor], None]:
    return lambda sup: sup.logic.request(Override(percent))


def _bug(where: str, command) -> Callable[[Supervisor], None]:  # noqa: ANN001 - a command message
    """A bug in the handler `where` ("<process>/<verb>"), met by `command` sent as the commander's
    own station would: the reply must say internal error (else the injection missed)."""
    def inject(sup: Supervisor) -> None:
        sup.set_sim(inject_bug=where)
        if where.startswith("gateway/"):
            reply = _station(sup).request(command)
        else:
            reply = sup.logic.request(command)
        if reply.ok or "internal error" not in reply.reason:
            raise RuntimeError(f"the bug injected into {where} was not met: {reply}")
    return inject


_STATIONS: dict[int, tuple[Any, OperatorStation]] = {}  # per controller: a station holding the lock


def _station(sup: Supervisor) -> OperatorStation:
    """An operator station on the controller's network endpoint, holding the command lock (kept
    until the bug is cleared: its loss would be one more event in the middle of the stop)."""
    if id(sup) not in _STATIONS:
        port = sup.config.zenoh.listen[0].rsplit(":", 1)[1]
        session = open_client([f"tcp/127.0.0.1:{port}"])
        station = OperatorStation(session, Keys(sup.config.zenoh.key_prefix, sup.config.machine.name), "fault-injection")
        _STATIONS[id(sup)] = (session, station)
    station = _STATIONS[id(sup)][1]
    reply = station.take_lock()
    if not reply.ok:
        raise RuntimeError(f"fault injection: the command lock: {reply.reason}")
    return station


def _stop_all(sup: Supervisor) -> None:
    """Stop all from a second station that does not hold the command lock (any station may)."""
    port = sup.config.zenoh.listen[0].rsplit(":", 1)[1]
    session = open_client([f"tcp/127.0.0.1:{port}"])
    try:
        station = OperatorStation(session, Keys(sup.config.zenoh.key_prefix, sup.config.machine.name), "bench-stop-all")
        reply = station.request(StopAll())
        station.close()
    finally:
        session.close()
    if not reply.ok:
        raise RuntimeError(f"stop all was refused: {reply.reason}")


_ASKING: dict[int, threading.Thread] = {}  # per controller: a parameter change on its way


def _control_fault(mode: int) -> Callable[[Supervisor], None]:
    """The fault-injection control program made to fail as `mode` says (1 raise, 2 NaN, 3 over its
    budget, 4 never return; 0 the PI-P again), set online as an engineer tunes a parameter. The
    door answers once the servo applied it, which takes ticks: the request goes on a thread, so
    that the injection returns and the (virtual) clock runs on meanwhile."""
    def inject(sup: Supervisor) -> None:
        station = _station(sup)
        failed: list[str] = []

        def ask_door() -> None:
            reply = station.set_param("control.fault", float(mode))
            if not reply.ok:
                failed.append(reply.reason)

        if id(sup) in _ASKING:
            _ASKING.pop(id(sup)).join()
        if mode == 0:
            ask_door()
            _bug_cleared(sup)
        else:
            _ASKING[id(sup)] = thread = threading.Thread(target=ask_door, name="fault-injection param", daemon=True)
            thread.start()
        if failed:
            raise RuntimeError(f"fault injection: control.fault = {mode}: {failed[0]}")
    return inject


def _bug_cleared(sup: Supervisor) -> None:
    sup.set_sim(inject_bug="")
    if id(sup) in _STATIONS:
        session, station = _STATIONS.pop(id(sup))
        station.close()
        session.close()


def catalogue() -> list[Fault]:
    """Every fault of the issue, in the order the tests inject them (the hardware server last:
    the controller cannot run without it). Those the controller learns of in wall time (through the
    PLC link, a process's death) land in the 50 mm/s cut: on the virtual clock the ticks run ahead
    of the wall meanwhile, and at 50 mm/s the stop still lies on the straight; the tick rig has
    every fault at both speeds (tests/test_safety_matrix.py), bench/faults.py on the real clock."""
    sim = lambda **kw: (lambda s: s.set_sim(**kw))  # noqa: E731
    return [
        Fault("e-stop pressed", sim(estop_pressed=1), sim(estop_pressed=0), "estop", 500.0, ServoFault.ESTOP, True),
        Fault("door opened", sim(doors_open=1), sim(doors_open=0), "doors_open", 500.0, ServoFault.DOORS),
        Fault("light barrier", _plc_fault("barrier_front", True), _plc_fault("barrier_front", False), "barrier_interrupted",
              50.0, ServoFault.BARRIER),
        Fault("hard limit switch", sim(limit_switch_mask=1), sim(limit_switch_mask=0), "hard_limit", 50.0,
              ServoFault.HARD_LIMIT),
        Fault("drive fault (Y)", sim(drive_fault_mask=2), sim(drive_fault_mask=0), "y_drive", 500.0, ServoFault.DRIVE_FAULT),
        Fault("mains loss", sim(mains_off=1), sim(mains_off=0), "mains_off", 50.0, ServoFault.MAINS, True),
        Fault("PLC link cut", _plc_fault("link_dead", True), _plc_fault("link_dead", False), "plc_link_lost", 50.0,
              ServoFault.PLC_LINK),
        Fault("PLC link process hung", _kill("plc_link", signal.SIGSTOP), _nothing, "plc_link_lost", 50.0,
              ServoFault.PLC_LINK, process="plc_link"),
        # the tick or the logic first, whichever reads the PLC's image first (the PLC's own alarm comes with it)
        Fault("pump fault", _plc_fault("pump_fault", True), _plc_fault("pump_fault", False), "pump_pressure_fault", 50.0),
        Fault("pump pressure drop", _plc_fault("pump_pressure_drop", True), _plc_fault("pump_pressure_drop", False),
              "pump_pressure_fault", 50.0),
        Fault("following error (friction x400)", _friction(400.0), _friction(1.0), "following_error", 500.0,
              ServoFault.FOLLOWING_ERROR),
        Fault("FIFO starved (planner stalled)", sim(planner_stall=1), sim(planner_stall=0), "fifo_underrun", 50.0,
              ServoFault.UNDERRUN),
        Fault("override 0 %", _override(0.0), _nothing, "feed_hold", 500.0, hold=True),
        # any operator station, without the command lock: jet off, the servo's stop, then the drives off
        Fault("stop all (software)", _stop_all, _nothing, "stop_all", 500.0),
        Fault("stop all (software), slow", _stop_all, _nothing, "stop_all", 50.0),
        # a bug in a request handler that commands motion (cnc.bus.service): the process's safe state, the
        # internal-error alarm, the door goes on serving; in each process that serves such requests
        Fault("bug in the gateway's override", _bug("gateway/override", Override(100.0)), _bug_cleared, "internal_error",
              500.0),
        Fault("bug in the logic's hold", _bug("logic/hold", Hold()), _bug_cleared, "internal_error", 500.0),
        Fault("bug in the planner's override", _bug("planner/override", Override(100.0)), _bug_cleared, "internal_error",
              500.0),
        # through the processes: a program that raises, and one that never returns (the watchdog's);
        # NaN commands and an overrun take the servo's same path: the tick rig has them in every state
        Fault("control program raises", _control_fault(1), _control_fault(0), "control_program", 500.0,
              ServoFault.CONTROL_PROGRAM),
        Fault("control program never returns", _control_fault(4), _control_fault(0), "watchdog", 50.0,
              ServoFault.RESTARTED, process="servo"),
        Fault("kill -9 gateway", _kill("gateway"), _nothing, "process_lost", 500.0, process="gateway"),
        Fault("kill -9 logger", _kill("logger"), _nothing, "process_lost", 50.0, process="logger"),
        Fault("kill -9 plc_link", _kill("plc_link"), _nothing, "process_lost", 50.0, process="plc_link"),
        # the supervisor sees the planner die before the FIFO runs dry, mostly: the logic's stop, or the underrun's
        Fault("kill -9 planner", _kill("planner"), _nothing, "process_lost", 50.0, process="planner"),
        # a dead or hung logic: the tick's COMMANDER stop after commander_timeout_ms, or (on the virtual clock,
        # where a silent timer client slows the ticks down) the restarted logic's stop first: process_lost either way
        Fault("kill -9 logic", _kill("logic"), _nothing, "process_lost", 500.0, process="logic"),
        # the board is brought to rest by the hardware server (the supervisor's safe state, or the watchdog when the
        # servo stays silent for its ticks first); the restarted servo starts tripped
        Fault("kill -9 servo", _kill("servo"), _nothing, "process_lost", 500.0, ServoFault.RESTARTED, process="servo"),
        Fault("logic hung", _kill("logic", signal.SIGSTOP), _nothing, "process_lost", 50.0, process="logic"),
        Fault("planner hung", _kill("planner", signal.SIGSTOP), _nothing, "fifo_underrun", 500.0, ServoFault.UNDERRUN,
              process="planner"),
        Fault("servo hung", _kill("servo", signal.SIGSTOP), _nothing, "watchdog", 500.0, ServoFault.RESTARTED,
              process="servo"),
        Fault("kill -9 hardware", _kill("hardware"), _nothing, "process_lost", 50.0, process="hardware"),
    ]


# -- driving the machine ----------------------------------------------------------------------
def jet_on(sup: Supervisor) -> bool:
    return bool(sup.hw()["digital_out"] & DigitalOut.JET_VALVE)


def pause_on_the_straight(sup: Supervisor, workdir: Path, speed_mm_s: float, attempts: int = 3) -> None:
    """Cutting the straight at `speed_mm_s`, the virtual clock paused there (a new cut when the one
    under way is not that, or the clock ran past the straight before it stopped); on the real-time
    clock, cutting there now."""
    for _ in range(attempts):
        if not on_the_straight(sup, speed_mm_s):
            if logic_block(sup)["phase"] != CyclePhase.NONE:
                ask(sup, Stop(), "a stop of the cycle under way")
                sup.wait_until(lambda: logic_block(sup)["phase"] == CyclePhase.NONE, 120.0, "the cycle to end")
            ready_to_cut(sup, program_path(workdir, speed_mm_s))
            start_cut(sup, speed_mm_s)
        if sup.clock != "virtual":  # the real clock cannot stop: the fault goes on now
            return
        sup.pause_virtual_clock()
        if on_the_straight(sup, speed_mm_s):
            return
        sup.resume_virtual_clock()
    raise RuntimeError(f"the head was not cruising on the straight at {speed_mm_s:g} mm/s when the clock stopped")


def start_cut(sup: Supervisor, speed_mm_s: float) -> None:
    """Cycle start, then wait until the head cuts along the long straight at `speed_mm_s`. An alarm
    that came up after the reset (the PLC's own, for a CNC heartbeat it missed meanwhile) is reset
    first, as an operator would. A fault before the cut begins (the PLC link lost) ends the wait at
    once with ScriptError saying why (`press_button_when_asked`), not after its time runs out."""
    def started() -> bool:
        reply = sup.logic.request(CycleStart(cycles=1))
        if not reply.ok and "alarms wait for reset" in reply.reason:
            reset_until_clear(sup)
        return reply.ok
    sup.wait_until(started, 60.0, "cycle start")
    press_button_when_asked(sup, lambda: logic_block(sup)["phase"] == CyclePhase.CUTTING and cutting_now(sup), 60.0,
                            "cutting with the jet on")
    sup.wait_until(lambda: on_the_straight(sup, speed_mm_s), 30.0, f"the head cutting at {speed_mm_s:g} mm/s")


def _path_speed(sup: Supervisor) -> float:
    return math.hypot(*sup.servo()["commanded_velocity_mm_s"])


def cutting_now(sup: Supervisor) -> bool:
    """The jet is on and the head moves along the cut."""
    return jet_on(sup) and sup.servo()["state"] == ServoState.TRACKING


def on_the_straight(sup: Supervisor, speed_mm_s: float) -> bool:
    """Cruising along the long straight at `speed_mm_s` (no longer accelerating: a stop that begins
    while accelerating first turns the acceleration round, a longer way than the bound), far enough
    from its end for any stop to stay on it."""
    s = sup.servo()
    return cutting_now(sup) and s["actual_mm"][0] < INJECT_BEFORE_X and s["actual_mm"][1] < 100.5 \
        and abs(_path_speed(sup) - speed_mm_s) <= 0.001 * speed_mm_s


def _history_has(history_path: str, alarm_id: str, after_seq: int) -> bool:
    with AlarmHistory(history_path, readonly=True) as history:
        return any(e.id == alarm_id and e.action == "raised" for e in history.after(after_seq, 1000).entries)


def inject_during_cut(sup: Supervisor, fault: Fault, timeout_s: float = 30.0) -> Reaction:
    """Inject `fault` into a cut on the straight at its speed and wait for the safe state: jet
    closed, axes still, the alarm in the history (a feed hold: held, jet closed). For the hardware
    server the supervisor gives up (its policy); the reaction says what it could."""
    config = sup.config
    with AlarmHistory(sup.history_path, readonly=True) as history:
        seq0 = history.last_seq()
    old_pid = sup.children[fault.process].process.pid if fault.process in sup.children else 0
    virtual = sup.clock == "virtual"
    t0 = (sup.hw()["tick"] if sup.hw()["paused"] else sup.pause_virtual_clock()) if virtual else sup.hw()["tick"]
    if not on_the_straight(sup, fault.speed_mm_s):
        raise RuntimeError(f"{fault.name}: the head is not cruising on the straight at {fault.speed_mm_s:g} mm/s")
    servo0 = sup.servo()
    p0, v0, trips0 = list(servo0["actual_mm"]), _path_speed(sup), servo0["trip_seq"]
    started = time.monotonic()
    fault.inject(sup)
    if sup.clock == "virtual":
        sup.resume_virtual_clock()
    if fault.process == "hardware":
        deadline = time.monotonic() + timeout_s
        while sup.failed is None and time.monotonic() < deadline:
            sup.poll()
            time.sleep(0.002)
        seen = _wait_for(lambda: _history_has(sup.history_path, fault.alarm, seq0), 5.0)
        # no tick source and no board: a real board's own output watchdog drops its outputs when the
        # host stops refreshing them; the simulated board (and the machine it simulates) ended with the process
        return Reaction(fault.name, v0, -1, -1, 0.0, None, "controller gives up (policy: never restart): exit 1",
                        _alarm_text(config, fault.alarm, seen), "not restarted", (time.monotonic() - started) * 1e3,
                        notes=[str(sup.failed)])

    def safe() -> bool:
        hw = sup.hw()
        still = not hw["digital_out"] & DigitalOut.JET_VALVE and hw["tick"] - hw["last_motion_tick"] > STILL_FOR_TICKS
        return still and (fault.hold or sup.servo()["state"] in (ServoState.FAULT, ServoState.HOLDING, ServoState.DISABLED))
    sup.wait_until(safe, timeout_s, f"the safe state after {fault.name}")
    sup.wait_until(lambda: _history_has(sup.history_path, fault.alarm, seq0), 15.0, f"alarm {fault.alarm} in the history")
    hw, servo = sup.hw(), sup.servo()
    # the first reaction: the servo's trip, the watchdog, or (a stop the logic decides, a hold at rest)
    # the jet closing, which the tick before decided
    reactions = [hw["jet_off_tick"] - 1] if hw["jet_off_tick"] > t0 else []
    stops = []  # the stop itself: the hardware server's ramp, the servo's own stop (a trip's, or the logic's)
    if fault.process == "servo":  # the hardware server's ramp: the watchdog's tick, or the supervisor's safe state
        ramp = [t for t in (hw["watchdog_trip_tick"], hw["jet_off_tick"] - 1) if t > t0]
        stops.append(min(ramp) if ramp else hw["tick"])
    elif servo["brake_tick"] > t0:
        stops.append(servo["brake_tick"])
    elif servo["trip_seq"] > trips0 and servo["fault"]:
        stops.append(servo["fault_tick"])
    acted = min(reactions + stops) if reactions or stops else hw["tick"]
    stop_from = stops[0] if stops else acted  # a hold: the planner decelerates on the path from about then
    stop_mm = math.dist(p0, servo["actual_mm"])
    detect = max(0, acted - t0)
    a, j = min(x.max_accel_mm_s2 for x in config.axes), min(x.max_jerk_mm_s3 for x in config.axes)
    bound = None
    if not fault.category0:
        bound = stop_distance_bound_mm(v0, max(0, stop_from - t0) * config.timing.period_s, a, j)
        if fault.hold:  # the planner's hold on the path runs out the FIFO's lead first
            bound += v0 * config.planner.fifo_high_ms / 1000.0
    restarted = ""
    if fault.process:
        sup.wait_until(lambda: fault.process in sup.children and sup.children[fault.process].process.pid != old_pid
                       and sup.children[fault.process].process.is_alive(), 30.0, f"a new {fault.process} process")
        restarted = f"{fault.process} restarted"
    trip = ServoFault(sup.servo()["trip_fault"]).name if sup.servo()["trip_seq"] > trips0 else "-"
    state = f"{MachineState(logic_block(sup)['state']).name}, servo {ServoState(sup.servo()['state']).name}, trip {trip}"
    jet_ticks = hw["jet_off_tick"] - acted if hw["jet_off_tick"] > t0 else -1
    return Reaction(fault.name, v0, detect, jet_ticks, stop_mm, bound, state, _alarm_text(config, fault.alarm, True),
                    restarted, (time.monotonic() - started) * 1e3)


def _wait_for(predicate: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def _alarm_text(config, alarm_id: str, seen: bool) -> str:  # noqa: ANN001 - a MachineConfig
    entry = next(a for a in config.alarm if a.id == alarm_id)
    return f"{entry.code} {entry.text}" if seen else f"{entry.code} {entry.text}: NOT in the history"


def recover(sup: Supervisor, fault: Fault, workdir: Path, speed_mm_s: float) -> None:
    """Take the fault away, reset, and start the cut again: the machine goes on."""
    fault.clear(sup)
    seq = sup.area.reader("plc").read_dict()["input_seq"]  # the PLC's image after the clear: two exchanges on
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["input_seq"] >= seq + 2, 30.0, "the PLC's next images")
    if fault.hold:  # the cut goes on: resume pierces again where the jet stopped
        ask(sup, Override(100.0), "the feed override back to 100 %")
        ask(sup, Resume(), "resume after the hold")
        sup.wait_until(lambda: cutting_now(sup), 30.0, "the cut going on after the hold")
        return
    ready_to_cut(sup, program_path(workdir, speed_mm_s))
    start_cut(sup, speed_mm_s)


def table(reactions: list[Reaction]) -> str:
    """The fault table: detection, jet off, stop distance against its bound, the state reached, the alarm."""
    rows = [("fault", "v mm/s", "detect", "jet off", "stop mm", "bound mm", "state reached", "alarm", "supervisor")]
    for r in reactions:
        bound = "coast (cat. 0)" if r.bound_mm is None and r.jet_off_ticks >= 0 else (
            "-" if r.bound_mm is None else f"{r.bound_mm:.2f}")
        rows.append((r.fault, f"{r.speed_mm_s:.0f}", _ticks(r.detect_ticks), _ticks(r.jet_off_ticks),
                     f"{r.stop_mm:.2f}" if r.jet_off_ticks >= 0 else "-", bound, r.state, r.alarm, r.restarted or "-"))
    lines = text_table(rows)
    lines.append("(detect: ticks from the injection to the tick that acted; jet off: ticks from that tick to the jet "
                 "valve closed; bound: v T_detect + v^2/2a + v a/2j + 1 mm, plus the FIFO's lead for a stop the "
                 "planner runs)")
    return "\n".join(lines)


def text_table(rows: list[tuple[str, ...]]) -> list[str]:
    """Rows of text in columns as wide as their widest cell, the first row a heading ruled off."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return lines


def _ticks(n: int) -> str:
    return "-" if n < 0 else str(n)
