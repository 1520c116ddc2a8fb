"""The path planner process: commands in, setpoints out to the FIFO in bursts, state and progress out.

A timer client of the hardware server (every `[planner] divisor` base ticks). At each wake
it tops the setpoint FIFO up: when the FIFO holds less than `fifo_low_ms` of motion it
pushes a burst that fills it to `fifo_high_ms` (the paper's burst scheme), so a hold or an
override takes effect within `fifo_high_ms` plus one planner period. Between wakes it
answers commands on `<root>/internal/planner/<verb>`: each is checked against the planner's
state, the servo's and the machine's, and answered ok or refused with the reason.

What moves goes through one `ProgramRunner`: a loaded program, a jog or a go-to (a program
of one straight move), so every motion keeps the same limits. Homing runs as a sequence of
steps (`homing.py`) between refills. The planner is the only writer of the `motion` block:
its state, the loaded program, progress (segment, line, path done, ETA from the planned
profile), the lowest FIFO fill seen during the run, program events and failures, and the
position references homing gives the servo.

No stale motion. A motion command (start, resume, jog, its refresh, go-to, homing) is carried
out only with the commander's stamp: its per-start token and the epoch it was issued in, as the
commander's block says now; one issued before a stop or a fault is refused, also when it waited
behind a long re-plan (the stamp is checked again before the motion begins). Every setpoint is
stamped with the servo's motion epoch read when its motion began: the servo drops setpoints of
any other, and a motion whose epoch the servo has moved on from (a trip, a reset, drives off) is
over here too. Stop, hold and a jog's refresh are served also while a start re-plans.

A continuous jog is a dead-man's: it stops unless its station refreshes it within `[planner]
jog_deadman_ms`, measured on both the controller's clock and the wall clock (the station lives in
wall time; on the virtual clock the ticks run faster, and a jog refreshed in wall time must not
stop between refreshes). Feed override 0 % while the jet is open (or about to open) is a feed
hold: the head decelerates on the path, the jet closes at rest, and only an explicit resume,
with the override above 0 %, pierces again and goes on.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
import os
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from gcode.errors import GCodeError
from gcode.interp import Interpreter
from gcode.program import Program

from ..bus.keys import Keys
from ..bus.messages import (
    MOTION_COMMANDS, MOTION_VERBS, PLANNER_COMMANDS, GoTo, Home, Jog, JogRefresh, LoadProgram, Mdi, Override,
    ProgramDiagnostic, Reply, RestartAt, SetCut, CheckRestart, Stop,
)
from ..bus.service import CommandRefused, CommandService, Request, Route, report_to_logic
from ..config import MachineConfig
from ..cutmodel import CutSetup
from ..data.dataserver import SharedArea
from ..data.injection import injected_bugs
from ..data.fifo import SetpointFifo
from ..homing import CHUNK_S as HOMING_CHUNK_S, Homing, HomingError, Push, Reference, Unhome
from ..data.layout import PlannerState, Proc, RunResult, ServoFault, ServoState
from ..machine_dialect import dialect_for
from ..params import registry, with_values
from ..programs import read_program
from ..runtime.rt import collector_paused, give_back_memory, leave_realtime
from . import programme
from .overlap import CornerOverlap
from .preflight import PreflightError, preflight
from .runner import ProgramRunner, RunState
from .rebase import PROBE_MM, StartShift, start_shift
from .recovery import Restart, RecoveryError, continue_at, into_segments, run_from_line, start_at_part
from .quality import CutPlan, CutPlanError, cut_plan_for
from .sections import iter_steps, move_steps, pierce_dwell_s
from .steps import ProgramTiming, StepSource

MDI_NAME = "MDI"  # how an MDI entry's errors name it
MDI_INTERPRET_S = 2.0  # an MDI entry still interpreting after this is refused (an endless loop typed by hand)
_PROGRAM_STOPS = {"stop": "M0 (program stop)", "optional_stop": "M1 (optional stop)", "pallet": "M60 (pallet change)"}
_PROGRAMS = (PlannerState.RUNNING, PlannerState.MDI)  # kinds of runner that run G-code: the override holds them
from .timing_process import TimingProcess, remove_stale

log = logging.getLogger(__name__)

REALTIME = ("stop", "hold", "jog_stop", "jog_refresh")  # also served while a program is being prepared
PLAN_AHEAD_S = 0.5  # motion planned this far ahead of the setpoints made, by the worker thread
FIRST_STRETCH_STEPS = 8  # steps made at load (and at a start from a moved head) before the answer
TIMED_AT_LOAD_SEGMENTS = 1000  # a program this short is made whole and timed before the load answers (< 0.2 s)

_RUN_STATES = {
    RunState.RUNNING: PlannerState.RUNNING, RunState.HOLDING: PlannerState.HOLDING, RunState.HELD: PlannerState.HELD,
    RunState.PAUSED: PlannerState.PAUSED, RunState.STOPPING: PlannerState.STOPPING,
}


def made_before_motion(steps: StepSource, timing: ProgramTiming, segments: int) -> bool:
    """A run's steps made before it moves, so that no refill makes sections while the head moves:
    all of a program of at most `TIMED_AT_LOAD_SEGMENTS` segments, its timing made from those very
    steps (True); the first stretch of a longer one (False: its timing is made elsewhere)."""
    if segments <= TIMED_AT_LOAD_SEGMENTS:
        steps.build_until(1 << 62)  # all of it: bounded by the program's size
        timing.compute([steps.peek(i) for i in range(steps.made)])
        return True
    steps.build_until(FIRST_STRETCH_STEPS - 1)
    return False


class LoadedProgram:
    """A program interpreted and checked, its first steps made, ready to start: the rest of its steps
    are made while it runs (`StepSource`), its cycle time beside it (`ProgramTiming`)."""

    def __init__(self, path: str, text: bytes, program: Program, config: MachineConfig, start: tuple,
                 shift: StartShift | None, cut: CutPlan | None = None, cut_text: str = "",
                 operator_cut: CutSetup | None = None) -> None:
        self.path, self.text, self.program, self.start, self.shift = path, text, program, start, shift
        self.config = config
        self.cut, self.cut_text, self.operator_cut = cut, cut_text, operator_cut  # the cutting job (`cnc.cutmodel`)
        self.name = Path(path).name
        self.hash = hashlib.sha256(text).hexdigest()
        st = program.stats
        self.programmed_mm = st.feed_length_mm + st.rapid_length_mm  # the path length until the timing has it
        self.timing = ProgramTiming(config.timing.period_s, CornerOverlap.of(config))
        # the first stretch (a short program: all of it, timed now), made now: the start finds it made
        self._first: StepSource | None = StepSource(iter_steps(program, config, cut))
        self.timing_job: TimingProcess | None = None
        if not made_before_motion(self._first, self.timing, len(program.segments)):
            # made on the helper thread (normal scheduling): the child process inherits that
            self.timing_job = TimingProcess(program, config, self.timing, cut)

    def new_source(self) -> StepSource:
        """The program's steps for one run, the first stretch made."""
        source = StepSource(iter_steps(self.program, self.config, self.cut))
        source.build_until(FIRST_STRETCH_STEPS - 1)
        return source

    def source(self) -> StepSource:
        """The steps of the next run (the one made at load, the first time)."""
        first, self._first = self._first, None
        return first or self.new_source()

    def shifted(self, start: tuple) -> Program:
        """The program as interpreted from `start`, by its start shift (`shift` is not None)."""
        delta = [0.0, 0.0, 0.0]
        for name, now, then in zip(self.config.axis_names, start, self.start):
            delta["xyz".index(name)] = float(now) - float(then)
        return self.shift.apply(self.program, tuple(delta))

    def rebased(self, start: tuple) -> "LoadedProgram":
        """This program as interpreted from `start` (the head moved since loading), by its start shift."""
        return LoadedProgram(self.path, self.text, self.shifted(start), self.config, start, self.shift, self.cut,
                             self.cut_text, self.operator_cut)

    def with_cut(self, cut: CutPlan | None, cut_text: str, operator_cut: CutSetup | None) -> "LoadedProgram":
        """This program under another cutting job (its steps and cycle time made again)."""
        return LoadedProgram(self.path, self.text, self.program, self.config, self.start, self.shift, cut, cut_text,
                             operator_cut)

    @property
    def total_mm(self) -> float:
        return self.timing.total_mm if self.timing.complete else self.programmed_mm


