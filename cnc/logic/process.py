"""Control logic (the soft-PLC): modes, machine state, commands, interlocks, alarms, procedures and
the automatic cycle, scanned every `[timing] logic_divisor` base ticks.

It is the machine's commander: the only writer of the `command` block (drives, fault reset, the
outputs it inhibits or forces), of the PLC's output image and of the alarm history, and the
only process that asks the planner to move in normal operation. Each scan reads one snapshot
of the blocks, serves the commands that arrived, evaluates the interlocks, steps the
automatic cycle and the guided procedure, and publishes what changed. It never waits: the
planner is asked without blocking (`PlannerLink`), and answers are acted on in a later scan.

Interlocks are decided in the tick, not here (`cnc.interlock`): the servo closes the jet and
stops the axes itself on an e-stop, a door, a barrier the logic arms during the cycle, the pump,
the PLC link or a silent commander, and on its own trips. The logic arms (barriers while the cycle
runs, the pump's pressure floor while cutting), beats a heartbeat every scan that the tick
watches, and tells people: each cause raises its alarm, each servo trip (`trip_seq`, however soon
a reset follows) its own. An alarm that stops the cut (fatal or error) also holds the jet closed
from here (`output_inhibit`), stops the planner on the path, aborts the cycle and leaves the PLC's
transport outputs off. Alarms latch until the operator resets them; the reset is refused, alarm
by alarm, while their cause is present, and does nothing while the axes still run out a stop.
Storing and publishing the alarms happens off the scan (`cnc.alarms.recorder`): the scan never
waits for a disk or the network.

The logic is the commander: it stamps every motion command it forwards to the planner with its
per-start token and the epoch it counts stops in (a stop, a fault, a jog stop, drives off), so a
motion asked for before a stop never runs after it; a jet test ends with any motion, homing or
drives change; stop and hold are always forwarded, whatever the planner runs.
"""

from __future__ import annotations

import logging
import math
import os
import secrets
import time
from typing import Any, Callable

import msgspec
import zenoh

from ..alarms import AlarmBook, AlarmHistory, AlarmLevel, Catalogue
from ..alarms.recorder import Recorder
from ..bus.keys import Keys
from ..bus.messages import (
    LOGIC_COMMANDS, MOTION_COMMANDS, MOTION_VERBS, AlarmEvent, GoTo, Hold, Home, InternalError, Jog, JogRefresh, JogStop,
    LoadProgram, Mdi, Notice, Override, Recover, Reply, ControlRun, RestartAt, CheckRestart, Resume, Stamp, Stop, encode,
)
from ..bus.service import DEFERRED, CommandRefused, CommandService, Request, Route
from ..config import CONTROLLER_ALARM_IDS, MachineConfig
from ..control.trajectories import run_text
from ..data.dataserver import SharedArea
from ..data.injection import injected_bugs
from ..hw.board import AxisIn, DigitalOut
from ..interlock import DRIVES_HELD_OFF, StopCause
from ..gateway.jobs import CutPoint, CutPoints, JobHistory, jobs_path
from ..data.layout import HIST_BINS, ClockKind, LinkState, PlannerState, Proc, RunResult, ServoFault, ServoState
from ..safety import fault_alarm
from .cycle import AutoCycle
from .pressure import PlcView, PressureWatch
from .procedures import ProcedureRunner
from .requests import PlannerLink
from .overruns import OverrunWatch
from .signals import PlcOutputs, SignalReader, Snapshot
from .states import CyclePhase, MachineState, Mode

log = logging.getLogger(__name__)

JET_BITS = int(DigitalOut.JET_VALVE | DigitalOut.ABRASIVE)
# plain ints: and'ing an int with an IntFlag member runs enum's Python code, every scan
_PUMP_CAUSE, _PLC_LINK_CAUSE = int(StopCause.PUMP), int(StopCause.PLC_LINK)
_MANUAL_MOTION = (PlannerState.JOGGING, PlannerState.MOVING, PlannerState.MDI)
_PROGRAM_RUNS = (PlannerState.RUNNING, PlannerState.HOLDING, PlannerState.HELD, PlannerState.PAUSED, PlannerState.STOPPING)
_MOVING = (PlannerState.RUNNING, PlannerState.HOLDING, PlannerState.STOPPING, PlannerState.HOMING,
           PlannerState.JOGGING, PlannerState.MOVING, PlannerState.MDI)
