"""Control logic (the soft-PLC): modes, machine state, commands, interlocks, alarms, procedures and
the automatic cycle, scanned every `[timing] logic_divisor` base ticks.

It is the machine's commander: the only writer of the `command` block (drives, fault reset, the
outputs it inhibits or forces), of the PLC's output image and of the alarm history, and the
only process that asks the planner to move in normal operation. Each scan reads one snapshot
of the blocks, serves the commands that arrived, evaluates the interlocks, steps the
automatic cycle and the guided procedure, and publishes what changed. It never waits: the
planner is asked without blocking (`PlannerLink`), and answers are acted on in a later scan.

Interlocks: e-stop, doors, safety barriers, drive faults, servo trips, the PLC link and the
pump raise their alarms; an alarm that stops the cut (fatal or error) closes the jet at once
(`output_inhibit`, applied by the servo within a tick), then stops the motion under control
along the path (the planner's stop), aborts the cycle and leaves the PLC's transport outputs
off. Such alarms latch until the operator resets them, and the reset is refused, alarm by
alarm, while their cause is present.
"""

from __future__ import annotations

import logging
import os
import time
from typing import Any, Callable

import msgspec
import zenoh

from ..alarms import AlarmBook, AlarmHistory, AlarmLevel, Catalogue
from ..bus.keys import Keys
from ..bus.messages import (
    LOGIC_COMMANDS, AlarmEvent, GoTo, Home, Jog, JogStop, LoadProgram, Override, Reply, Resume, SchemaVersionError,
    Stop, decode, encode,
)
from ..config import CONTROLLER_ALARM_IDS, MachineConfig
from ..dataserver import SharedArea
from ..hw.board import AxisIn, DigitalOut
from ..jobs import JobHistory, jobs_path
from ..layout import HIST_BINS, ClockKind, LinkState, PlannerState, Proc, RunResult, ServoFault, ServoState
from .cycle import AutoCycle
from .procedures import ProcedureRefused, ProcedureRunner
from .requests import PlannerLink
from .signals import PlcOutputs, SignalReader, Snapshot
from .states import CyclePhase, MachineState, Mode

log = logging.getLogger(__name__)

JET_BITS = int(DigitalOut.JET_VALVE | DigitalOut.ABRASIVE)
_SERVO_ALARMS = {
    ServoFault.FOLLOWING_ERROR: "following_error", ServoFault.SOFT_LIMIT: "soft_limit",
    ServoFault.HARD_LIMIT: "hard_limit", ServoFault.WATCHDOG: "watchdog",
    ServoFault.RESTARTED: "process_lost", ServoFault.SAFE_STATE: "process_lost",
}
_MANUAL_MOTION = (PlannerState.JOGGING, PlannerState.MOVING)
PLC_RESET_PULSE_S = 0.5  # how long the PLC's reset coil stays on: several link cycles
DEFERRED = "deferred"  # a command handler's answer: the reply follows when the planner has answered


class Refused(Exception):
    """A command the current mode or state does not allow; the message says why."""