class Planner:
    """The planner's state and work; `run()` is its loop."""

    def __init__(self, config: MachineConfig, area: SharedArea, fifo: SetpointFifo, session: zenoh.Session, timer) -> None:
        self.config, self.fifo, self.timer = config, fifo, timer
        if config.planner.corner_programme_ms > 0.0:
            programme.load_solver()  # now, not in the worker's first programmed corner (it would be late)
        self.dt = config.timing.period_s
        self.n = len(config.axis_names)
        self.low = max(1, round(config.planner.fifo_low_ms / 1000.0 / self.dt))
        # homing's FIFO lead: one chunk, or two of the planner's periods where that is longer (the
        # FIFO must not run dry before the next wake, nor before one that comes a period late)
        self.homing_lead = max(1, round(HOMING_CHUNK_S / self.dt), 2 * config.planner.divisor)
        self.high = min(fifo.capacity, max(self.low + 1, round(config.planner.fifo_high_ms / 1000.0 / self.dt)))
        self.out = area.writer("motion")
        self.out.load_current()
        self.hw_r, self.servo_r, self.command_r = area.reader("hw"), area.reader("servo"), area.reader("command")
        self.sim_r = area.reader("sim")  # the simulated machine's fault knobs (planner_stall)
        self._i_stall = self.sim_r.layout.index["planner_stall"]
        self.shutdown = area.blocks["supervisor"].array["shutdown"]
        hb = area.blocks["heartbeat"].array[0]
        self.beat = hb["beat"]
        hb["pid"][Proc.PLANNER] = os.getpid()
        self.keys = Keys(config.zenoh.key_prefix, config.machine.name)
        self.report_bug = report_to_logic(session, self.keys, "planner")
        self.service = CommandService(session, self.keys, "planner", self._on_bug, inject=injected_bugs(area, config))
        self.service.serve(*(
            Route(verb, self.keys.planner(verb), self._command(verb), kind, motion=verb in MOTION_VERBS,
                  lane="realtime" if verb in REALTIME else "main")
            for verb, kind in PLANNER_COMMANDS.items()
        ))
        self.token = session.liveliness().declare_token(self.keys.alive("planner"))
        self.loaded: LoadedProgram | None = None
        self.timing_published = False  # the loaded program's cycle time is in the status
        remove_stale()  # a predecessor killed while it timed a program leaves its files
        self.runner: ProgramRunner | None = None
        self.runner_kind = PlannerState.IDLE  # RUNNING (a program), JOGGING or MOVING
        self.restart: Restart | None = None  # the run under way starts inside the program
        self.homing = None
        self.homing_obj: Homing | None = None
        self.waiting_for: tuple | None = None  # homing: ("drain",) or ("reference", seq)
        self.override = 1.0
        self.motion_epoch = 0  # the servo's epoch the motion under way belongs to (stamped on its setpoints)
        self.jog_continuous = False
        self.jog_life = (0, 0)  # (tick, monotonic ns) of the continuous jog's last refresh
        self.deadman = (round(config.planner.jog_deadman_ms / 1000.0 / self.dt), int(config.planner.jog_deadman_ms * 1e6))
        self.start_cancelled = ""  # a stop or hold served while a start re-planned: the start is not carried out
        cap = fifo.capacity
        self.ring_done = np.zeros(cap)
        self.ring_segment = np.full(cap, -1, dtype=np.int64)
        self.ring_line = np.zeros(cap, dtype=np.int64)
        self.ring_into = np.zeros(cap)  # how far into its segment each record lies (`recovery.into_segments`)
        self.into_carry = (-1, 0.0)
        self.run_first = 0  # FIFO head counter at the run's first record
        self.track_fill = False
        self.last_pushed: np.ndarray | None = None
        self.params_r = area.reader("params")
        self.param_specs = [p for p in registry(config) if p.owner == "planner"]
        self._set(state=int(PlannerState.IDLE), homing_axis=-1, override=1.0, fifo_min_fill=-1, segment=-1,
                  pierce_s=self.config.jet.pierce_dwell_s)
        self._forget_program()
        self.apply_params()  # a restarted planner takes the values in force, not the file's
        # Look-ahead windows are planned by a worker thread, away from the refills: a window of
        # hundreds of short chords takes tens of ms, more than the FIFO's slack. The main loop
        # holds `lock` while it serves commands and refills; the worker only to fetch a window
        # and to commit it (`ProgramRunner.plan_job`, `SectionStream.accept`).
        self.lock = threading.Lock()
        self.plan_wanted = threading.Event()
        self._stop_worker = threading.Event()
        self.worker = threading.Thread(target=self._plan_ahead, name="plan-ahead", daemon=True)
        self.worker.start()

    # -- the loop ---------------------------------------------------------------------------
    def run(self) -> None:
        my_bit = 1 << Proc.PLANNER
        while not self.shutdown[0] & my_bit:
            woke = self.timer.wait_tick(0.005)
            if woke:
                while self.timer.wake.acquire(False):
                    pass
            with self.lock:
                self.apply_params()
                self.handle_commands()
                self._timing_done()  # also while the clock stands (a paused virtual clock)
                self._restart_timing_done()
                if woke:
                    try:
                        self.on_tick()
                    finally:
                        self.timer.tick_done()
            self.beat[Proc.PLANNER] += 1

    def apply_params(self) -> None:
        """Take the planner's control parameters from the params block when they changed and no
        program runs (the gateway refuses the ones that need that while one does; any that arrive
        as a program starts wait for its end)."""
        values, _ = self.params_r.read()
        index = self.params_r.layout.index
        seq = values[index["change"]]
        if seq == self.out.get("params_change") or (self.runner is not None and self.runner_kind == PlannerState.RUNNING):
            return
        slots = values[index["values"]]
        self.config = with_values(self.config, self.param_specs, [slots[p.index] for p in self.param_specs])
        self.low = max(1, round(self.config.planner.fifo_low_ms / 1000.0 / self.dt))
        self.high = min(self.fifo.capacity, max(self.low + 1, round(self.config.planner.fifo_high_ms / 1000.0 / self.dt)))
        self._set(params_change=seq)

    def _plan_ahead(self) -> None:
        """Worker: after each refill, plan windows until the motion is planned PLAN_AHEAD_S ahead."""
        while not self._stop_worker.is_set():
            if not self.plan_wanted.wait(0.05):
                continue
            self.plan_wanted.clear()
            runner = self.runner
            if runner is not None:
                try:
                    runner.build_ahead()  # outside the lock: the refills go on meanwhile
                except Exception:  # the main loop meets the same failure when it reaches that step
                    log.exception("planner: making the next steps failed")
            while not self._stop_worker.is_set():
                with self.lock:
                    runner = self.runner
                    job = runner.plan_job(PLAN_AHEAD_S) if runner is not None else None
                if job is None:
                    break
                try:
                    job.compute()
                except Exception:  # a bug: the main loop plans the same window itself and reports it
                    log.exception("planner: planning ahead failed")
                    break
                with self.lock:
                    if self.runner is runner:
                        job.stream.accept(job)
            if runner is not None and self.runner is runner and hasattr(runner, "solve_ahead"):
                try:  # a programmed corner ahead (`programme.py`): tens of ms, outside the lock
                    runner.solve_ahead()
                except Exception:  # the refill solves the same corner itself and meets the same failure
                    log.exception("planner: solving a corner ahead failed")
            with self.lock:  # the corner ahead decided now, the FIFO just refilled (`ProgramRunner.decide_corner`)
                if self.runner is not None and self.runner is runner and hasattr(runner, "decide_corner"):
                    try:
                        runner.decide_corner()
                    except Exception:  # the main loop meets the same failure when it reaches that corner
                        log.exception("planner: deciding the corner ahead failed")

    def close(self) -> None:
        if self.loaded is not None and self.loaded.timing_job is not None:
            self.loaded.timing_job.cancel()
        self._cancel_restart_timing()
        self._stop_worker.set()
        self.worker.join(2.0)
        self.service.close()
        self.token.undeclare()

    # -- commands ---------------------------------------------------------------------------
    def handle_commands(self) -> None:
        self.service.poll()

    def _command(self, verb: str):
        """The handler of `verb`: a motion command only with the commander's current stamp, then
        `_cmd_<verb>`. While a start is being prepared, a stop or hold cancels it (and says so)."""
        method = getattr(self, f"_cmd_{verb}")

        def handle(request: Request) -> Reply | None:
            msg = request.message
            if verb in ("stop", "hold") and self.preparing_start:
                self.start_cancelled = f"cancelled by a {verb} while it was being prepared"
                return Reply(True, f"the start was {self.start_cancelled}")
            if isinstance(msg, MOTION_COMMANDS):
                self._check_stamp(msg)
            return method(msg)
        return handle

    def _on_bug(self, request: Request, exc: BaseException) -> None:
        """A bug in a handler: when the command moves the machine, what runs stops on its path (as a
        stop does; abandoned, when even that fails), and the logic is told, which brings the machine
        to its safe state (jet off first) and raises the internal-error alarm."""
        if request.motion and (self.runner is not None or self.homing is not None):
            try:
                self._cmd_stop(None)
            except Exception:
                log.exception("planner: the stop after a bug in %s failed too", request.what)
                self._fail(f"{request.what}: internal error: {exc!r}", report=False)
        self.report_bug(request, exc)

    def _check_stamp(self, msg) -> None:
        """Only the current commander's motion commands of its current epoch move the machine."""
        cmd = self.command_r.read_dict()
        stamp = msg.stamp
        if stamp is None or stamp.token != cmd["token"]:
            raise CommandRefused("not from the machine's commander (motion commands come from the control logic)")
        if stamp.epoch != cmd["epoch"]:
            raise CommandRefused(f"issued before the last stop (epoch {stamp.epoch}, now {cmd['epoch']}): not carried out")

    def _state(self) -> PlannerState:
        return PlannerState(self.out.get("state"))

    def _require_idle(self, what: str) -> None:
        state = self._state()
        if state != PlannerState.IDLE:
            raise CommandRefused(f"cannot {what} while {state.name}")

    def _require_servo(self, what: str, moving_ok: bool = False) -> dict:
        s = self.servo_r.read_dict()
        if s["state"] in (ServoState.FAULT, ServoState.STOPPING):
            raise CommandRefused(f"cannot {what}: the servo is tripped ({ServoFault(s['fault']).name}); reset first")
        if s["state"] == ServoState.TRACKING and moving_ok:
            return s
        if s["state"] == ServoState.TRACKING:
            raise CommandRefused(f"cannot {what}: the axes are still moving")
        if s["state"] != ServoState.HOLDING:
            raise CommandRefused(f"cannot {what}: the drives are not enabled")
        return s

    def _cmd_load(self, msg: LoadProgram) -> None:
        self._require_idle("load a program")
        path = msg.path
        # bounded, without blocking, regular text files only: the path comes from a command
        data = read_program(path, self.config.gcode.max_program_bytes)
        servo = self.servo_r.read_dict()
        start = tuple(servo["commanded_mm"])
        # on a homed machine a move beyond the travel is refused now (before it is planned), not
        # at the start of a cycle that has fed the material
        setup = cut_setup_of(msg.cut)
        self._take(self._prepare(path, data, start, check_travel=servo["homed_mask"] == (1 << self.n) - 1, setup=setup))
        program = self.loaded.program
        self._set(
            program_seq=self.out.get("program_seq") + 1, program_name=self.loaded.name, program_hash=self.loaded.hash,
            program_lines=program.stats.lines, done_mm=0.0, segment=-1, segment_mm=-1.0, line=0,
            run_result=int(RunResult.NONE),
            cut=self.loaded.cut_text,
        )

    def _cmd_cut_setup(self, msg: SetCut) -> Reply:
        """The operator's cutting job for the loaded program (or back to the program's own): checked
        against the library and the program, then the program's steps and cycle time made with it."""
        if self.loaded is None:
            raise CommandRefused("no program is loaded: load one, then choose its material")
        self._require_idle("change the cutting job")
        setup = cut_setup_of(msg)
        loaded = self.loaded
        cut, text = self._on_helper(lambda: self._cut_plan(loaded.program, setup, loaded.name))
        self._take(loaded.with_cut(cut, text, setup))
        self._set(cut=text)
        return Reply(True, text or f"{loaded.name} cuts at its programmed feed")

    def _cut_plan(self, program: Program, given: CutSetup | None, name: str) -> tuple[CutPlan | None, str]:
        try:
            return cut_plan_for(program, given, self.config, name)
        except CutPlanError as exc:
            raise CommandRefused(str(exc)) from None

    def _take(self, loaded: LoadedProgram) -> None:
        """Make `loaded` the program; its cycle time is being planned in a process of its own (the
        status says -1 s until it is done: `_timing_done`); the timing of the program it replaces
        stops."""
        if self.loaded is not None and self.loaded.timing_job is not None:
            self.loaded.timing_job.cancel()
        self.loaded = loaded
        self.timing_published = False
        self._set(planned_s=-1.0, eta_s=-1.0, total_mm=loaded.total_mm, program_start_mm=[float(v) for v in loaded.start])
        self._timing_done()

    def _timing_done(self) -> None:
        """Publish the loaded program's cycle time and path length once its timing is complete."""
        loaded = self.loaded
        if loaded is None or self.timing_published:
            return
        timing = loaded.timing
        if loaded.timing_job is not None and not timing.complete and timing.failure is None:
            if not loaded.timing_job.poll():
                return
            loaded.timing_job = None
        if timing.failure is not None:
            self.timing_published = True
            log.error("planner: timing %s failed: %r", loaded.name, timing.failure)
            self._event("timing_failed", f"the cycle time of {loaded.name} could not be planned: {timing.failure}", 0)
            return
        if timing.complete:
            self.timing_published = True
            planned = timing.total_ticks * self.dt
            values = dict(planned_s=planned, total_mm=timing.total_mm)
            if self.runner is None or self.runner_kind != PlannerState.RUNNING:
                values["eta_s"] = planned
            self._set(**values)

    def _forget_program(self) -> None:
        """A planner started again has no program: the status must not name the one its
        predecessor held (cycle start would be offered, then refused)."""
        lost = bytes(self.out.get("program_name")).rstrip(b"\0").decode(errors="replace")
        if not lost:
            return
        log.warning("planner: the program %s was lost with the planner's restart: load it again", lost)
        self._set(program_seq=self.out.get("program_seq") + 1, program_name="", program_hash="", program_lines=0,
                  planned_s=0.0, total_mm=0.0, done_mm=0.0, segment=-1, segment_mm=-1.0, line=0, eta_s=0.0)

    def _prepare(self, path: str, data: bytes, start: tuple, check_travel: bool = False, probe: bool = True,
                 setup: CutSetup | None = None) -> LoadedProgram:
        """Interpret and check a program, and make its first steps, on a helper thread while this loop
        keeps its heartbeat: a large program takes seconds to interpret, and a silent heartbeat
        makes the supervisor kill the planner as hung. The program is interpreted a second time
        from a probe start (`rebase.py`), so that a start from wherever the head then is needs no
        third interpretation."""
        return self._on_helper(lambda: self._load(path, data, start, check_travel, probe, setup))

    def _load(self, path: str, data: bytes, start: tuple, check_travel: bool, probe: bool,
              setup: CutSetup | None = None) -> LoadedProgram:
        program = self._interpret(path, data, start)
        if check_travel:
            preflight(program.segments, self.config, dict.fromkeys(self.config.axis_names, True), Path(path).name)
        cut, cut_text = self._cut_plan(program, setup, Path(path).name)
        if not probe:
            return LoadedProgram(path, data, program, self.config, start, None, cut, cut_text, setup)
        offset = [PROBE_MM["xyz".index(a)] for a in self.config.axis_names]
        probe_start = tuple(float(v) + d for v, d in zip(start, offset))
        try:
            probe = self._interpret(path, data, probe_start)
        except CommandRefused:  # valid from here, not from there: a start elsewhere interprets again
            shift = None
        else:
            shift = start_shift(program, probe, _xyz(self.config, offset))
            del probe
        give_back_memory()
        return LoadedProgram(path, data, program, self.config, start, shift, cut, cut_text, setup)

    def _on_helper(self, work):
        """`work()` on a helper thread (out of real time, the collector paused) while this loop beats
        and answers stop, hold and a jog's refresh; its result, or its exception raised here."""
        outcome: list = []

        def run() -> None:
            leave_realtime()  # seconds of work for a large program: not at the refills' priority
            try:
                with collector_paused():
                    outcome.append(work())
            except PreflightError as exc:
                outcome.append(CommandRefused(str(exc)))
            except BaseException as exc:  # raised again below, on the loop's thread
                outcome.append(exc)

        helper = threading.Thread(target=run, name="prepare-program", daemon=True)
        helper.start()
        while helper.is_alive():
            helper.join(0.02)
            self.beat[Proc.PLANNER] += 1
            self._serve_realtime()
        if isinstance(outcome[0], BaseException):
            raise outcome[0]
        return outcome[0]

    def _serve_realtime(self) -> None:
        """While a program is prepared (seconds, for a large one): stop, hold and a jog's refresh are
        answered now. Nothing moves meanwhile; a stop or hold cancels the start being prepared."""
        self.service.poll(("realtime",))

    preparing_start = False
    restart_timing: TimingProcess | None = None  # a long restart's timing under way (`_restart_runner`)

    def _interpret(self, path: str, data: bytes, start: tuple) -> Program:
        dialect = dataclasses.replace(dialect_for(self.config), start_position_mm=_xyz(self.config, start))
        try:
            return Interpreter(dialect, path).run(data)
        except GCodeError as exc:
            raise CommandRefused(exc.render()) from None

    def _cmd_start(self, msg) -> None:
        if self.loaded is None:
            raise CommandRefused("no program is loaded")
        self._require_idle("start")
        servo = self._require_servo("start")
        # a start from the beginning runs the program from where the head stands; a restart, as the
        # interrupted run placed it (`RestartAt.start_mm`, else as it is): only its rapid leaves from the head
        start = tuple(servo["commanded_mm"]) if msg.restart is None else self._restart_start(msg.restart)
        moved = not _same_start(start, self.loaded.start)
        restart = timing_job = None
        if moved or msg.restart is not None:
            # seconds of work for a large program or a slow machine: on the helper, stop and hold answered
            self.preparing_start, self.start_cancelled = True, ""
            try:
                loaded = self.loaded
                if moved and loaded.shift is not None:  # the program's first move starts from `start`
                    self._take(self._on_helper(lambda: loaded.rebased(start)))
                elif moved:  # not a pure shift of its start: interpreted again from there (and again at the next move)
                    self._take(self._prepare(loaded.path, loaded.text, start, probe=False))
                if self.start_cancelled:
                    raise CommandRefused(f"the start was {self.start_cancelled}")
                servo = self._require_servo("start")
                homed = _homed(self.config, servo)
                if msg.restart is not None:
                    at, head, program = msg.restart, _xyz(self.config, servo["commanded_mm"]), self.loaded.program
                    runner, restart, timing_job = self._on_helper(lambda: self._restart_runner(at, head, homed, program))
            finally:
                self.preparing_start = False
            try:
                if self.start_cancelled:
                    raise CommandRefused(f"the start was {self.start_cancelled}")
                self._check_stamp(msg)  # a stop may have come while it was prepared
                servo = self._require_servo("start")
                if restart is not None and _homed(self.config, servo) != homed:
                    raise CommandRefused("an axis's reference changed while the start was prepared: start again")
            except CommandRefused:
                if timing_job is not None:
                    timing_job.cancel()
                raise
        if restart is not None:
            log.info("planner: %s: %s", self.loaded.name, restart.description)
            self._event("restart", restart.description, restart.line)
        else:
            try:
                preflight(self.loaded.program.segments, self.config, _homed(self.config, servo), self.loaded.name)
            except PreflightError as exc:
                raise CommandRefused(str(exc)) from None
            runner = ProgramRunner(None, self.config, steps=self.loaded.source(), timing=self.loaded.timing,
                                   pierce_s=pierce_dwell_s(self.config, self.loaded.cut))
        self._begin(runner, PlannerState.RUNNING)
        self.restart = restart  # its segments are numbered as the loaded program's (`_push`)
        self.restart_timing = timing_job  # a long restart's cycle time, for its ETA (`_restart_timing_done`)
        self._set(run_seq=self.out.get("run_seq") + 1, run_result=int(RunResult.NONE),
                  run_start_tick=self.hw_r.read_dict()["tick"])

    def _restart_start(self, at: RestartAt) -> tuple:
        """Where a restart's program starts from: where the interrupted run started (`at.start_mm`,
        checked), else where the loaded program was placed."""
        if not at.start_mm:
            return self.loaded.start
        if len(at.start_mm) != self.n or not all(math.isfinite(v) for v in at.start_mm):
            raise CommandRefused(f"restart start_mm {list(at.start_mm)} must be {self.n} finite values, one per axis "
                                 f"({', '.join(a.upper() for a in self.config.axis_names)})")
        return tuple(float(v) for v in at.start_mm)

    def _cmd_check_restart(self, msg: CheckRestart) -> Reply:
        """Whether a restart would start from where the head stands: what `start` with it would
        refuse, refused now (before the cycle ramps the pump for it); nothing moves."""
        if self.loaded is None:
            raise CommandRefused("no program is loaded")
        servo = self._require_servo("start")
        at, head, homed = msg.restart, _xyz(self.config, servo["commanded_mm"]), _homed(self.config, servo)
        start, loaded = self._restart_start(at), self.loaded
        restart = self._on_helper(lambda: self._restart_of(at, head, homed, self._program_from(loaded, start)))
        return Reply(True, restart.description)

    def _program_from(self, loaded: LoadedProgram, start: tuple) -> Program:
        """The loaded program as interpreted from `start` (itself, when it was)."""
        if _same_start(start, loaded.start):
            return loaded.program
        if loaded.shift is not None:
            return loaded.shifted(start)
        return self._interpret(loaded.path, loaded.text, start)

    def _restart_of(self, at: RestartAt, head: tuple[float, float, float], homed: dict, program: Program) -> Restart:
        """`program` (the loaded one, placed as the interrupted run placed it) restarted from inside
        it (`recovery.py`), checked against the travel like any program; CommandRefused says why it
        cannot."""
        try:
            if at.kind == "continue":
                restart = continue_at(program, at.segment, (at.x_mm, at.y_mm), at.overlap_mm, head, at.segment_mm)
            elif at.kind == "part":
                restart = start_at_part(program, at.number, head)
            elif at.kind == "line":
                restart = run_from_line(program, at.number, head)
            else:
                raise RecoveryError(f"restart kind {at.kind!r} is not one of: continue, part, line")
            preflight(restart.program.segments, self.config, homed, self.loaded.name)
        except (RecoveryError, PreflightError) as exc:
            raise CommandRefused(str(exc)) from None
        return restart

    def _restart_runner(self, at: RestartAt, head: tuple[float, float, float], homed: dict,
                        program: Program) -> tuple[ProgramRunner, Restart, TimingProcess | None]:
        """A run of the loaded program from inside it: the restart (`_restart_of`), its first steps
        made, and its timing: made now when short, else in a process of its own (returned: its ETA
        shows once that is done, as a long program's after a load). Runs on the helper
        (`_on_helper`): a long program's restart, or a slow machine's steps, take seconds; the
        timing process inherits the helper's normal scheduling."""
        restart = self._restart_of(at, head, homed, program)
        cut = None
        if self.loaded.cut is not None:  # the same job: each segment keeps its quality (the rapid has none)
            original = restart.original_segment(np.arange(len(restart.program.segments)))
            cut = CutPlan(self.loaded.cut.model, self.loaded.cut.quality[np.clip(original, 0, len(self.loaded.cut.quality) - 1)])
        steps = StepSource(iter_steps(restart.program, self.config, cut))
        timing = ProgramTiming(self.dt, CornerOverlap.of(self.config))
        job = None
        if not made_before_motion(steps, timing, len(restart.program.segments)):
            job = TimingProcess(restart.program, self.config, timing, cut)
        runner = ProgramRunner(None, self.config, steps=steps, timing=timing, pierce_s=pierce_dwell_s(self.config, cut))
        return runner, restart, job

    def _restart_timing_done(self) -> None:
        """A long restart's timing taken in once its process is done (the runner's ETA then has it);
        a failure leaves the ETA unknown, and says so."""
        job = self.restart_timing
        if job is None or not job.poll():
            return
        self.restart_timing = None
        if job.timing.failure is not None:
            log.error("planner: timing the restart of %s failed: %r", self.loaded.name if self.loaded else "?",
                      job.timing.failure)

    def _cmd_hold(self, _msg) -> Reply:
        """A feed hold of a program; a jog, go-to or homing (which cannot continue) stops."""
        if self.homing is not None:
            self._abort_homing("stopped by a hold")
            return Reply(True, "homing stopped")
        if self.runner is not None and self.runner_kind != PlannerState.RUNNING:
            self.runner.stop()
            return Reply(True, f"{self.runner_kind.name.lower()} stopped")
        if self.runner is None or self.runner.state != RunState.RUNNING:
            raise CommandRefused(f"nothing to hold ({self._state().name})")
        self.runner.hold()
        self._publish_state()
        return Reply(True)

    def _cmd_resume(self, _msg) -> None:
        if self.runner is None or self.runner.state not in (RunState.HOLDING, RunState.HELD, RunState.PAUSED):
            raise CommandRefused(f"nothing to resume ({self._state().name})")
        if self.override <= 0.0 and self.runner_kind in _PROGRAMS:
            raise CommandRefused("the feed override is 0 %: raise it before resuming")
        # the hold's last setpoints may still be running out: what resume adds follows them
        self._require_servo("resume", moving_ok=True)
        self.runner.resume()
        self.track_fill = False  # the refill after a standstill starts from an empty FIFO
        self._publish_state()

    def _cmd_stop(self, msg: Stop) -> Reply:
        if self.homing is not None:
            self._abort_homing(f"stopped: {msg.reason}" if msg.reason else "stopped by the operator")
            return Reply(True)
        if self.runner is None:
            raise CommandRefused("nothing to stop: nothing moves")
        self.runner.stop()
        self._publish_state()
        return Reply(True)

    def _cmd_override(self, msg: Override) -> None:
        if not (math.isfinite(msg.percent) and 0.0 <= msg.percent <= 200.0):
            raise CommandRefused(f"override {msg.percent:g} % is out of range: 0 to 200 %")
        self.override = msg.percent / 100.0
        if self.runner is not None and self.runner_kind in _PROGRAMS:
            held = self.runner.state
            self.runner.set_override(self.override)
            if self.runner.state != held and self.runner.state in (RunState.HOLDING, RunState.HELD):
                self._event("feed_hold", "feed override 0 % with the jet open: the feed holds, the jet closes at rest; "
                            "raise the override and resume to pierce again", self.runner.line_now)
            self._publish_state()
        self._set(override=self.override)

    def _cmd_jog(self, msg: Jog) -> None:
        axis = msg.axis.lower()
        if axis not in self.config.axis:
            raise CommandRefused(f"no axis {msg.axis!r} on this machine (axes: {', '.join(self.config.axis_names)})")
        self._require_idle("jog")
        servo = self._require_servo("jog")
        a = self.config.axis[axis]
        i = self.config.axis_names.index(axis)
        speed = abs(msg.velocity_mm_s) or self.config.planner.jog_velocity_mm_s
        if not math.isfinite(speed) or speed > a.max_velocity_mm_s:
            raise CommandRefused(f"jog speed {speed:g} mm/s is out of range: up to {a.max_velocity_mm_s:g} mm/s for {axis.upper()}")
        here = list(servo["commanded_mm"])
        homed = bool(servo["homed_mask"] >> i & 1)
        travel = f"the travel {a.travel_min_mm:g} to {a.travel_max_mm:g} mm"
        if msg.distance_mm is not None:
            if not math.isfinite(msg.distance_mm) or msg.distance_mm == 0.0:
                raise CommandRefused(f"jog distance {msg.distance_mm!r} must be a non-zero number of mm")
            target = here[i] + msg.distance_mm
            if homed and _beyond(a, target) > max(a.soft_limit_tolerance_mm, _beyond(a, here[i])):
                raise CommandRefused(f"{axis.upper()} would reach {target:.3f} mm, outside {travel}")
        else:
            direction = math.copysign(1.0, msg.velocity_mm_s) if msg.velocity_mm_s else 1.0
            if homed:
                target = a.travel_max_mm if direction > 0 else a.travel_min_mm
                if (target - here[i]) * direction <= 0.0:
                    raise CommandRefused(f"{axis.upper()} is at {here[i]:.3f} mm, at or beyond the end of {travel} that way: "
                                  f"jog {'negative' if direction > 0 else 'positive'}")
            else:  # no soft limits before homing: the hard limit switch is what stops it
                target = here[i] + direction * 2.0 * (a.travel_max_mm - a.travel_min_mm)
        end = list(here)
        end[i] = target
        self._manual(here, end, speed, PlannerState.JOGGING)
        self.jog_continuous = msg.distance_mm is None and self.runner is not None
        self._refreshed()

    def _cmd_jog_stop(self, _msg) -> None:
        if self.runner is None or self.runner_kind != PlannerState.JOGGING:
            raise CommandRefused(f"not jogging ({self._state().name})")
        self.runner.stop()

    def _cmd_jog_refresh(self, _msg: JogRefresh) -> None:
        if not (self.runner is not None and self.runner_kind == PlannerState.JOGGING and self.jog_continuous):
            raise CommandRefused(f"no continuous jog to refresh ({self._state().name})")
        self._refreshed()

    def _refreshed(self) -> None:
        self.jog_life = (self.hw_r.read_dict()["tick"], time.monotonic_ns())

    def _deadman(self) -> None:
        """A continuous jog whose station has not refreshed it in time stops (on both clocks)."""
        if not (self.jog_continuous and self.runner is not None and self.runner_kind == PlannerState.JOGGING):
            return
        tick, ns = self.jog_life
        if self.runner.state == RunState.RUNNING and (self.hw_r.read_dict()["tick"] - tick > self.deadman[0]
                                                      and time.monotonic_ns() - ns > self.deadman[1]):
            self.runner.stop()
            self.jog_continuous = False
            self._event("jog_stopped", f"the station did not refresh the jog within {self.config.planner.jog_deadman_ms:g} ms "
                        "(dead-man): the jog stopped", 0)

    def _cmd_goto(self, msg: GoTo) -> None:
        self._require_idle("go to a position")
        servo = self._require_servo("go to a position")
        here = list(servo["commanded_mm"])
        end = list(here)
        for name, value in msg.position_mm.items():
            axis = name.lower()
            if axis not in self.config.axis:
                raise CommandRefused(f"no axis {name!r} on this machine (axes: {', '.join(self.config.axis_names)})")
            i = self.config.axis_names.index(axis)
            a = self.config.axis[axis]
            if not servo["homed_mask"] >> i & 1:
                raise CommandRefused(f"axis {axis.upper()} is not homed: home it before moving to a position")
            if not math.isfinite(value) or not a.travel_min_mm <= value <= a.travel_max_mm:
                raise CommandRefused(f"{axis.upper()}{value:g} is outside the travel {a.travel_min_mm:g} to {a.travel_max_mm:g} mm")
            end[i] = float(value)
        feed = math.inf if msg.feed_mm_s is None else msg.feed_mm_s
        if not feed > 0.0:
            raise CommandRefused(f"feed {msg.feed_mm_s!r} mm/s must be positive")
        self._manual(here, end, feed, PlannerState.MOVING)

    def _cmd_mdi(self, msg: Mdi) -> Reply:
        """G-code typed by hand, run from where the head stands: on a homed machine, checked as a
        program and against the travel before anything moves, the jet only where the lines ask for
        it and the commander allows it (`jet_refused`), no program stops."""
        self._require_idle("run MDI")
        servo = self._require_servo("run MDI")
        unhomed = [a.upper() for i, a in enumerate(self.config.axis_names) if not servo["homed_mask"] >> i & 1]
        if unhomed:
            raise CommandRefused(f"MDI needs a homed machine: home {', '.join(unhomed)} first")
        if self.override <= 0.0:
            raise CommandRefused("the feed override is 0 %: raise it before running MDI")
        start = tuple(servo["commanded_mm"])
        try:
            program = self._on_helper(lambda: self._interpret_mdi(msg.text, start))
        except GCodeError as exc:
            return Reply(False, str(exc), [ProgramDiagnostic(exc.line, exc.column, exc.message,
                                                                 (exc.source_line or "").rstrip("\r\n"))])
        stops = [m for m in program.messages if m.kind in _PROGRAM_STOPS]
        if stops:
            raise CommandRefused(f"{MDI_NAME}:{stops[0].line}: {_PROGRAM_STOPS[stops[0].kind]} cannot run by hand: "
                                 "there is no cycle start in MANUAL to go on with")
        try:
            preflight(program.segments, self.config, dict.fromkeys(self.config.axis_names, True), MDI_NAME)
        except PreflightError as exc:
            raise CommandRefused(str(exc)) from None
        jet = program.segments["jet"]
        if jet.any() and msg.jet_refused:
            line = int(program.segments["line"][int(np.argmax(jet))])
            raise CommandRefused(f"{MDI_NAME}:{line}: the jet would be open on this line, but {msg.jet_refused}")
        if not len(program.segments):
            return Reply(True, "nothing to move: the lines hold no motion or dwell")
        self._begin(ProgramRunner(None, self.config, steps=StepSource(iter_steps(program, self.config))), PlannerState.MDI)
        return Reply(True, f"running {program.stats.lines} line{'s' if program.stats.lines != 1 else ''} by hand"
                     + (", the jet opens where they ask" if jet.any() else ""))

    def _interpret_mdi(self, text: str, start: tuple) -> Program:
        """An MDI entry interpreted from `start` with the machine's dialect; an endless loop typed by
        hand is refused after MDI_INTERPRET_S, not the minutes a program may take."""
        dialect = dataclasses.replace(dialect_for(self.config), start_position_mm=_xyz(self.config, start),
                                      max_seconds=min(self.config.gcode.interpret_timeout_s, MDI_INTERPRET_S))
        # lines typed by hand end where they end: the program end a file needs is implied (after
        # an M2 of their own the interpreter reads no further)
        return Interpreter(dialect, MDI_NAME).run((text.rstrip("\r\n") + "\nM2\n").encode("utf-8"))

    def _cmd_home(self, msg: Home) -> None:
        self._require_idle("home")
        self._require_servo("home")
        axes = [a.lower() for a in msg.axes] or list(self.config.axis_names)
        for a in axes:
            if a not in self.config.axis:
                raise CommandRefused(f"no axis {a!r} on this machine (axes: {', '.join(self.config.axis_names)})")
        self.homing_obj = Homing(self.config, self.hw_r.read_dict, self.servo_r.read_dict)
        self.homing = self.homing_obj.steps(axes)
        self.waiting_for = None
        self.motion_epoch = self.servo_r.read_dict()["motion_epoch"]
        self._set(state=int(PlannerState.HOMING))

    # -- starting and ending motion ------------------------------------------------------------
    def _manual(self, here: list[float], end: list[float], feed: float, kind: PlannerState) -> None:
        xyz = lambda p: tuple(float(p[self.config.axis_names.index(a)]) if a in self.config.axis else 0.0 for a in "xyz")  # noqa: E731
        steps = move_steps(xyz(here), xyz(end), feed, self.config)
        if not steps:
            return
        self._begin(ProgramRunner(None, self.config, steps=steps), kind)

    def _begin(self, runner: ProgramRunner, kind: PlannerState) -> None:
        self.restart = None
        if kind in _PROGRAMS:
            runner.set_override(self.override)
        if hasattr(runner, "solves_ahead"):
            runner.solves_ahead = True  # the worker solves the programmed corners ahead (`_plan_ahead`)
        self.runner, self.runner_kind = runner, kind
        self.motion_epoch = self.servo_r.read_dict()["motion_epoch"]
        self.jog_continuous = False
        self.run_first = self.fifo.head()
        self.into_carry = (-1, 0.0)
        self.track_fill = False
        self._set(state=int(kind), fifo_min_fill=-1, segment=-1, line=0, done_mm=0.0, segment_mm=-1.0,
                  pierce_s=runner.pierce_s)

    def _end_run(self, result: RunResult) -> None:
        self._progress(self.servo_r.read_dict())
        if self.runner_kind == PlannerState.RUNNING:
            self._set(run_result=int(result), run_end_tick=self.hw_r.read_dict()["tick"], eta_s=0.0)
            if result == RunResult.DONE:  # the last setpoints sampled may end short of the path's last mm
                self._set(done_mm=self.out.get("total_mm"))
        self.runner, self.runner_kind, self.restart = None, PlannerState.IDLE, None
        self._cancel_restart_timing()  # the run it would time has ended
        self._set(state=int(PlannerState.IDLE))

    def _cancel_restart_timing(self) -> None:
        if self.restart_timing is not None:
            self.restart_timing.cancel()
            self.restart_timing = None

    def _fail(self, why: str, report: bool = True) -> None:
        """Stop what runs (the servo has dropped the setpoints when it tripped) and say why; with
        `report`, as a failure the commander raises an alarm for (error_seq)."""
        self.homing = self.homing_obj = None
        self._set(homing_axis=-1)
        if self.runner is not None:
            self._end_run(RunResult.FAULT)
        self._set(state=int(PlannerState.IDLE), error=why)
        if report:
            self._set(error_seq=self.out.get("error_seq") + 1)
        log.error("planner: %s", why)

    # -- each wake --------------------------------------------------------------------------
    def on_tick(self) -> None:
        servo = self.servo_r.read_dict()
        busy = self.runner is not None or self.homing is not None
        void = busy and servo["motion_epoch"] != self.motion_epoch
        if busy and (servo["state"] in (ServoState.FAULT, ServoState.DISABLED) or void):
            names = self.config.axis_names
            axis = f" on axis {names[servo['fault_axis']].upper()}" if 0 <= servo["fault_axis"] < len(names) else ""
            why = (f"the servo tripped ({ServoFault(servo['fault']).name}{axis})" if servo["state"] == ServoState.FAULT
                   else "the drives were disabled" if servo["state"] == ServoState.DISABLED
                   else "the servo ended it (a trip, a reset or the drives)")
            # the servo's own trip, or a stop the commander had it make, is reported by the commander;
            # not a program failure (the drives switched off under a motion is one)
            self._fail(f"motion stopped: {why}", report=servo["state"] == ServoState.DISABLED)
        elif self.homing is not None:
            self._step_homing(servo)
        elif self.runner is not None:
            self._deadman()
            self._feed(servo)
        self._progress(servo)

    def _feed(self, servo: dict) -> None:
        runner = self.runner
        fill = self.fifo.fill()
        producing = not runner.idle
        if producing and self.track_fill:
            low = self.out.get("fifo_min_fill")
            self._set(fifo_min_fill=fill if low < 0 else min(low, fill))
        if fill < self.low and producing and not self._stalled():
            records, done = runner.take(self.high - fill)
            self._push(records, done)
            self.track_fill = len(records) > 0 and not runner.idle
            self.plan_wanted.set()
        elif runner.idle:
            records, done = runner.take(0)  # the record that leaves the servo at rest, if one is due
            self._push(records, done)
        for event in runner.events:
            self._event(event.kind, event.text, event.line)
        runner.events.clear()
        self._publish_state()
        if runner.finished and self.fifo.fill() == 0 and servo["state"] not in (ServoState.TRACKING, ServoState.STOPPING):
            self._end_run(RunResult.DONE if runner.state == RunState.DONE else RunResult.ABORTED)

    def _stalled(self) -> bool:
        """Simulated starvation (the sim block's `planner_stall`): the planner produces nothing, as
        if it had no CPU; the FIFO runs dry and the controller's reaction can be tested."""
        return bool(self.config.board.kind == "sim" and self.sim_r.read()[0][self._i_stall])

    def _push(self, records: np.ndarray, done: np.ndarray) -> None:
        if not len(records):
            return
        records["epoch"] = self.motion_epoch & 0xFFFF_FFFF
        into, self.into_carry = into_segments(records["segment"], done, self.into_carry,
                                              self.restart.into_mm if self.restart is not None else None)
        if self.restart is not None:  # a run from inside the program: its segments as the program's
            records["segment"] = self.restart.original_segment(records["segment"])
        head = self.fifo.head()
        taken = self.fifo.push(records)
        if taken != len(records):  # cannot happen: bursts never exceed the room left
            raise RuntimeError(f"the FIFO took {taken} of {len(records)} records")
        idx = (head + np.arange(taken)) % self.fifo.capacity
        self.ring_done[idx], self.ring_segment[idx], self.ring_line[idx] = done, records["segment"], records["line"]
        self.ring_into[idx] = into
        self.last_pushed = records[-1]
        self._set(records_pushed=self.out.get("records_pushed") + taken)

    def _publish_state(self) -> None:
        if self.runner is None:
            return
        state = self.runner_kind
        if self.runner_kind == PlannerState.RUNNING and self.runner.state in _RUN_STATES:
            state = _RUN_STATES[self.runner.state]
        self._set(state=int(state))

    def _progress(self, servo: dict) -> None:
        if self.runner is None or self.runner_kind != PlannerState.RUNNING:
            return
        consumed = self.fifo.tail()
        if consumed > self.run_first:
            k = (consumed - 1) % self.fifo.capacity
            self._set(done_mm=float(self.ring_done[k]), segment=int(self.ring_segment[k]), line=int(self.ring_line[k]),
                      segment_mm=float(self.ring_into[k]))
        eta = self.runner.remaining_s() + self.fifo.fill() * self.dt
        self._set(eta_s=eta if math.isfinite(eta) else -1.0)

    # -- homing -----------------------------------------------------------------------------
    def _step_homing(self, servo: dict) -> None:
        """Homing's next steps: chunks pushed until the FIFO holds its lead (several in one wake
        where the planner's period is longer than a chunk: one a wake would run it dry), then the
        reference, the settle."""
        while True:
            if self.waiting_for is not None:
                kind = self.waiting_for[0]
                # the next chunk once this one has nearly run: never more than the lead ahead, whatever
                # the FIFO's lead (`fifo_low_ms`), so that the switches are seen within it
                if kind == "drain" and self.fifo.fill() > min(self.low, self.homing_lead):
                    return
                if kind == "reference" and (servo["position_ref_seq"] != self.waiting_for[1] or self.fifo.fill()):
                    return
                if kind == "settle" and (self.fifo.fill() or servo["state"] == ServoState.TRACKING):
                    return
                self.waiting_for = None
            try:
                step = next(self.homing)
            except StopIteration:
                self.homing = self.homing_obj = None
                self._set(state=int(PlannerState.IDLE), homing_axis=-1)
                return
            except HomingError as exc:
                self.homing = self.homing_obj = None
                self._fail(str(exc))
                return
            self._set(homing_axis=self.homing_obj.axis)
            if isinstance(step, Push):
                self._push(step.records, np.zeros(len(step.records)))
                self.waiting_for = ("drain",)
                continue  # and the next chunk now, while the FIFO is short of its lead
            if isinstance(step, Reference):
                self.waiting_for = ("reference", self._reference(step))
            elif isinstance(step, Unhome):
                self.waiting_for = ("reference", self._unhome(step.axis))
            else:
                self.waiting_for = ("settle",)
            return

    def _reference(self, step: Reference) -> int:
        counts = list(self.out.get("position_ref_counts"))
        mm = list(self.out.get("position_ref_mm"))
        counts[step.axis], mm[step.axis] = int(step.counts), float(step.position_mm)
        seq = self.out.get("position_ref_seq") + 1
        self._set(position_ref_counts=counts, position_ref_mm=mm, position_ref_mask=1 << step.axis, position_ref_unhome=0,
                  position_ref_seq=seq)
        return seq

    def _unhome(self, axis: int) -> int:
        seq = self.out.get("position_ref_seq") + 1
        self._set(position_ref_mask=0, position_ref_unhome=1 << axis, position_ref_seq=seq)
        return seq

    def _abort_homing(self, why: str) -> None:
        """Stop homing: bring the moving axis to rest (jerk-limited) and report why."""
        last, homing = self.last_pushed, self.homing_obj
        self.homing = self.homing_obj = None
        if last is not None and homing is not None and homing.axis >= 0:
            i = homing.axis
            chunk, _ = homing._ramp(i, list(last["position"]), float(last["velocity"][i]), 0.0, None)
            self._push(chunk, np.zeros(len(chunk)))
        self._set(state=int(PlannerState.IDLE), homing_axis=-1, error_seq=self.out.get("error_seq") + 1, error=f"homing {why}")

    # -----------------------------------------------------------------------------------
    def _event(self, kind: str, text: str, line: int) -> None:
        self._set(event_seq=self.out.get("event_seq") + 1, event=f"{kind}: {text}" + (f" (line {line})" if line else ""))

    def _set(self, **values) -> None:
        for key, value in values.items():
            self.out.set(key, value)
        self.out.publish()