PLC_RESET_PULSE_S = 0.5  # how long the PLC's reset coil stays on: several link cycles

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
        if not self.command.load_current():
            log.warning("control logic: the commander's block was left mid-write: starting from safe defaults")
        self.command.set("token", secrets.randbits(63))  # a new commander: the tick and the planner start afresh
        self.command.publish()  # at once: the tick takes its counters as they are now, before any request
        self.out = area.writer("logic")
        if not self.out.load_current():
            log.warning("control logic: its block was left mid-write: the losses and trips it reported are unknown")
        self.shutdown = area.blocks["supervisor"].array["shutdown"]
        self.supervisor = area.reader("supervisor")
        hb = area.blocks["heartbeat"].array[0]
        self.beat = hb["beat"]
        hb["pid"][Proc.LOGIC] = os.getpid()
        self.scan_hist = area.blocks["logic_scan"].array
        self.wake_hist = area.blocks["logic_wake"].array
        # the PLC link starts beside this process, on wall time: until it has had the time of a lost
        # link (its cycles and their time-outs), "down, no error, never lost" is not yet "not started"
        plc = config.plc
        self.plc_stale_scans = 0  # consecutive scans the link was up and the tick found its inputs stale
        self.plc_stale_tick = -1  # the servo's tick those scans last read
        self.link_grace_until = time.monotonic() + plc.lost_after_cycles * (plc.cycle_ms + plc.timeout_ms) / 1000.0
        self.overruns = OverrunWatch(int(area.reader("servo").read_dict()["overruns"]), config.timing.period_s,
                                     config.timing.max_overruns_per_s)
        self.recorder = Recorder("logic-recorder")
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
        self.history_path = history_path
        self.book = AlarmBook(Catalogue(config), self.history, publish=self._publish_alarm, recorder=self.recorder)
        self.recorder.committed_seq = self.book.last_seq
        self.book.prune(config.logic.history_keep_days)
        self.procedures = ProcedureRunner(
            config.procedure, raise_alarm=self._procedure_alarm, known_signals=self.reader.known(), source=config.source
        )
        self.planner = PlannerLink(session, self.keys)
        self.cycle = AutoCycle(self)
        # answered from the recorder's thread, after what a command raised is stored: whoever got an
        # answer finds its entries in the history, and the scan still never waits for the disk
        self.service = CommandService(session, self.keys, "logic", self._on_bug, send=self.recorder.submit,
                                      inject=injected_bugs(area, config))
        self.service.serve(
            *(Route(verb, self.keys.logic(verb), self._command(verb), kind, motion=verb in MOTION_VERBS)
              for verb, kind in LOGIC_COMMANDS.items()),
            Route("alarms", self.keys.alarms_active, lambda _request: self.book.active(), read=True),
            Route("bug", self.keys.logic("bug"), self._bug_reported, InternalError, motion=True),
            Route("notice", self.keys.logic("notice"), self._noticed, Notice),
        )
        self.jobs = JobHistory(jobs_path(history_path))
        self.cuts = CutPoints(jobs_path(history_path))  # written by the recorder thread only
        self.cut_point: CutPoint | None = None  # where the jet last cut (for "continue")
        self.cut_saved: CutPoint | None = None  # ... as last handed to the recorder
        self.control_run: tuple[int, bool] | None = None  # a timed control run: (its ticks, then its end tick; seen running)
        self.point_asked: str = ""  # the loaded program whose stored cut point the recorder looks up
        self.point_stored: tuple[str, CutPoint | None] | None = None  # ... and what it found (set by the recorder)
        self.cutting_program = False  # the jet's ticks belong to a program run (not to a jog, an MDI, ...)
        self.jet_ticks_seen = -1  # the servo's jet_on_ticks at the last scan (-1: none yet)
        self.run_seen = (-1, -1)  # (run_seq, run_result) of the last run recorded or seen starting
        self.run_started_ns = 0
        self.token = session.liveliness().declare_token(self.keys.alive("logic"))
        self.mode = Mode.MANUAL
        self.state = MachineState.IDLE
        self.jet_test = False
        self.pressure = PressureWatch(config.pump)
        self.plc_reset_until = 0.0
        self.heartbeat = 0
        self.last_event_seq = -1
        self.last_error_seq = -1
        self.message = ""
        self.last_scan_ns = 0
        self.now = 0.0  # the scan's clock, for the command handlers
        self.snap: Snapshot | None = None
        # ids of the interlock and prompt alarms whose cause is present: raised on the rising edge,
        # cleared on the falling one (a restarted logic picks up what the history says is active)
        self.present: set[str] = {a.id for a in self.book.active().alarms if a.active}
        self.drives_wanted = bool(self.command.get("servo_enable"))
        self.drives_off_at_rest = False  # a stop-all: the drives go off once the axes stand still
        self.inhibit = int(self.command.get("output_inhibit"))
        self.inhibit_release = False  # a reset or a start asked for the inhibit to go, once nothing runs out a stop
        self.barriers_latched = bool(self.command.get("arm") & StopCause.BARRIER)  # a restarted logic keeps them armed
        self.lost_told, self.trips_told = self.out.get("lost_seen"), self.out.get("trip_seen")
        self.watchdog_told = self.out.get("watchdog_seen")
        # counters whose alarms the recorder has stored, published with the block (both keys from the
        # start: the recorder's thread only changes values, never the dict's size, while a scan reads it)
        self.told: dict[str, int] = {"lost_seen": self.lost_told, "trip_seen": self.trips_told,
                                     "watchdog_seen": self.watchdog_told}
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
        self.now = now
        self.service.poll()
        signals = self.reader.signals(snap, self.state.name, self.mode.name)
        self._interlocks(snap, signals)
        self._losses(snap)
        self._overruns(snap, now)
        self._drives_after_stop_all(snap)
        self._program_events(snap)
        self._record_jobs(snap)
        self._track_cut(snap)
        self._show_cut_point(snap)
        self._control_run_time(snap, now)
        self.cycle.step(snap, now)
        if self.procedures.scan(signals, now):
            self._publish_procedure()
        self._prompts(snap, signals)
        self._pump(snap)
        self._derive_state(snap)
        self._write_outputs(now)
        self._put(scans=self.out.get("scans") + 1, scan_us=self.last_scan_ns // 1000, **self.told)
        self.out.publish()
        self.last_scan_ns = time.perf_counter_ns() - t0
        self._record(self.scan_hist, self.last_scan_ns)

    def close(self) -> None:
        self.service.close()
        self.jobs.close()
        self.recorder.close()  # what is queued is stored and published first
        self.cuts.close()
        self.alarm_pub.undeclare()
        self.procedure_pub.undeclare()
        self.token.undeclare()
        self.history.close()

    # -- commands ---------------------------------------------------------------------------
    def _command(self, verb: str) -> Callable[[Request], Any]:
        """The handler of `verb`: `_cmd_<verb>` on the scan's snapshot; a refusal is noted too."""
        method = getattr(self, f"_cmd_{verb}")

        def handle(request: Request) -> Any:
            try:
                return method(request.message, self.snap, self.now, request)
            except CommandRefused as exc:
                self._note(f"{verb} refused: {exc}")
                raise
        return handle

    def _on_bug(self, request: Request, exc: BaseException) -> None:
        """A bug in one of the logic's handlers: the safe state first when it commands motion, then the alarm."""
        detail = f"control logic: {request.what}: {exc!r}"
        if request.motion:
            self.fault("internal_error", detail)
        else:
            self._latch("internal_error", detail, "logic")

    def _noticed(self, request: Request) -> None:
        """Another process tells the operators something (the gateway: a simulated input changed):
        an info entry, nothing graver (alarms are raised where their cause is watched)."""
        m: Notice = request.message
        if m.id not in self.book.catalogue or self.book.catalogue.entry(m.id).level != AlarmLevel.INFO:
            raise CommandRefused(f"{m.id!r} is not an info entry of the alarm catalogue")
        self.notice(m.id, m.detail)

    def _bug_reported(self, request: Request) -> None:
        """Another process met a bug serving a request (`cnc.bus.service.report_to_logic`)."""
        m: InternalError = request.message
        detail = f"{m.process}: {m.what}: {m.detail}"
        if m.motion:
            self.fault("internal_error", detail)
        else:
            self._latch("internal_error", detail, m.process)

    def _stamp(self, command):
        """A motion command as the commander sends it: with its token and the current epoch."""
        if isinstance(command, MOTION_COMMANDS):
            return msgspec.structs.replace(command, stamp=Stamp(self.command.get("token"), self.command.get("epoch")))
        return command

    def _stop_epoch(self) -> None:
        """A stop the commander decides: motion commands issued before it are void from now on."""
        self.command.set("epoch", self.command.get("epoch") + 1)
        self.command.publish()

    def _forward(self, command, request: Request, then: Callable[[Reply], None] | None = None,
                 timeout_s: float | None = None) -> object:
        """Ask the planner; the operator's request is answered with the planner's reply."""
        command = self._stamp(command)
        def on_reply(reply: Reply) -> None:
            if then is not None:
                then(reply)
            if not reply.ok:
                self._note(reply.reason)
            request.answer(reply)
        self.planner.send(command, on_reply, timeout_s)
        return DEFERRED

    def _require_mode(self, mode: Mode, what: str) -> None:
        if self.mode != mode:
            self._tell("wrong_mode", f"{what} needs {mode.name} mode (the machine is in {self.mode.name})", "logic")
            raise CommandRefused(f"wrong operation mode: {what} needs {mode.name} (mode is {self.mode.name})")

    def _require_no_blocking(self, what: str) -> None:
        if self.book.blocking():
            alarms = ", ".join(f"{a.code} {a.text}" for a in self.book.active().alarms if _stops(a.level))
            raise CommandRefused(f"cannot {what} while alarms wait for reset: {alarms}")

    def _require_still(self, what: str) -> None:
        if self.state in (MachineState.RUNNING, MachineState.HOLD, MachineState.HOMING, MachineState.JOGGING,
                          MachineState.MDI):
            raise CommandRefused(f"cannot {what} while {self.state.name}")

    def _cmd_mode(self, msg, snap, now, request) -> None:
        try:
            mode = Mode[msg.mode.upper()]
        except KeyError:
            raise CommandRefused(f"mode {msg.mode!r} is not one of: {', '.join(m.name for m in Mode)}") from None
        if mode != self.mode:
            self._require_still("change the operation mode")
            if self.jet_test:
                raise CommandRefused("cannot change the operation mode during a jet test")
            self.mode = mode

    def _cmd_start(self, msg, snap, now, request) -> None:
        self._require_mode(Mode.AUTO, "cycle start")
        if msg.cycles < 0:
            raise CommandRefused(f"cycles {msg.cycles} must be 0 (until stopped) or more")
        self._require_no_blocking("start")
        if self.state not in (MachineState.READY, MachineState.STOPPED):
            raise CommandRefused(f"cannot start while {self.state.name}" + (
                ": switch the drives on and home the machine" if self.state == MachineState.IDLE else ""))
        if not snap.motion["program_name"]:
            raise CommandRefused("no program is loaded")
        if self.procedures.running:
            raise CommandRefused(f"a procedure is running ({self.procedures.state().title}): end it first")
        signals = self.reader.signals(snap, self.state.name, self.mode.name)
        broken = [b for b in ("front", "rear") if signals.get(f"plc.barrier_{b}_ok") is False]
        if broken:  # the cycle arms the barriers: it would stop at once
            raise CommandRefused(f"the {' and '.join(broken)} light barrier{'s are' if len(broken) > 1 else ' is'} interrupted")
        self.jet_test = False
        self.inhibit_release = True
        self.cycle.start(msg.cycles, now)

    def _cmd_recover(self, msg: Recover, snap, now, request) -> Reply:
        """Start the cycle inside the loaded program with the material in place: continue the cut
        interrupted last, or a part, or a line (`cnc.planner.recovery`; the planner checks the
        rest). Refused with the reason where it cannot start."""
        self._require_mode(Mode.AUTO, "continuing a cut")
        if msg.kind not in ("continue", "part", "line"):
            raise CommandRefused(f"kind {msg.kind!r} is not one of: continue, part, line")
        self._require_no_blocking("continue")
        if self.state not in (MachineState.READY, MachineState.STOPPED):
            raise CommandRefused(f"cannot start while {self.state.name}" + (
                ": switch the drives on and home the machine" if self.state == MachineState.IDLE else ""))
        m = snap.motion
        if not m["program_name"]:
            raise CommandRefused("no program is loaded")
        if self.procedures.running:
            raise CommandRefused(f"a procedure is running ({self.procedures.state().title}): end it first")
        overlap = self.config.cycle.recovery_overlap_mm if msg.overlap_mm is None else msg.overlap_mm
        if not (math.isfinite(overlap) and 0.0 <= overlap <= 100.0):
            raise CommandRefused(f"overlap_mm {overlap:g} is out of range: 0 to 100 mm")
        # the interrupted run's cut point, and with it where that run started (a G91 program's place)
        point = self._cut_point_for(m["program_hash"])
        start = point.start_mm if point is not None else ()
        if msg.kind == "continue":
            if point is None:
                raise CommandRefused(f"no interrupted cut of {m['program_name']} is known (it ran to its end, or never "
                                     "cut): start at a part or from a line instead")
            restart = RestartAt("continue", segment=point.segment, x_mm=point.x_mm, y_mm=point.y_mm, overlap_mm=overlap,
                                segment_mm=point.segment_mm, start_mm=start)
        else:
            if msg.number < 1:
                raise CommandRefused(f"number {msg.number} must be the part (from 1) or the line to start at")
            restart = RestartAt(msg.kind, number=msg.number, start_mm=start)
        signals = self.reader.signals(snap, self.state.name, self.mode.name)
        if signals.get("plc.material_in_place") is False:
            raise CommandRefused("the PLC reports no material in place: a cut inside the program needs the material "
                                 "it was cutting; start a normal cycle")
        broken = [b for b in ("front", "rear") if signals.get(f"plc.barrier_{b}_ok") is False]
        if broken:
            raise CommandRefused(f"the {' and '.join(broken)} light barrier{'s are' if len(broken) > 1 else ' is'} interrupted")
        asked_in = self.state

        def checked(reply: Reply) -> None:
            """The planner's answer: a restart it would refuse is refused now, before the pump ramps
            for it; one it would take starts the cycle, unless the machine moved on meanwhile."""
            if reply.ok and (self.state != asked_in or self.mode != Mode.AUTO or self.cycle.active or self.procedures.running):
                reply = Reply(False, f"the machine went {self.state.name} in {self.mode.name} while the restart was checked: "
                                     "ask again")
            if reply.ok:
                self.jet_test = False
                self.inhibit_release = True
                self.cycle.start(1, self.now, restart)
                # the planner's account of the restart (`recovery.Restart.description`): where it
                # starts, and how (backed up by the overlap, or pierced again where it was piercing)
                reply = Reply(True, f"{m['program_name']}: {reply.reason}; pressure, then the cut (no transport: the "
                                    "material is in place)")
            else:
                self._note(f"recover refused: {reply.reason}")
            request.answer(reply)

        self.planner.send(CheckRestart(restart=restart), checked)
        return DEFERRED

    def _cmd_hold(self, msg, snap, now, request) -> str | None:
        """Hold is always passed on: a program holds on its path; a jog, go-to or homing stops."""
        if msg.why and "operator_lost" in self.book.catalogue:
            self._tell("operator_lost", msg.why[:200], "gateway")
        if self.cycle.active and not self.cycle.held:
            self.cycle.hold(now)  # the sequence waits; in the cutting phase the planner holds on the path
            return None
        if snap.motion["state"] in (*_MANUAL_MOTION, PlannerState.HOMING):
            self._stop_epoch()
        return self._forward(Hold(why=msg.why), request)

    def _cmd_resume(self, msg, snap, now, request) -> str | None:
        self._require_no_blocking("resume")
        if self.cycle.held:
            self.cycle.resume(now)
            return None
        if self.cycle.active and snap.motion["state"] in (PlannerState.PAUSED, PlannerState.HELD, PlannerState.HOLDING):
            return self._forward(Resume(), request)  # a program stop (M0/M1) or a feed hold at override 0 %
        if snap.motion["state"] == PlannerState.MDI:  # MDI held by the override at 0 % (the planner says if it is)
            return self._forward(Resume(), request)
        raise CommandRefused(f"nothing to resume ({self.state.name})")

    def _cmd_stop(self, msg, snap, now, request) -> str | None:
        """Stop is always passed on (the planner says whether anything moved); motion asked for
        before it is void."""
        self._stop_epoch()
        if self.cycle.active:
            self.cycle.stop()
            self.planner.send(Stop())  # whatever the planner runs; the cycle's own stop is the answer
            return None
        return self._forward(Stop(), request)

    def _cmd_stop_all(self, msg, snap, now, request) -> Reply:
        """Stop everything (any operator station, lock or not): the jet closed in the next tick, the
        axes stopped on their braking distance by the servo itself, the cycle and the program
        ended, then the drives off once the axes stand still; latched until reset."""
        who = msg.station or "an operator station"
        self._stop_epoch()
        self.fault("stop_all", f"stop all from {who}")
        self.drives_off_at_rest = True
        return Reply(True, "everything stopped: jet closed, axes stopping, drives off once they stand still; reset to go on")

    def _drives_after_stop_all(self, snap: Snapshot) -> None:
        """The drives off once a stop-all's axes stand still (never while they still brake: they
        would coast)."""
        if not self.drives_off_at_rest:
            return
        if snap.servo["state"] != ServoState.STOPPING and not snap.hw["braking"] and \
                snap.motion["state"] in (PlannerState.IDLE,):
            self.drives_wanted = False
            self.drives_off_at_rest = False

    def _cmd_reset(self, msg, snap, now, request) -> Reply:
        """Reset: servo and watchdog faults that tripped before it, the PLC's faults, then every
        alarm whose cause has gone. Nothing, while the axes still run out a stop.

        The drives come on with the reset, unless the board still shows an open door, a pressed
        e-stop or the mains off (`DRIVES_HELD_OFF`): drives switched on then would trip in the
        next tick (a controlled stop of a machine at rest, a second trip in the history, and a
        reset refused until that stop has run out). They stay off, the answer says why, and the
        reset pressed once the cause has gone (which its alarm waits for anyway) switches them on.
        The PLC's causes are not held against it: the reset's own pulse may clear them."""
        if snap.servo["state"] == ServoState.STOPPING or snap.hw["braking"]:
            raise CommandRefused("the axes are still stopping: reset once they stand still")
        # the reset covers the trips this scan has seen, and no later one
        self.command.set("reset_tick", snap.hw["tick"])
        self.command.set("reset_trip_seq", snap.servo["trip_seq"])
        self.command.set("reset_seq", self.command.get("reset_seq") + 1)
        self.inhibit_release = True
        self.jet_test = False
        self.barriers_latched = False
        self.plc_reset_until = now + PLC_RESET_PULSE_S
        held_off = snap.servo["stop_causes"] & DRIVES_HELD_OFF
        self.drives_wanted = not held_off
        self.drives_off_at_rest = False
        if self.cycle.stopped:
            self.cycle.stopped = False
        still = self.book.reset()
        said = [f"the drives stay off while {_causes_text(held_off)}"] if held_off else []
        if still:
            said.append("still present: " + ", ".join(f"{a.code} {a.text}" for a in still))
        return Reply(True, "reset; " + "; ".join(said) if said else "")

    def _cmd_drives(self, msg, snap, now, request) -> None:
        if msg.on:
            self._require_no_blocking("switch the drives on")
        else:
            self._require_still("switch the drives off")
            self._stop_epoch()
        self.jet_test = False
        self.drives_wanted = msg.on

    def _cmd_home(self, msg: Home, snap, now, request) -> str:
        self._require_mode(Mode.MANUAL, "homing")
        self._require_no_blocking("home")
        self.jet_test = False
        return self._forward(msg, request)

    def _cmd_jog(self, msg: Jog, snap, now, request) -> str:
        self._require_mode(Mode.MANUAL, "jog")
        self._require_no_blocking("jog")
        self.jet_test = False
        return self._forward(msg, request)

    def _cmd_jog_stop(self, msg: JogStop, snap, now, request) -> str:
        self._stop_epoch()
        return self._forward(msg, request)

    def _cmd_jog_refresh(self, msg: JogRefresh, snap, now, request) -> str:
        return self._forward(msg, request)

    def _cmd_goto(self, msg: GoTo, snap, now, request) -> str:
        self._require_mode(Mode.MANUAL, "go to position")
        self._require_no_blocking("move")
        self.jet_test = False
        return self._forward(msg, request)

    def _require_manual_at_rest(self, what: str, to_do: str, before: str) -> None:
        """MANUAL, no blocking alarm, READY (homed, at rest), no procedure and no jet test: where
        lines typed by hand or a control run may move the machine; CommandRefused says what is not."""
        self._require_mode(Mode.MANUAL, what)
        self._require_no_blocking(to_do)
        if self.state != MachineState.READY:
            raise CommandRefused(f"cannot {to_do} while {self.state.name}" + (
                ": switch the drives on and home the machine" if self.state == MachineState.IDLE else ""))
        if self.procedures.running:
            raise CommandRefused(f"a procedure is running ({self.procedures.state().title}): end it first")
        if self.jet_test:
            raise CommandRefused(f"the jet test is on: switch it off before {before}")

    def _cmd_mdi(self, msg: Mdi, snap, now, request) -> str:
        """G-code typed by hand, in MANUAL, on a homed machine at rest; the planner checks the lines
        and the travel. Whether the jet may open is decided here, where the pressure is known: the
        planner refuses lines that open it when it may not."""
        self._require_manual_at_rest("MDI", "run MDI", "running MDI")
        msg = msgspec.structs.replace(msg, jet_refused=self._jet_refused(snap))
        return self._forward(msg, request)

    def _cmd_control_run(self, msg: ControlRun, snap, now, request) -> str:
        """QMotor's timed run of the control alone: the trajectory's G-code from where the head
        stands (`cnc.control.trajectories.run_text`), run as an MDI with the jet refused, and stopped on
        the path when its duration is up (`_control_run_time`)."""
        try:
            text = run_text(msg.trajectory, msg.duration_s, self.config)
        except ValueError as exc:
            raise CommandRefused(str(exc)) from None
        self._require_manual_at_rest("a control run", "start a control run", "a control run")
        what = f"control run: {msg.trajectory} for {msg.duration_s:g} s"
        ticks = int(round(msg.duration_s / self.config.timing.period_s))

        def started(reply: Reply) -> None:
            if reply.ok:  # its duration counts in machine time (the ticks), from its first motion
                self.control_run = (ticks, False)
                self._note(what)
                reply = Reply(True, f"{what} from where the head stands, the jet closed; the axes stop on the path "
                                    "when the time is up")
            else:
                self._note(reply.reason)
            request.answer(reply)
        self.planner.send(self._stamp(Mdi(text, jet_refused="a control run cuts nothing: the jet stays closed")), started)
        return DEFERRED

    def _control_run_time(self, snap: Snapshot, now: float) -> None:
        """A control run under way: once its ticks are up, the servo stops the axes on the path."""
        if self.control_run is None:
            return
        until, running = self.control_run
        state, tick = snap.motion["state"], snap.hw["tick"]
        if state == PlannerState.MDI and not running:
            self.control_run = (tick + until, True)  # `until` was its length in ticks: now the tick it ends at
        elif running and state != PlannerState.MDI:
            self.control_run = None  # it ended (its time, a stop, a hold, a fault)
        elif running and tick >= until:
            # the servo's own stop on the path, from its next tick (so the duration holds to the tick
            # whatever the network does); the planner is told to end the run
            self.control_run = (1 << 62, True)
            self.command.set("stop_seq", self.command.get("stop_seq") + 1)
            self._write_command()
            self._stop_epoch()
            self.planner.send(Stop(reason="the control run's time is up"))
            self._note("control run: its time is up, stopping on the path")

    def _jet_refused(self, snap: Snapshot) -> str:
        """Why the jet may not open by hand now ("" when it may): what holds it closed in the tick,
        or a pump below the pierce pressure."""
        if snap.servo["stop_causes"]:
            return f"the jet stays closed while {_causes_text(snap.servo['stop_causes'])}"
        need = self.config.pump.pierce_pressure_bar - self.config.pump.tolerance_bar
        pressure = self.reader.plc_value(snap, "pump_pressure")
        if not self.outputs.has("pump_on") or pressure < need:
            return f"the pump is at {pressure:.0f} bar and the jet needs at least {need:.0f} bar: switch the pump on first"
        return ""

    def _cmd_load(self, msg: LoadProgram, snap, now, request) -> str:
        if self.cycle.phase == CyclePhase.CUTTING:
            raise CommandRefused("cannot load a program while cutting: it is taken between cycles")
        return self._forward(msg, request, timeout_s=self.config.planner.load_timeout_s)

    def _cmd_cut_setup(self, msg, snap, now, request) -> str:
        """The cutting job of the loaded program (`cnc.cutmodel`): only while no automatic cycle runs
        (the planner also refuses it while anything moves)."""
        if self.cycle.phase != CyclePhase.NONE:
            raise CommandRefused(f"cannot change the cutting job during the automatic cycle ({self.cycle.phase.name} phase): "
                                 "it is chosen before cycle start")
        return self._forward(msg, request, timeout_s=self.config.planner.load_timeout_s)

    def _cmd_override(self, msg: Override, snap, now, request) -> str:
        return self._forward(msg, request)

    def _cmd_pump(self, msg, snap, now, request) -> None:
        self._require_mode(Mode.MANUAL, "pump on/off")
        if msg.on:
            self._require_no_blocking("start the pump")
            bar = self.config.pump.cut_pressure_bar if msg.pressure_bar is None else msg.pressure_bar
            if not 0.0 <= bar <= self.config.pump.cut_pressure_bar:
                raise CommandRefused(f"pressure_bar {bar:g} is out of range: 0 to {self.config.pump.cut_pressure_bar:g} bar")
            if not self.outputs.has("pump_on"):
                raise CommandRefused("this machine's PLC map has no pump_on output")
            self._set_pump(True, bar)
        else:
            if self.jet_test:
                raise CommandRefused("close the jet (jet test off) before stopping the pump")
            self._set_pump(False, 0.0)

    def _cmd_jet_test(self, msg, snap, now, request) -> None:
        if not msg.on:
            self.jet_test = False
            return
        self._require_mode(Mode.MANUAL, "jet test")
        self._require_no_blocking("open the jet")
        if snap.servo["state"] != ServoState.HOLDING or snap.motion["state"] != PlannerState.IDLE:
            raise CommandRefused("the jet test needs the drives on and the axes at rest")
        if snap.servo["stop_causes"]:
            raise CommandRefused(f"the jet stays closed while {_causes_text(snap.servo['stop_causes'])}")
        need = self.config.pump.pierce_pressure_bar - self.config.pump.tolerance_bar
        pressure = self.reader.plc_value(snap, "pump_pressure")
        if pressure < need:
            raise CommandRefused(f"the pump is at {pressure:.0f} bar; the jet test needs at least {need:.0f} bar")
        self.jet_test = True

    def _cmd_acknowledge(self, msg, snap, now, request) -> None:
        if msg.code is not None and not any(a.code == msg.code for a in self.book.active().alarms):
            raise CommandRefused(f"alarm {msg.code} is not active")
        self.book.acknowledge(msg.code)

    def _cmd_procedure_start(self, msg, snap, now, request) -> None:
        self._procedure_call(lambda: self.procedures.start(msg.id))

    def _cmd_procedure_confirm(self, msg, snap, now, request) -> None:
        self._procedure_call(self.procedures.confirm)

    def _cmd_procedure_stop(self, msg, snap, now, request) -> None:
        self._procedure_call(self.procedures.stop)

    def _cmd_procedure_end(self, msg, snap, now, request) -> None:
        self._procedure_call(self.procedures.end)

    def _procedure_call(self, call: Callable[[], Any]) -> None:
        call()  # a refusal (CommandRefused) goes to the asker as it is
        self._publish_procedure()

    # -- what the cycle needs (CycleHost) ---------------------------------------------------
    def plc(self, snap: Snapshot, var_id: str) -> float:
        return self.reader.plc_value(snap, var_id)

    def send_planner(self, command, on_reply=None) -> None:
        self.planner.send(self._stamp(command), on_reply)

    def void_motion(self) -> None:
        self._stop_epoch()

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
        except CommandRefused as exc:
            return str(exc)
        self._publish_procedure()
        return ""

    def stop_procedure(self, why: str) -> None:
        """Stop the procedure the automatic cycle opened, if it still runs."""
        if self.procedures.running and self.procedures.state().by_cycle:
            self.procedures.stop(why)
            self._publish_procedure()

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
        cutting = self._cutting(snap)
        running = self.cycle.active and not self.cycle.held
        c: dict[str, str | None] = {}
        estop = []
        if not signals["din.estop_ok"]:
            estop.append("e-stop circuit open at the controller")
        if link_ok and signals.get("plc.safety_circuit_ok") is False:
            estop.append("the PLC reports the safety circuit open")
        c["estop"] = "; ".join(estop) or None
        c["mains_off"] = None if signals["din.mains_on"] else "the machine mains are off"
        c["doors_open"] = None if signals["din.doors_closed"] else "a safety door is open"
        for i, name in enumerate(self.names):
            ready = hw["axis_inputs"][i] & AxisIn.DRIVE_READY
            c[f"{name}_drive"] = None if ready else f"the {name.upper()} drive is not ready"
        causes = servo["stop_causes"]
        if has_plc:
            up = plc["state"] == LinkState.OK  # whether the tick trusts its inputs is judged below
            starting = not plc["losses"] and (plc["state"] == LinkState.CONNECTING or plc["state"] == LinkState.DOWN
                                              and not plc["error"] and time.monotonic() < self.link_grace_until)
            c["plc_link_lost"] = None if up or starting else (
                f"no answer from the PLC for {self.config.plc.lost_after_cycles} exchanges" if plc["losses"]
                else "the PLC link is down: " + (plc["error"] or "not started"))
            plc_alarm = int(self.reader.plc_value(snap, "plc_alarm"))
            stopped = link_ok and signals.get("plc.plc_running") is False
            c["plc_error"] = (f"PLC alarm {plc_alarm}" if plc_alarm else "the PLC is not in automatic operation" if stopped
                              and self.cycle.active else None)
            c["pump_pressure_fault"] = self._pump_fault(snap, signals, cutting) or (
                "the tick found the pump faulted or its pressure below the floor with the jet open"
                if causes & _PUMP_CAUSE else None)
            barriers = [b for b in ("front", "rear") if link_ok and signals.get(f"plc.barrier_{b}_ok") is False]
            c["barrier_interrupted"] = f"{' and '.join(barriers)} barrier interrupted" if barriers and running else None
            # the link up but the tick finding its inputs stale: a hung PLC-link process, once it lasts
            # two scans (the servo runs beside this scan: a link just come up, or back, is seen by the
            # tick a tick later; the tick has already stopped the machine either way). A scan counts
            # only when the servo has run a tick since the last one: a servo late for a while (its
            # block frozen with the cause it found before the link came up) is no news of the link
            stale = bool(causes & _PLC_LINK_CAUSE) and up
            if not stale:
                self.plc_stale_scans = 0
            elif servo["tick"] != self.plc_stale_tick:
                self.plc_stale_scans += 1
            self.plc_stale_tick = servo["tick"]
            if self.plc_stale_scans >= 2 and c["plc_link_lost"] is None:
                c["plc_link_lost"] = "the PLC's inputs stopped arriving (the PLC-link process is hung)"
        return c

    def _losses(self, snap: Snapshot) -> None:
        """A controller process lost (the supervisor says which and how) or the setpoint FIFO run
        dry during a motion (the servo has closed the jet already): latched, and the cut stops.
        The counts seen live in the logic's block, so a restarted logic reports what its
        predecessor could not: its own death among them."""
        sup = self.supervisor.read_dict()
        if sup["lost_seq"] > self.lost_told:
            self.lost_told = sup["lost_seq"]
            what = f"{Proc(sup['lost_proc']).name.lower()} process {sup['lost_why']}"
            self.fault("process_lost", what + ("; restarted" if sup["lost_restarted"] else "; not restarted"))
            self._committed(lost_seen=self.lost_told)
        servo = snap.servo
        trips = servo["trip_seq"] - self.trips_told
        if trips < 0:  # a servo restarted from an unknown block counts afresh
            trips = 1
        if trips > 0:
            # every trip is told, also one a reset right after it has already cleared in the servo
            self.trips_told = servo["trip_seq"]
            alarm_id = fault_alarm(ServoFault(servo["trip_fault"]), self.names, servo["trip_axis"])
            # a cause whose own alarm is listed already says it: present, or latched since (a door
            # closed before the trip that followed its opening is seen keeps its one alarm)
            if alarm_id not in self.present and not any(a.id == alarm_id for a in self.book.active().alarms):
                more = f" ({trips} trips since the last report)" if trips > 1 else ""
                self.fault(alarm_id, self._servo_detail(servo) + more)
            self._committed(trip_seen=self.trips_told)
        dog = snap.hw["watchdog_trip_tick"]
        if snap.hw["watchdog_tripped"] and dog != self.watchdog_told:
            self.watchdog_told = dog
            self.fault("watchdog", f"the servo missed {self.config.timing.watchdog_missed_ticks} ticks (tick {dog}): "
                                   "the hardware server brought the axes to rest and holds the board safe")
            self._committed(watchdog_seen=dog)

    def _overruns(self, snap: Snapshot, now: float) -> None:
        """The servo's overruns as alarms (`overruns.OverrunWatch`): a warning per episode, an
        error that stops the cut when they come faster than the machine file allows."""
        servo = snap.servo
        for action, alarm_id, detail in self.overruns.update(int(servo["overruns"]), int(servo["overrun_last_ticks"]), now):
            if action == "raise":
                self.book.raise_(alarm_id, detail, "logic")
            elif action == "clear":
                self.book.clear(alarm_id)
            elif action == "latch":
                self._latch(alarm_id, detail, "logic")
            else:
                self.fault(alarm_id, detail)

    def _committed(self, **counters: int) -> None:
        """What the logic's block says was told, once its alarm is stored: a logic killed before
        that has its successor tell it again rather than nobody."""
        self.recorder.submit(lambda: self.told.update(counters))

    def _servo_detail(self, servo: dict) -> str:
        """The servo's last trip, in words (its trip_* fields outlive a reset)."""
        axis = servo["trip_axis"]
        where = f" on axis {self.names[axis].upper()}" if 0 <= axis < len(self.names) else ""
        fault = ServoFault(servo["trip_fault"])
        if fault == ServoFault.PUMP and axis < 0:
            value = f" (pressure {servo['trip_value']:.0f} bar)"
        else:
            value = f" ({servo['trip_value']:.3f})" if servo["trip_value"] else ""
        causes = f": {_causes_text(servo['trip_causes'])}" if servo["trip_causes"] else ""
        speed = f", at {servo['trip_speed_mm_s']:.0f} mm/s" if servo["trip_speed_mm_s"] >= 0.5 else ""
        if fault == ServoFault.CONTROL_PROGRAM:  # what the program did, then how the servo stopped
            return f"{servo['control_failure']}; the servo's own PI-P stopped the axes on the path{speed}"
        return f"servo tripped: {fault.name}{where}{value}{causes}{speed}"

    def _pump_fault(self, snap: Snapshot, signals: dict[str, object], cutting: bool) -> str | None:
        if signals.get("plc.pump_fault"):
            return "the pump reports a fault"
        if not (cutting and snap.jet_on):
            return None
        return self.pressure.fault(self.reader.plc_value(snap, "pump_pressure"), self.clock())

    def _cutting(self, snap: Snapshot | None) -> bool:
        """The jet may cut now: the cycle's cutting phase, or G-code typed by hand (MDI) running."""
        return self.cycle.phase == CyclePhase.CUTTING or (snap is not None and snap.motion["state"] == PlannerState.MDI)

    def _pressure_floor(self) -> float:
        """The pressure the tick holds the pump to while the jet cuts (`PressureWatch.floor_bar`);
        from the state at the end of the scan, so a set point lowered for the next pierce lowers
        the floor in the same publication."""
        return self.pressure.floor_bar() if self._cutting(self.snap) else 0.0

    def _safe_stop(self, why: str) -> None:
        """Jet off first (the servo drops the bits within a tick), then a controlled stop on the path
        that the servo runs itself from its next tick (`stop_seq`; the planner is told to stop too);
        motion asked for before it is void."""
        self.inhibit = JET_BITS
        self.inhibit_release = False
        self.jet_test = False
        self.command.set("stop_seq", self.command.get("stop_seq") + 1)  # the servo stops on the path, in its next tick
        self.barriers_latched = self.barriers_latched or (self.cycle.active and not self.cycle.held)
        self._write_command()
        self._stop_epoch()
        if self.snap is not None and self.snap.motion["state"] not in (PlannerState.IDLE,):
            self.planner.send(Stop(reason=f"safe stop: {why}"[:200]))
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
            if m["event"].startswith("feed_hold:"):
                self._tell("feed_hold", m["event"].partition(": ")[2], "planner")
            elif m["event"]:
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
        """Follow the pressure (cnc.logic.pressure) with the set point in force at the end of the scan."""
        plc = snap.plc
        view = PlcView(snap.link_ok, plc["output_seq_sent"], plc["input_seq"],
                       self.reader.plc_value(snap, "pump_pressure"))
        self.pressure.follow(self.outputs.get("pump_pressure_set"), bool(self.outputs.get("pump_on")),
                             self.outputs.image_carrying_changes(), view, self.clock())

    def pressure_reached(self, bar: float) -> bool:
        return self.pressure.reached_at(bar)

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
        elif motion["state"] == PlannerState.MDI:
            state = MachineState.MDI
        elif motion["state"] in _MANUAL_MOTION:
            state = MachineState.JOGGING
        elif self.cycle.stopped:
            state = MachineState.STOPPED
        elif servo["state"] in (ServoState.HOLDING, ServoState.TRACKING) and homed:
            state = MachineState.READY
        else:
            state = MachineState.IDLE
        self.state = state

    def _write_command(self) -> None:
        """The commander's block: drives, the outputs held off or forced, what the tick should arm,
        and the heartbeat the tick watches (+1 every scan)."""
        snap = self.snap
        if self.inhibit_release and snap is not None:
            at_rest = (snap.motion["state"] in (PlannerState.IDLE, PlannerState.HELD, PlannerState.PAUSED)
                       and snap.servo["state"] not in (ServoState.TRACKING, ServoState.STOPPING))
            if at_rest and not snap.servo["stop_causes"]:  # never while a stop runs out with its jet bits
                self.inhibit, self.inhibit_release = 0, False
        c = self.command
        c.set("servo_enable", int(self.drives_wanted))
        c.set("output_inhibit", self.inhibit)
        c.set("output_force", int(DigitalOut.JET_VALVE) if self.jet_test else 0)
        # the barriers guard the transport zone while the cycle runs, and stay armed after a fault stopped
        # it until the reset: the tick latches an interruption the logic saw first (and aborted the cycle for)
        running = self.cycle.active and not self.cycle.held
        c.set("arm", int(StopCause.BARRIER) if running or self.barriers_latched else 0)
        c.set("pressure_floor_bar", self._pressure_floor())
        c.set("heartbeat", c.get("heartbeat") + 1)
        c.publish()

    def _write_outputs(self, now: float) -> None:
        self._write_command()
        enable = int(self.drives_wanted)
        self.heartbeat = (self.heartbeat + 1) & 0xFFFF
        self.outputs.set("cnc_heartbeat", self.heartbeat)
        self.outputs.set("plc_reset", int(now < self.plc_reset_until))
        self.outputs.publish()
        seq = self.recorder.committed_seq  # what a subscriber can already find in the history
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
        payload = encode(self.procedures.state())
        self.recorder.submit(lambda: self.procedure_pub.put(payload))

    def _procedure_alarm(self, alarm_id: str, detail: str) -> None:
        self._latch(alarm_id, detail, "procedure")

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
        if m["run_result"] == RunResult.DONE and self.cut_point is not None and self.cut_point.hash == m["program_hash"]:
            done = m["program_hash"]
            self.cut_point = self.cut_saved = None  # cut to its end: nothing left to continue
            self.point_stored, self.point_asked = (done, None), done
            self.recorder.submit(lambda: self.cuts.clear(done))
        if m["run_result"] != RunResult.NONE:
            ticks = max(0, m["run_end_tick"] - m["run_start_tick"])
            self.jobs.append(m["program_name"], m["program_hash"], self.run_started_ns or time.time_ns(), time.time_ns(),
                             RunResult(m["run_result"]).name, ticks * self.config.timing.period_s, float(m["planned_s"]),
                             m["cut"])

    def _track_cut(self, snap: Snapshot) -> None:
        """Where the jet cuts in the program, kept for "continue": the servo notes it every tick the
        jet is open (`jet_on_*`, exact to the tick, also the last one before a fault closed it);
        this takes it every scan while a program runs (and once more after the run ended, for its
        last ticks), and has the recorder write it to the job record every `[cycle]
        recovery_save_mm` of cut and whenever the jet closes: never in the way of a reaction, which
        comes first in the scan."""
        m, sv = snap.motion, snap.servo
        if m["state"] in _PROGRAM_RUNS:
            self.cutting_program = True
        elif m["state"] != PlannerState.IDLE:  # a jog, go-to, MDI or homing: its jet is no cut of the program
            self.cutting_program = False
        ticks, self.jet_ticks_seen = self.jet_ticks_seen, sv["jet_on_ticks"]
        if ticks < 0:
            self._adopt_unrecorded_cut(sv, m)
        if self.cutting_program and sv["jet_on_ticks"] != ticks and m["program_hash"] and ticks >= 0:
            point = self.cut_point = self._servos_cut_point(sv, m)
            saved = self.cut_saved
            if saved is None or saved.hash != point.hash or math.hypot(
                    point.x_mm - saved.x_mm, point.y_mm - saved.y_mm) >= self.config.cycle.recovery_save_mm:
                self._save_cut()
        if not snap.jet_on and self.cut_point is not None and self.cut_point is not self.cut_saved:
            self._save_cut()  # the jet closed (a stop, a fault, the end of a part): where it last cut

    def _adopt_unrecorded_cut(self, sv: dict, m: dict) -> None:
        """At this process's first scan: where the jet last cut in the loaded program's last run, if
        that run did not end and the servo noted it (`jet_on_tick` within the run's ticks). A logic
        killed or hung mid-cut never saw its last ticks (the servo closed the jet on its silence), so
        the job record keeps a point up to `recovery_save_mm` short of them; the servo's block,
        which outlives this process, has the exact one, and "continue" backs up only the overlap."""
        if not (sv["jet_on_ticks"] > 0 and m["program_hash"] and m["run_seq"] > 0):
            return
        if m["run_result"] == RunResult.DONE or sv["jet_on_tick"] < m["run_start_tick"]:
            return
        if m["run_result"] != RunResult.NONE and sv["jet_on_tick"] > m["run_end_tick"]:
            return  # a jog's or an MDI's jet after the run ended: no cut of the program
        point = self.cut_point = self._servos_cut_point(sv, m)
        self._save_cut()
        log.info("logic: the cut of %s last reached line %d at X%.3f Y%.3f (taken from the servo)",
                 m["program_name"], point.line, point.x_mm, point.y_mm)

    def _servos_cut_point(self, sv: dict, m: dict) -> CutPoint:
        """The servo's last jet-on setpoint as the loaded program's cut point."""
        pos = sv["jet_on_mm"]
        x = float(pos[self.names.index("x")]) if "x" in self.names else 0.0
        y = float(pos[self.names.index("y")]) if "y" in self.names else 0.0
        return CutPoint(m["program_hash"], m["program_name"], int(sv["jet_on_segment"]), x, y, int(sv["jet_on_line"]),
                        segment_mm=self._into_segment(sv, m, x, y),
                        start_mm=tuple(float(v) for v in m["program_start_mm"]))

    def _into_segment(self, sv: dict, m: dict, x: float, y: float) -> float:
        """Roughly how far into its segment the jet last cut (-1 unknown): which turn of an arc of
        several "continue" is to back up in. The planner's progress says it while the servo follows
        the setpoints (to within a planner period); a trip flushes them and the progress jumps
        to the last one pushed, so from then on it is the last one taken plus the way on from there."""
        segment, last = int(sv["jet_on_segment"]), self.cut_point
        if sv["state"] == ServoState.TRACKING and int(m["segment"]) == segment:
            return float(m["segment_mm"])
        if last is not None and last.segment == segment and last.segment_mm >= 0.0 and last.hash == m["program_hash"]:
            return last.segment_mm + math.hypot(x - last.x_mm, y - last.y_mm)
        return -1.0

    def _save_cut(self) -> None:
        point = self.cut_saved = self.cut_point
        self.recorder.submit(lambda: self.cuts.save(point))

    def _show_cut_point(self, snap: Snapshot) -> None:
        """The interrupted cut "continue" would take up, for the screen: this run's, or the one the
        job record kept for the loaded program (looked up by the recorder thread when a program is
        loaded, never by the scan)."""
        loaded = snap.motion["program_hash"]
        if loaded != self.point_asked:
            self.point_asked, self.point_stored = loaded, None
            if loaded:
                def look_up(h: str = loaded) -> None:
                    found = self.cuts.get(h)
                    if self.point_asked == h and self.point_stored != (h, None):  # not cleared meanwhile
                        self.point_stored = (h, found)
                self.recorder.submit(look_up)
        point = self.cut_point if self.cut_point is not None and self.cut_point.hash == loaded else None
        if point is None and self.point_stored is not None and self.point_stored[0] == loaded:
            point = self.point_stored[1]
        if point is None:
            self._put(cut_point_hash="", cut_point_line=0, cut_point_mm=[0.0, 0.0])
        else:
            self._put(cut_point_hash=point.hash, cut_point_line=point.line, cut_point_mm=[point.x_mm, point.y_mm])

    def _cut_point_for(self, program_hash: str) -> CutPoint | None:
        """The last cut point of the program with this hash: this run's, or one the job record kept
        (a restarted controller, the program loaded again)."""
        if self.cut_point is not None and self.cut_point.hash == program_hash:
            return self.cut_point
        stored = CutPoints(jobs_path(self.history_path), readonly=True)
        try:
            return stored.get(program_hash)
        finally:
            stored.close()

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


_CAUSE_TEXT = {
    StopCause.ESTOP: "the e-stop circuit is open", StopCause.MAINS: "the mains are off", StopCause.DOORS: "a door is open",
    StopCause.SAFETY_CIRCUIT: "the PLC's safety circuit is open", StopCause.BARRIER: "a light barrier is interrupted",
    StopCause.PUMP: "the pump is faulted or below its pressure floor",
    StopCause.PLC_LINK: "the PLC's inputs are not fresh", StopCause.COMMANDER: "the commander's heartbeat stopped",
}


def _causes_text(causes: int) -> str:
    return ", ".join(text for cause, text in _CAUSE_TEXT.items() if causes & cause)