class Logic:
    """The soft-PLC's state and work; `run()` is its loop, `scan()` one pass."""

    def __init__(
        self, config: MachineConfig, area: SharedArea, session: zenoh.Session, timer: Any, history_path: str,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config, self.area, self.session, self.timer, self.clock = config, area, session, timer, clock
        self.keys = Keys(config.zenoh.key_prefix, config.machine.name)
        self.names = config.axis_names
        self.reader = SignalReader(config, area)
        self.outputs = PlcOutputs(config, area)
        self.command = area.writer("command")
        self.command.load_current()
        self.out = area.writer("logic")
        self.out.load_current()
        self.shutdown = area.blocks["supervisor"].array["shutdown"]
        self.supervisor = area.reader("supervisor")
        hb = area.blocks["heartbeat"].array[0]
        self.beat = hb["beat"]
        hb["pid"][Proc.LOGIC] = os.getpid()
        self.scan_hist = area.blocks["logic_scan"].array
        self.wake_hist = area.blocks["logic_wake"].array
        self.alarm_pub = session.declare_publisher(
            self.keys.event_alarm, encoding=zenoh.Encoding.APPLICATION_JSON,
            congestion_control=zenoh.CongestionControl.BLOCK, priority=zenoh.Priority.INTERACTIVE_HIGH, express=True,
        )
        self.procedure_pub = session.declare_publisher(
            self.keys.procedure, encoding=zenoh.Encoding.APPLICATION_JSON, congestion_control=zenoh.CongestionControl.BLOCK
        )
        missing = [i for i in CONTROLLER_ALARM_IDS if i not in {a.id for a in config.alarm}]
        if missing:
            raise ValueError(f"{config.source}: the control logic needs an [[alarm]] catalogue with: {', '.join(missing)}")
        self.history = AlarmHistory(history_path)
        self.book = AlarmBook(Catalogue(config), self.history, publish=self._publish_alarm)
        self.book.prune(config.logic.history_keep_days)
        self.procedures = ProcedureRunner(
            config.procedure, raise_alarm=self._procedure_alarm, known_signals=self.reader.known(), source=config.source
        )
        self.planner = PlannerLink(session, self.keys)
        self.cycle = AutoCycle(self)
        self.queryables = {verb: session.declare_queryable(self.keys.logic(verb)) for verb in LOGIC_COMMANDS}
        self.q_active = session.declare_queryable(self.keys.alarms_active)
        self.jobs = JobHistory(jobs_path(history_path))
        self.run_seen = (-1, -1)  # (run_seq, run_result) of the last run recorded or seen starting
        self.run_started_ns = 0
        self.token = session.liveliness().declare_token(self.keys.alive("logic"))
        self.mode = Mode.MANUAL
        self.state = MachineState.IDLE
        self.jet_test = False
        self.pump_reached = False  # the pressure reached its set point since the last change
        self.reached_bar = 0.0  # the last set point the pressure reached (0: none since the pump started)
        self.set_changed_at = 0.0
        self.plc_reset_until = 0.0
        self.heartbeat = 0
        self.last_event_seq = -1
        self.last_error_seq = -1
        self.message = ""
        self.last_scan_ns = 0
        self.snap: Snapshot | None = None
        # ids of the interlock and prompt alarms whose cause is present: raised on the rising edge,
        # cleared on the falling one (a restarted logic picks up what the history says is active)
        self.present: set[str] = {a.id for a in self.book.active().alarms if a.active}
        self.drives_wanted = bool(self.command.get("servo_enable"))
        self.inhibit = int(self.command.get("output_inhibit"))
        self._set(mode=int(self.mode), state=int(self.state), alarm_seq=self.book.last_seq, alarm_level=-1)
        self._publish_procedure()

    # -- the loop ---------------------------------------------------------------------------
    def run(self) -> None:
        my_bit = 1 << Proc.LOGIC
        hw = self.area.reader("hw")
        while not self.shutdown[0] & my_bit:
            woke = self.timer.wait_tick(0.02)
            if woke:
                while self.timer.wake.acquire(False):
                    pass
                image = hw.read_dict()
                if image["clock_kind"] != ClockKind.VIRTUAL:  # virtual ticks have no deadline in wall time
                    self._record(self.wake_hist, time.monotonic_ns() - image["tick_time_ns"])
            try:
                self.scan()
            except Exception as exc:  # a bug: make the machine safe, say so, keep scanning
                log.exception("control logic: scan failed")
                self._internal_error(exc)
            finally:
                if woke:
                    self.timer.tick_done()
            self.beat[Proc.LOGIC] += 1

    def scan(self) -> None:
        """One pass: snapshot, commands, interlocks, cycle, procedure, outputs."""
        t0 = time.perf_counter_ns()
        now = self.clock()
        snap = self.snap = self.reader.snapshot()
        self.planner.poll()
        self._serve_commands(snap, now)
        self._serve_queries()
        signals = self.reader.signals(snap, self.state.name, self.mode.name)
        self._interlocks(snap, signals)
        self._losses(snap)
        self._program_events(snap)
        self._record_jobs(snap)
        self.cycle.step(snap, now)
        if self.procedures.scan(signals, now):
            self._publish_procedure()
        self._prompts(snap, signals)
        self._pump(snap)
        self._derive_state(snap)
        self._write_outputs(now)
        self._put(scans=self.out.get("scans") + 1, scan_us=self.last_scan_ns // 1000)
        self.out.publish()
        self.last_scan_ns = time.perf_counter_ns() - t0
        self._record(self.scan_hist, self.last_scan_ns)

    def close(self) -> None:
        for q in (*self.queryables.values(), self.q_active):
            q.undeclare()
        self.jobs.close()
        self.alarm_pub.undeclare()
        self.procedure_pub.undeclare()
        self.token.undeclare()
        self.history.close()

    # -- commands ---------------------------------------------------------------------------
    def _serve_commands(self, snap: Snapshot, now: float) -> None:
        for verb, queryable in self.queryables.items():
            while (query := queryable.try_recv()) is not None:
                reply = self._answer(verb, query, snap, now)
                if reply is not None:  # None: answered later, when the planner has answered
                    _reply(query, reply)

    def _answer(self, verb: str, query, snap: Snapshot, now: float) -> Reply | None:
        try:
            msg = decode(query.payload.to_bytes() if query.payload is not None else b"{}", LOGIC_COMMANDS[verb])
        except (msgspec.ValidationError, msgspec.DecodeError, SchemaVersionError) as exc:
            return Reply(False, f"{verb}: malformed command: {exc}")
        try:
            result = getattr(self, f"_cmd_{verb}")(msg, snap, now, query)
        except Refused as exc:
            self._note(f"{verb} refused: {exc}")
            return Reply(False, f"{verb}: {exc}")
        if result == DEFERRED:
            return None
        return result if result is not None else Reply(True)

    def _forward(self, command, query, then: Callable[[Reply], None] | None = None, timeout_s: float | None = None) -> str:
        """Ask the planner; the operator's query is answered with the planner's reply."""
        def on_reply(reply: Reply) -> None:
            if then is not None:
                then(reply)
            if not reply.ok:
                self._note(reply.reason)
            _reply(query, reply)
        self.planner.send(command, on_reply, timeout_s)
        return DEFERRED

    def _require_mode(self, mode: Mode, what: str) -> None:
        if self.mode != mode:
            self._tell("wrong_mode", f"{what} needs {mode.name} mode (the machine is in {self.mode.name})", "logic")
            raise Refused(f"wrong operation mode: {what} needs {mode.name} (mode is {self.mode.name})")

    def _require_no_blocking(self, what: str) -> None:
        if self.book.blocking():
            alarms = ", ".join(f"{a.code} {a.text}" for a in self.book.active().alarms if _stops(a.level))
            raise Refused(f"cannot {what} while alarms wait for reset: {alarms}")

    def _require_still(self, what: str) -> None:
        if self.state in (MachineState.RUNNING, MachineState.HOLD, MachineState.HOMING, MachineState.JOGGING):
            raise Refused(f"cannot {what} while {self.state.name}")

    def _cmd_mode(self, msg, snap, now, query) -> None:
        try:
            mode = Mode[msg.mode.upper()]
        except KeyError:
            raise Refused(f"mode {msg.mode!r} is not one of: {', '.join(m.name for m in Mode)}") from None
        if mode != self.mode:
            self._require_still("change the operation mode")
            if self.jet_test:
                raise Refused("cannot change the operation mode during a jet test")
            self.mode = mode

    def _cmd_start(self, msg, snap, now, query) -> None:
        self._require_mode(Mode.AUTO, "cycle start")
        if msg.cycles < 0:
            raise Refused(f"cycles {msg.cycles} must be 0 (until stopped) or more")
        self._require_no_blocking("start")
        if self.state not in (MachineState.READY, MachineState.STOPPED):
            raise Refused(f"cannot start while {self.state.name}" + (
                ": switch the drives on and home the machine" if self.state == MachineState.IDLE else ""))
        if not snap.motion["program_name"]:
            raise Refused("no program is loaded")
        if self.procedures.running:
            raise Refused(f"a procedure is running ({self.procedures.state().title}): end it first")
        self.inhibit = 0
        self.cycle.start(msg.cycles, now)

    def _cmd_hold(self, msg, snap, now, query) -> str | None:
        if msg.why and "operator_lost" in self.book.catalogue:
            self._tell("operator_lost", msg.why[:200], "gateway")
        if self.cycle.active and not self.cycle.held:
            self.cycle.hold(now)
            return None
        if snap.motion["state"] in _MANUAL_MOTION:
            return self._forward(Stop(), query)
        raise Refused(f"nothing to hold ({self.state.name})")

    def _cmd_resume(self, msg, snap, now, query) -> str | None:
        self._require_no_blocking("resume")
        if self.cycle.held:
            self.cycle.resume(now)
            return None
        if self.cycle.active and snap.motion["state"] == PlannerState.PAUSED:
            return self._forward(Resume(), query)  # a program stop (M0/M1): cycle start continues
        raise Refused(f"nothing to resume ({self.state.name})")

    def _cmd_stop(self, msg, snap, now, query) -> str | None:
        if self.cycle.active:
            self.cycle.stop()
            return None
        if snap.motion["state"] in (*_MANUAL_MOTION, PlannerState.HOMING):
            return self._forward(Stop(), query)
        raise Refused("nothing to stop")

    def _cmd_reset(self, msg, snap, now, query) -> Reply:
        """Reset: servo and watchdog faults, the PLC's faults, then every alarm whose cause has gone."""
        self.command.set("reset_seq", self.command.get("reset_seq") + 1)
        self.inhibit = 0
        self.plc_reset_until = now + PLC_RESET_PULSE_S
        self.drives_wanted = True
        # alarms latched by the servo go with its reset (it re-trips, and they come back, if the cause persists)
        for fault_alarm in {*_SERVO_ALARMS.values()} & self.present:
            self.present.discard(fault_alarm)
            self.book.clear(fault_alarm)
        if self.cycle.stopped:
            self.cycle.stopped = False
        still = self.book.reset()
        if still:
            return Reply(True, "reset; still present: " + ", ".join(f"{a.code} {a.text}" for a in still))
        return Reply(True)

    def _cmd_drives(self, msg, snap, now, query) -> None:
        if msg.on:
            self._require_no_blocking("switch the drives on")
        else:
            self._require_still("switch the drives off")
        self.drives_wanted = msg.on

    def _cmd_home(self, msg: Home, snap, now, query) -> str:
        self._require_mode(Mode.MANUAL, "homing")
        self._require_no_blocking("home")
        return self._forward(msg, query)

    def _cmd_jog(self, msg: Jog, snap, now, query) -> str:
        self._require_mode(Mode.MANUAL, "jog")
        self._require_no_blocking("jog")
        return self._forward(msg, query)

    def _cmd_jog_stop(self, msg: JogStop, snap, now, query) -> str:
        return self._forward(msg, query)

    def _cmd_goto(self, msg: GoTo, snap, now, query) -> str:
        self._require_mode(Mode.MANUAL, "go to position")
        self._require_no_blocking("move")
        return self._forward(msg, query)

    def _cmd_load(self, msg: LoadProgram, snap, now, query) -> str:
        if self.cycle.phase == CyclePhase.CUTTING:
            raise Refused("cannot load a program while cutting: it is taken between cycles")
        return self._forward(msg, query, timeout_s=self.config.planner.load_timeout_s)

    def _cmd_override(self, msg: Override, snap, now, query) -> str:
        return self._forward(msg, query)

    def _cmd_pump(self, msg, snap, now, query) -> None:
        self._require_mode(Mode.MANUAL, "pump on/off")
        if msg.on:
            self._require_no_blocking("start the pump")
            bar = self.config.pump.cut_pressure_bar if msg.pressure_bar is None else msg.pressure_bar
            if not 0.0 <= bar <= self.config.pump.cut_pressure_bar:
                raise Refused(f"pressure_bar {bar:g} is out of range: 0 to {self.config.pump.cut_pressure_bar:g} bar")
            if not self.outputs.has("pump_on"):
                raise Refused("this machine's PLC map has no pump_on output")
            self._set_pump(True, bar)
        else:
            if self.jet_test:
                raise Refused("close the jet (jet test off) before stopping the pump")
            self._set_pump(False, 0.0)

    def _cmd_jet_test(self, msg, snap, now, query) -> None:
        if not msg.on:
            self.jet_test = False
            return
        self._require_mode(Mode.MANUAL, "jet test")
        self._require_no_blocking("open the jet")
        if snap.servo["state"] != ServoState.HOLDING:
            raise Refused("the jet test needs the drives on and the axes at rest")
        need = self.config.pump.pierce_pressure_bar - self.config.pump.tolerance_bar
        pressure = self.reader.plc_value(snap, "pump_pressure")
        if pressure < need:
            raise Refused(f"the pump is at {pressure:.0f} bar; the jet test needs at least {need:.0f} bar")
        self.jet_test = True

    def _cmd_acknowledge(self, msg, snap, now, query) -> None:
        if msg.code is not None and not any(a.code == msg.code for a in self.book.active().alarms):
            raise Refused(f"alarm {msg.code} is not active")
        self.book.acknowledge(msg.code)

    def _cmd_procedure_start(self, msg, snap, now, query) -> None:
        self._procedure_call(lambda: self.procedures.start(msg.id))

    def _cmd_procedure_confirm(self, msg, snap, now, query) -> None:
        self._procedure_call(self.procedures.confirm)

    def _cmd_procedure_stop(self, msg, snap, now, query) -> None:
        self._procedure_call(self.procedures.stop)

    def _cmd_procedure_end(self, msg, snap, now, query) -> None:
        self._procedure_call(self.procedures.end)

    def _procedure_call(self, call: Callable[[], Any]) -> None:
        try:
            call()
        except ProcedureRefused as exc:
            raise Refused(str(exc)) from None
        self._publish_procedure()

    # -- what the cycle needs (CycleHost) ---------------------------------------------------
    def plc(self, snap: Snapshot, var_id: str) -> float:
        return self.reader.plc_value(snap, var_id)

    def send_planner(self, command, on_reply=None) -> None:
        self.planner.send(command, on_reply)

    def fault(self, alarm_id: str, detail: str) -> None:
        """An event that stops the cut (a timeout, a refused program): latched until reset."""
        self._latch(alarm_id, detail, "logic")
        self._safe_stop(f"{alarm_id}: {detail}")

    def _latch(self, alarm_id: str, detail: str, source: str) -> None:
        """Raise an alarm whose cause is an event, not a lasting condition: it stays listed until reset."""
        self.book.raise_(alarm_id, detail, source)
        self.book.clear(alarm_id, detail)

    def notice(self, alarm_id: str, detail: str) -> None:
        self._tell(alarm_id, detail, "logic")

    def _tell(self, alarm_id: str, detail: str, source: str) -> None:
        """An info entry is a one-shot message; anything graver is latched until reset."""
        if alarm_id not in self.book.catalogue:
            log.warning("logic: %s (%s): no such alarm in the catalogue", alarm_id, detail)
        elif self.book.catalogue.entry(alarm_id).level == AlarmLevel.INFO:
            self.book.message(alarm_id, detail, source)
        else:
            self._latch(alarm_id, detail, source)

    def start_procedure(self, procedure_id: str) -> str:
        try:
            if self.procedures.running:
                self.procedures.stop()
            self.procedures.start(procedure_id, by_cycle=True)
        except ProcedureRefused as exc:
            return str(exc)
        self._publish_procedure()
        return ""

    def procedure_outcome(self, procedure_id: str) -> str:
        st = self.procedures.state()
        if st.id != procedure_id:
            return "idle"
        return st.state

    # -- interlocks -------------------------------------------------------------------------
    def _interlocks(self, snap: Snapshot, signals: dict[str, object]) -> None:
        for alarm_id, detail in self._conditions(snap, signals).items():
            if self._edge(alarm_id, detail) and self.book.catalogue.entry(alarm_id).level.stops_cut:
                self._safe_stop(f"{alarm_id}: {detail}")

    def _edge(self, alarm_id: str, detail: str | None) -> bool:
        """Raise when the cause appears, clear when it goes; True on the rising edge."""
        if detail is None:
            if alarm_id in self.present:
                self.present.discard(alarm_id)
                self.book.clear(alarm_id)
            return False
        if alarm_id in self.present:
            return False
        self.present.add(alarm_id)
        self.book.raise_(alarm_id, detail, "logic")
        return True

    def _conditions(self, snap: Snapshot, signals: dict[str, object]) -> dict[str, str | None]:
        """Each interlock alarm id: the detail of its cause when present, None when absent."""
        hw, servo, plc = snap.hw, snap.servo, snap.plc
        has_plc = bool(self.config.plc.var)
        link_ok = snap.link_ok
        cutting = self.cycle.phase == CyclePhase.CUTTING
        running = self.cycle.active and not self.cycle.held
        c: dict[str, str | None] = {}
        estop = []
        if not signals["din.estop_ok"]:
            estop.append("e-stop circuit open at the controller")
        if link_ok and signals.get("plc.safety_circuit_ok") is False:
            estop.append("the PLC reports the safety circuit open")
        c["estop"] = "; ".join(estop) or None
        c["doors_open"] = None if signals["din.doors_closed"] else "a safety door is open"
        for i, name in enumerate(self.names):
            if f"{name}_drive" in self.book.catalogue:
                ready = hw["axis_inputs"][i] & AxisIn.DRIVE_READY
                c[f"{name}_drive"] = None if ready else f"the {name.upper()} drive is not ready"
        # a fault the servo still shows while it has not acted on our reset is the one just reset
        reset_pending = servo["reset_seq"] != self.command.get("reset_seq")
        fault = ServoFault(servo["fault"]) if servo["state"] == ServoState.FAULT and not reset_pending else ServoFault.NONE
        for f, alarm_id in _SERVO_ALARMS.items():
            if c.get(alarm_id) is None:
                c[alarm_id] = self._servo_detail(servo) if fault == f else None
        if has_plc:
            c["plc_link_lost"] = None if link_ok or plc["state"] == LinkState.CONNECTING and not plc["losses"] else (
                f"no answer from the PLC for {self.config.plc.lost_after_cycles} exchanges" if plc["losses"]
                else "the PLC link is down: " + (plc["error"] or "not started"))
            plc_alarm = int(self.reader.plc_value(snap, "plc_alarm"))
            stopped = link_ok and signals.get("plc.plc_running") is False
            c["plc_error"] = (f"PLC alarm {plc_alarm}" if plc_alarm else "the PLC is not in automatic operation" if stopped
                              and self.cycle.active else None)
            c["pump_pressure_fault"] = self._pump_fault(snap, signals, cutting)
            barriers = [b for b in ("front", "rear") if link_ok and signals.get(f"plc.barrier_{b}_ok") is False]
            c["barrier_interrupted"] = f"{' and '.join(barriers)} barrier interrupted" if barriers and running else None
        return {k: v for k, v in c.items() if k in self.book.catalogue}

    def _losses(self, snap: Snapshot) -> None:
        """A controller process lost (the supervisor says which and how) or the setpoint FIFO run
        dry during a motion (the servo has closed the jet already): latched, and the cut stops.
        The counts seen live in the logic's block, so a restarted logic reports what its
        predecessor could not: its own death among them."""
        sup = self.supervisor.read_dict()
        if sup["lost_seq"] > self.out.get("lost_seen"):
            self._put(lost_seen=sup["lost_seq"])
            what = f"{Proc(sup['lost_proc']).name.lower()} process {sup['lost_why']}"
            self.fault("process_lost", what + ("; restarted" if sup["lost_restarted"] else "; not restarted"))
        dry_at = snap.servo["underrun_tick"]
        if dry_at > self.out.get("underrun_seen"):
            self._put(underrun_seen=dry_at)
            if "fifo_underrun" in self.book.catalogue:
                self.fault("fifo_underrun", f"the servo found the FIFO empty at tick {dry_at} during a motion: "
                                            "the jet closed, the axes held")

    def _servo_detail(self, servo: dict) -> str:
        axis = servo["fault_axis"]
        where = f" on axis {self.names[axis].upper()}" if 0 <= axis < len(self.names) else ""
        value = f" ({servo['fault_value']:.3f})" if servo["fault_value"] else ""
        return f"servo tripped: {ServoFault(servo['fault']).name}{where}{value}"

    def _pump_fault(self, snap: Snapshot, signals: dict[str, object], cutting: bool) -> str | None:
        if signals.get("plc.pump_fault"):
            return "the pump reports a fault"
        if not (cutting and snap.jet_on):
            return None
        pump = self.config.pump
        pressure = self.reader.plc_value(snap, "pump_pressure")
        set_bar = self.outputs.get("pump_pressure_set")
        floor = set_bar if self.pump_reached else self.reached_bar
        if floor and pressure < floor - pump.drop_bar:
            return f"pressure fell to {pressure:.0f} bar while cutting at {floor:.0f} bar"
        if not self.pump_reached and self.clock() - self.set_changed_at > pump.ramp_timeout_s:
            return f"the pump did not reach {set_bar:.0f} bar within {pump.ramp_timeout_s:g} s while cutting"
        return None

    def _safe_stop(self, why: str) -> None:
        """Jet off first (the servo drops the bits within a tick), then a controlled stop on the path."""
        self.inhibit = JET_BITS
        self.jet_test = False
        if self.snap is not None and self.snap.motion["state"] not in (PlannerState.IDLE,):
            self.planner.send(Stop())
        if self.cycle.active:
            self.cycle.abort()
        if self.present & {"pump_pressure_fault", "estop"}:
            self._set_pump(False, 0.0)
        self._note(f"safe stop: {why}")

    def _internal_error(self, exc: BaseException) -> None:
        try:
            self.fault("internal_error", f"control logic: {exc!r}")
            self._write_outputs(self.clock())
        except Exception:
            log.exception("control logic: could not even report the internal error")

    def _program_events(self, snap: Snapshot) -> None:
        m = snap.motion
        if self.last_error_seq < 0:
            self.last_error_seq, self.last_event_seq = m["error_seq"], m["event_seq"]
            return
        if m["error_seq"] != self.last_error_seq:
            self.last_error_seq = m["error_seq"]
            if m["error"]:
                self._tell("program_error", m["error"], "planner")
        if m["event_seq"] != self.last_event_seq:
            self.last_event_seq = m["event_seq"]
            if m["event"]:
                self._tell("program_message", m["event"], "planner")

    def _prompts(self, snap: Snapshot, signals: dict[str, object]) -> None:
        """The paper's operator prompts: 2842 press button, 2841 press start button."""
        st = self.procedures.state()
        waiting_button = (self.procedures.running and 0 <= st.step < len(st.steps)
                          and "button" in st.steps[st.step].text.lower())
        self._prompt("press_button", "the procedure waits for the transport-station button" if waiting_button else None)
        ready = self.mode == Mode.AUTO and self.state in (MachineState.READY, MachineState.STOPPED) and bool(
            snap.motion["program_name"]) and not self.cycle.active
        self._prompt("press_start", "the machine is ready for cycle start" if ready else None)

    def _prompt(self, alarm_id: str, detail: str | None) -> None:
        if alarm_id in self.book.catalogue:
            self._edge(alarm_id, detail)

    # -- pump, state, outputs ---------------------------------------------------------------
    def _set_pump(self, on: bool, bar: float) -> None:
        self.outputs.set("pump_on", int(on))
        self.outputs.set("pump_pressure_set", bar if on else 0.0)

    def _pump(self, snap: Snapshot) -> None:
        """Follow the pressure: reached the set point yet, and the last set point it reached (a
        drop below that while cutting is a fault, even while ramping to a new set point)."""
        set_bar = self.outputs.get("pump_pressure_set")
        if not self.outputs.get("pump_on"):
            self.reached_bar = 0.0
        if set_bar != getattr(self, "_last_set_bar", None):
            self._last_set_bar, self.pump_reached, self.set_changed_at = set_bar, False, self.clock()
            # lowered on purpose (low pressure for the next pierce), the pressure may fall as far as the
            # new set point, and rise from there when the cutting pressure follows before it got there
            self.reached_bar = min(self.reached_bar, set_bar)
        elif not self.pump_reached and self.outputs.get("pump_on"):
            pressure = self.reader.plc_value(snap, "pump_pressure")
            self.pump_reached = abs(pressure - set_bar) <= self.config.pump.tolerance_bar
            if self.pump_reached:
                self.reached_bar = set_bar

    def _derive_state(self, snap: Snapshot) -> None:
        din_estop = "estop" in self.present
        servo, motion = snap.servo, snap.motion
        homed = servo["homed_mask"] & self.reader.all_homed == self.reader.all_homed
        if din_estop:  # released, the latched alarm makes it FAULT until reset
            state = MachineState.ESTOP
        elif self.book.blocking():
            state = MachineState.FAULT
        elif motion["state"] == PlannerState.HOMING:
            state = MachineState.HOMING
        elif self.cycle.active:
            held = self.cycle.held or motion["state"] in (PlannerState.HELD, PlannerState.HOLDING, PlannerState.PAUSED)
            state = MachineState.HOLD if held else MachineState.RUNNING
        elif motion["state"] in _MANUAL_MOTION:
            state = MachineState.JOGGING
        elif self.cycle.stopped:
            state = MachineState.STOPPED
        elif servo["state"] in (ServoState.HOLDING, ServoState.TRACKING) and homed:
            state = MachineState.READY
        else:
            state = MachineState.IDLE
        self.state = state

    def _write_outputs(self, now: float) -> None:
        force = int(DigitalOut.JET_VALVE) if self.jet_test else 0
        c = self.command
        enable = int(self.drives_wanted)
        if (c.get("servo_enable"), c.get("output_inhibit"), c.get("output_force")) != (enable, self.inhibit, force):
            c.set("servo_enable", enable)
            c.set("output_inhibit", self.inhibit)
            c.set("output_force", force)
        c.publish()
        self.heartbeat = (self.heartbeat + 1) & 0xFFFF
        self.outputs.set("cnc_heartbeat", self.heartbeat)
        self.outputs.set("plc_reset", int(now < self.plc_reset_until))
        self.outputs.publish()
        seq = self.book.last_seq
        if seq != self.out.get("alarm_seq") or not self.out.get("scans"):  # the alarm summary changes with the history
            level = self.book.highest_level()
            self._put(alarm_seq=seq, alarms_active=len(self.book.active().alarms),
                      alarm_level=-1 if level is None else int(level), blocking=int(self.book.blocking()))
        st = self.procedures.state()
        self._put(
            mode=int(self.mode), state=int(self.state), phase=int(self.cycle.phase), cycles_done=self.cycle.done,
            cycles_target=self.cycle.target, drives_on=enable, pump_on=int(self.outputs.get("pump_on")),
            pump_set_bar=self.outputs.get("pump_pressure_set"), jet_test=int(self.jet_test),
            procedure_seq=st.seq, procedure=st.id, procedure_state=st.state, message=self.message,
        )

    # -- publishing -------------------------------------------------------------------------
    def _publish_alarm(self, event: AlarmEvent) -> None:
        """Called by the book after the entry is in the history."""
        self.alarm_pub.put(encode(event))
        log.log(logging.WARNING if event.level in ("fatal", "error") else logging.INFO,
                "alarm %s %d %s %s", event.action, event.code, event.text, event.detail)

    def _publish_procedure(self) -> None:
        self.procedure_pub.put(encode(self.procedures.state()))

    def _procedure_alarm(self, alarm_id: str, detail: str) -> None:
        self._latch(alarm_id, detail, "procedure")

    def _serve_queries(self) -> None:
        while (query := self.q_active.try_recv()) is not None:
            _reply(query, self.book.active())

    def _record_jobs(self, snap: Snapshot) -> None:
        """Each program run into the job history when it ends (the planner's run counters say when)."""
        m = snap.motion
        seen = (m["run_seq"], m["run_result"])
        if seen == self.run_seen:
            return
        if self.run_seen[0] < 0:  # first scan: what ran before this process started is not ours to record
            self.run_seen = seen
            return
        if m["run_seq"] != self.run_seen[0]:
            self.run_started_ns = time.time_ns()
        self.run_seen = seen
        if m["run_result"] != RunResult.NONE:
            ticks = max(0, m["run_end_tick"] - m["run_start_tick"])
            self.jobs.append(m["program_name"], m["program_hash"], self.run_started_ns or time.time_ns(), time.time_ns(),
                             RunResult(m["run_result"]).name, ticks * self.config.timing.period_s)

    def _note(self, text: str) -> None:
        self.message = text
        log.info("logic: %s", text)

    def _put(self, **values: Any) -> None:
        """Stage fields of the logic block; the scan publishes them once, at its end."""
        for k, v in values.items():
            self.out.set(k, v)

    def _set(self, **values: Any) -> None:
        self._put(**values)
        self.out.publish()

    @staticmethod
    def _record(block, ns: int) -> None:
        if ns < 0:
            return
        arr = block[0]
        us = ns // 1000
        arr["hist"][us if us < HIST_BINS - 1 else HIST_BINS - 1] += 1
        arr["count"] += 1
        if ns > arr["max_ns"]:
            arr["max_ns"] = ns


def _stops(level: str) -> bool:
    return level in ("fatal", "error")


def _reply(query, message: msgspec.Struct) -> None:
    query.reply(query.key_expr, encode(message), encoding=zenoh.Encoding.APPLICATION_JSON)
    query.drop()