def cut_setup_of(msg: SetCut | None) -> CutSetup | None:
    """The operator's cutting job from its message (None: the program's own)."""
    if msg is None or not msg.material:
        return None
    return CutSetup(msg.material, float(msg.thickness_mm), int(msg.quality), msg.mode, int(msg.pierce_quality))


def _same_start(a: tuple, b: tuple) -> bool:
    """Whether two starts (one value per machine axis) are the same place: a program interpreted
    from one runs unchanged from the other."""
    return all(abs(x - y) <= 1e-6 for x, y in zip(a, b))


def _homed(config: MachineConfig, servo: dict) -> dict[str, bool]:
    """Which of the machine's axes the servo's state says are homed."""
    return {a: bool(servo["homed_mask"] >> i & 1) for i, a in enumerate(config.axis_names)}


def _xyz(config: MachineConfig, values) -> tuple[float, float, float]:
    """Machine-axis values as (x, y, z), 0 for an axis the machine does not have."""
    xyz = [0.0, 0.0, 0.0]
    for name, value in zip(config.axis_names, values):
        xyz["xyz".index(name)] = float(value)
    return tuple(xyz)


def _beyond(axis, position: float) -> float:
    """How far `position` lies beyond the axis' travel (0 inside)."""
    return max(axis.travel_min_mm - position, position - axis.travel_max_mm, 0.0)
