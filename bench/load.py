#!/usr/bin/env python3
"""Load benchmark: servo timing and status rate with 50 observers, a 1M-line upload and its preview.

Starts the whole controller (PLC simulator included) on the real-time clock and runs the same
automatic cycle twice, each on a fresh controller, with the cut (a nest of rounded rectangles
with corner arcs and CAM-style polylines, about `--cut-seconds` long) as the measured window:

- unloaded: one observer session (status, position and alarm events, decoded as an HMI does);
  after the cycle, an idle window of `--idle-seconds` with the table holding;
- loaded: `--observers` sessions in OBSERVER_PROCESSES processes of their own, and an operator
  screen's connection with its contour view (offscreen Qt) in another process. During the cut
  the `--lines` program (bench/gcode_speed.py's CAM polylines) is uploaded: the gateway checks
  and interprets all of it, and the control logic refuses to take it while cutting (a program is
  taken between cycles). After the cycle it is uploaded again and loaded by the planner, and the
  screen previews it (fetches the interpreted path when the status names the program, draws the
  contour); that load and preview is the loaded run's second window.

The observers and the screen stand for other hosts (HMIs, `waterjet watch`): their processes run
at nice OBSERVER_NICE, so that their own decoding and drawing yields to the controller as it would
on a host of its own, while what they cost the controller (the router's fan-out to 50 sessions,
the gateway's answers, the program's path) stays on this one.

Each window reports the servo's own timing as servo_timing.py measures it (tick wake latency
of the hardware server, tick-to-speed-command latency of the servo, from the controller's 1 us
histograms; overruns, underruns, late and missed ticks) and the status messages per second one
observer received. The loaded figures are printed beside the unloaded ones with their ratio,
then the large program's upload, load and preview times and what every observer received
(status sequence gaps, alarm events missed against the history's sequence numbers).

    .venv/bin/python bench/load.py [--observers 50] [--lines 1000000] [--cut-seconds 30]
                                   [--idle-seconds 30] [--json OUT]

Exits 1 when the controller fails (a process lost, a servo fault, the drive watchdog); the
figures measured up to the failure are printed with it.
"""

from __future__ import annotations

import argparse
import faulthandler
import hashlib
import json
import logging
import math
import multiprocessing
import os
import queue
import sys
import tempfile
import threading
import time
import tomllib
from concurrent.futures import Future
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, TypeVar

import msgspec
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from gcode_speed import million_line_program  # noqa: E402
from servo_timing import BenchError, Latency, Snapshot, check_healthy, on_free_port, summarize, system_text  # noqa: E402
from servo_timing import window_counters  # noqa: E402

from cnc.bus.keys import Keys  # noqa: E402
from cnc.bus.messages import AlarmEvent, CycleStart, Home, Position, Reply, Reset, SetMode, Status, decode  # noqa: E402
from cnc.bus.operator import OperatorStation  # noqa: E402
from cnc.bus.session import connect_endpoints, open_client  # noqa: E402
from cnc.config import ConfigError, MachineConfig, load_machine  # noqa: E402
from cnc.data.layout import LinkState, PlannerState, ServoState  # noqa: E402
from cnc.logic.states import CyclePhase, MachineState  # noqa: E402
from cnc.runtime.supervisor import Supervisor, SupervisorError  # noqa: E402
from plc_link.sim_model import PlantTimes  # noqa: E402

DEFAULT_MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"
T = TypeVar("T")
BRISK_PLANT = PlantTimes(feed_s=1.0, gripper_s=0.3, unload_s=1.0)  # the demo's: the cycle's time goes to cutting
OBSERVER_PROCESSES = 2  # the observer sessions are shared out over this many processes
CUT_FEED_MM_MIN = 6000.0
SETTLE_S = 2.0  # after the program is loaded, before the cycle starts
UPLOAD_DELAY_S = 2.0  # into the loaded cut, before the large program is sent
START_TIMEOUT_S = 120.0  # observer and preview processes up, on a busy 2-core machine
RESULT_TIMEOUT_S = 120.0  # for the observers' reports once they are told to stop
OBSERVER_NICE = 10  # observers and the screen stand for other hosts: their own work yields to the controller's
UPLOAD_TIMEOUT_S = 900.0  # how long the bench's station waits for an upload's reply
LOAD_TIMEOUT_S = 900.0  # until the planner has the large program
PREVIEW_TIMEOUT_S = 300.0  # until the screen has drawn it
CYCLE_TIMEOUT_S = 600.0
ATTEMPTS = 3  # homing or a cycle that faults (this machine is shared) is noted, reset and done again
RECOVER_TIMEOUT_S = 60.0
STATION = "load-bench"
PREVIEW_STATION = "load-preview"


# -- the programs ------------------------------------------------------------------------------


def cut_program(seconds: float) -> str:
    """A nest of parts cut at F6000 for about `seconds` (the pierces come on top): each unit is a
    200 x 120 mm rectangle with R15 corner arcs and a 100-chord sine strap above it, laid out on a
    grid inside the travel (repeated in place when the grid is full)."""
    feed_mm_s = CUT_FEED_MM_MIN / 60.0
    unit_mm = 2 * (170 + 90) + 2 * math.pi * 15 + 250  # rectangle perimeter + strap, about
    units = max(1, math.ceil(seconds * feed_mm_s / unit_mm))
    out = ["(load.py: a nest of rectangles and straps)", "G21 G90 G17", "G64 P0.05", f"F{CUT_FEED_MM_MIN:g}"]
    for k in range(units):
        x, y = 100.0 + 260.0 * (k % 5), 100.0 + 260.0 * (k // 5 % 4)
        out += _rounded_rectangle(x, y, 200.0, 120.0, 15.0) + _strap(x, y + 190.0, 200.0, 25.0, 100)
    out += ["G0 X50 Y50", "M2"]
    return "\n".join(out) + "\n"


def _rounded_rectangle(x: float, y: float, w: float, h: float, r: float) -> list[str]:
    return [
        f"G0 X{x + r:.3f} Y{y:.3f}", "M3",
        f"G1 X{x + w - r:.3f} Y{y:.3f}", f"G3 X{x + w:.3f} Y{y + r:.3f} I0 J{r:.3f}",
        f"G1 X{x + w:.3f} Y{y + h - r:.3f}", f"G3 X{x + w - r:.3f} Y{y + h:.3f} I{-r:.3f} J0",
        f"G1 X{x + r:.3f} Y{y + h:.3f}", f"G3 X{x:.3f} Y{y + h - r:.3f} I0 J{-r:.3f}",
        f"G1 X{x:.3f} Y{y + r:.3f}", f"G3 X{x + r:.3f} Y{y:.3f} I{r:.3f} J0", "M5",
    ]


def _strap(x: float, y: float, length: float, amplitude: float, chords: int) -> list[str]:
    """A sine wave in short chords, as a CAM system approximates a spline."""
    points = [(x + length * k / chords, y + amplitude * math.sin(2 * math.pi * k / chords)) for k in range(chords + 1)]
    return [f"G0 X{points[0][0]:.3f} Y{points[0][1]:.3f}", "M3",
            *(f"G1 X{px:.3f} Y{py:.3f}" for px, py in points[1:]), "M5"]


# -- observer sessions (their own processes) ----------------------------------------------------


@dataclass(frozen=True)
class SessionSummary:
    """What one observer session received over its subscription."""

    statuses: int
    status_gaps: int  # status sequence numbers skipped between its first and last status
    positions: int
    alarm_seqs: list[int]
    status_times: list[tuple[int, int]]  # (published, received) wall clock ns; the measuring session only


@dataclass
class SessionLog:
    """One observer session's subscriptions, decoding every message as an HMI would."""

    measuring: bool
    status_seqs: list[int] = field(default_factory=list)
    status_times: list[tuple[int, int]] = field(default_factory=list)
    positions: int = 0
    alarm_seqs: list[int] = field(default_factory=list)

    def on_status(self, sample: Any) -> None:
        received_ns = time.time_ns()
        status = decode(sample.payload.to_bytes(), Status)
        self.status_seqs.append(status.seq)
        if self.measuring:
            self.status_times.append((status.stamp_ns, received_ns))

    def on_position(self, sample: Any) -> None:
        decode(sample.payload.to_bytes(), Position)
        self.positions += 1

    def on_alarm(self, sample: Any) -> None:
        self.alarm_seqs.append(decode(sample.payload.to_bytes(), AlarmEvent).seq)

    def summary(self) -> SessionSummary:
        seqs = sorted(set(self.status_seqs))
        gaps = seqs[-1] - seqs[0] + 1 - len(seqs) if seqs else 0
        return SessionSummary(len(self.status_seqs), gaps, self.positions, sorted(self.alarm_seqs), list(self.status_times))


def observers_main(endpoints: list[str], prefix: str, machine: str, sessions: int, measuring: bool,
                   ready: Any, stop: Any, results: Any, group: int) -> None:
    """`sessions` observer sessions, each its own Zenoh client session subscribed to status, position
    and alarm events; ready once every one has received a status; reports what each received at `stop`."""
    faulthandler.enable()  # a crash in a session's native code leaves its traceback
    os.nice(OBSERVER_NICE)
    for kind in (Status, Position, AlarmEvent):
        # msgspec builds a type's decoding info at its first use: here, once, rather than in many
        # sessions' callback threads at the same moment (two observer processes died in msgspec's
        # first decode of a Status that way, SIGSEGV, under this machine's load)
        msgspec.json.Decoder(kind)
    keys = Keys(prefix, machine)
    logs = [SessionLog(measuring and i == 0) for i in range(sessions)]
    opened: list[tuple[Any, list[Any]]] = []
    try:
        for log_ in logs:
            session = open_client(endpoints)
            subs = [session.declare_subscriber(keys.status, log_.on_status),
                    session.declare_subscriber(keys.position, log_.on_position),
                    session.declare_subscriber(keys.event_alarm, log_.on_alarm)]
            opened.append((session, subs))
        deadline = time.monotonic() + START_TIMEOUT_S
        while not all(log_.status_seqs for log_ in logs) and time.monotonic() < deadline:
            time.sleep(0.01)
        ready.set()
        stop.wait()
    except Exception as exc:  # reported to the bench, which fails naming it
        results.put((group, [], f"{type(exc).__name__}: {exc}"))
        ready.set()
        return
    finally:
        for session, subs in opened:
            for sub in subs:
                sub.undeclare()
            session.close()
    results.put((group, [log_.summary() for log_ in logs], ""))


class Observers:
    """`count` observer sessions in up to OBSERVER_PROCESSES processes; session 0 measures the status rate."""

    def __init__(self, sup: Supervisor, count: int) -> None:
        ctx = multiprocessing.get_context("spawn")
        self.stop, self.results = ctx.Event(), ctx.Queue()
        endpoints = connect_endpoints(sup.config.zenoh.listen)
        shares = [len(part) for part in np.array_split(np.arange(count), min(count, OBSERVER_PROCESSES))]
        self.readies = [ctx.Event() for _ in shares]
        self.processes = [
            ctx.Process(target=observers_main, name=f"load-observers{g}", daemon=True,
                        args=(endpoints, sup.keys.prefix, sup.keys.machine, n, g == 0, ready, self.stop, self.results, g))
            for g, (n, ready) in enumerate(zip(shares, self.readies))
        ]
        for p in self.processes:
            p.start()

    def wait_ready(self, sup: Supervisor) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        for p, ready in zip(self.processes, self.readies):
            while not ready.wait(0.05):
                supervise(sup)
                if not p.is_alive() or time.monotonic() > deadline:
                    raise BenchError(f"observer process {p.name} did not come up (exit code {p.exitcode})")

    def collect(self) -> list[SessionSummary]:
        """Stop every session; what each received, in group order."""
        self.stop.set()
        groups: dict[int, list[SessionSummary]] = {}
        try:
            for _ in self.processes:
                group, summaries, error = self.results.get(timeout=RESULT_TIMEOUT_S)
                if error:
                    raise BenchError(f"observer process {group} failed: {error}")
                groups[group] = summaries
        except queue.Empty:
            silent = [f"{p.name} ({'alive' if p.is_alive() else f'exit code {p.exitcode}'})"
                      for g, p in enumerate(self.processes) if g not in groups]
            raise BenchError(f"no report within {RESULT_TIMEOUT_S:g} s from {', '.join(silent)}") from None
        finally:
            self.kill()
        return [s for g in sorted(groups) for s in groups[g]]

    def kill(self) -> None:
        """Wait a little for the processes to end, then kill those still there."""
        self.stop.set()
        for p in self.processes:
            p.join(10.0)
            if p.is_alive():
                p.kill()

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self.processes]


def supervise(sup: Supervisor) -> None:
    """Supervise once; only a process lost for good fails (during set-up the drives are off, and a
    drive watchdog trip is cleared by the operator's reset: `Run.notes` says when there was one)."""
    sup.poll()
    if sup.failed:
        raise SupervisorError(sup.failed)


# -- the operator screen's preview (its own process) --------------------------------------------


@dataclass(frozen=True)
class Preview:
    """One program previewed by the operator screen."""

    name: str
    hash: str
    segments: int  # in the screen's model
    fetch_s: float  # from the first status naming the program until its path was in the model
    draw_s: float  # contour built, fitted and rendered (set_path + fit + grab)


def preview_main(endpoints: list[str], prefix: str, machine: str, travel: tuple[float, float, float, float],
                 ready: Any, stop: Any, results: Any) -> None:
    """An operator screen's connection and contour view (offscreen): every program the status
    names is fetched with its path by the connection, as the screen does, then drawn; each
    preview's figures go to `results`."""
    faulthandler.enable()
    os.nice(OBSERVER_NICE)
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication

    from hmi.connection import Connection
    from hmi.contour import ContourView
    from hmi.model import MachineModel

    app = QApplication.instance() or QApplication([])
    model = MachineModel(PREVIEW_STATION)
    connection = Connection(model, endpoints, Keys(prefix, machine), PREVIEW_STATION)
    view = ContourView()
    view.resize(1280, 800)
    view.set_travel(*travel)
    view.show()
    connection.start()
    named: dict[str, float] = {}
    try:
        while not stop.is_set():
            status = model.status
            if status is not None and status.program is not None and status.program.hash not in named:
                named[status.program.hash] = time.monotonic()
            program = model.program
            if program is not None and program.path is not None and named.get(program.hash, 0.0) > 0.0:
                fetch_s = time.monotonic() - named[program.hash]
                named[program.hash] = -1.0  # drawn
                t0 = time.perf_counter()
                view.set_path(program.path)
                view.fit()
                view.grab()
                results.put(Preview(program.name, program.hash, program.segments, fetch_s, time.perf_counter() - t0))
            if model.reachable:
                ready.set()
            app.processEvents()
            time.sleep(0.01)
    finally:
        connection.close()
        view.close()


class PreviewProcess:
    """The operator screen's preview in a process of its own."""

    def __init__(self, sup: Supervisor) -> None:
        ctx = multiprocessing.get_context("spawn")
        self.ready, self.stop, self.results = ctx.Event(), ctx.Event(), ctx.Queue()
        x, y = sup.config.axis["x"], sup.config.axis["y"]
        travel = (x.travel_min_mm, x.travel_max_mm, y.travel_min_mm, y.travel_max_mm)
        self.process = ctx.Process(target=preview_main, name="load-preview", daemon=True, args=(
            connect_endpoints(sup.config.zenoh.listen), sup.keys.prefix, sup.keys.machine, travel,
            self.ready, self.stop, self.results))
        self.process.start()

    def wait_ready(self, sup: Supervisor) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self.ready.wait(0.05):
            supervise(sup)
            if not self.process.is_alive() or time.monotonic() > deadline:
                raise BenchError(f"the preview process did not come up (exit code {self.process.exitcode})")

    def wait_for(self, sup: Supervisor, digest: str, timeout_s: float) -> Preview:
        """The preview of the program with this hash, once drawn."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            supervise(sup)
            if not self.process.is_alive():
                raise BenchError(f"the preview process died (exit code {self.process.exitcode})")
            while not self.results.empty():
                preview = self.results.get()
                if preview.hash == digest:
                    return preview
            time.sleep(0.05)
        raise BenchError(f"the operator screen did not preview the program within {timeout_s:g} s")

    def close(self) -> None:
        self.stop.set()
        self.process.join(30.0)
        if self.process.is_alive():
            self.process.kill()


# -- the operator -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Upload:
    """A program sent by the operator station: its reply and how long each stage took."""

    lines: int
    bytes: int
    reply: Reply
    reply_s: float  # from sending until the gateway's reply
    loaded_s: float | None = None  # from sending until the planner had it (None: not loaded)


class Operator:
    """Plays the operator of an automatic run, as the demo does: commands go to the control logic,
    programs through an operator station that holds the command lock, and the transport station's
    button is pressed whenever the transport procedure asks for it."""

    def __init__(self, sup: Supervisor) -> None:
        self.sup = sup
        self.session = open_client(connect_endpoints(sup.config.zenoh.listen))
        self.station = OperatorStation(self.session, sup.keys, STATION, timeout_s=UPLOAD_TIMEOUT_S)
        reply = self.station.take_lock()
        if not reply.ok:
            raise BenchError(f"the command lock: {reply.reason}")

    def close(self) -> None:
        self.station.close()
        self.session.close()

    def ask(self, what: str, command: Any) -> None:
        reply = self.sup.logic.request(command)
        if not reply.ok:
            raise BenchError(f"{what} refused: {reply.reason}")

    def logic(self) -> dict:
        return self.sup.area.reader("logic").read_dict()

    def wait(self, until: Callable[[], bool], timeout_s: float, what: str, faults: list[str] | None = None) -> None:
        """Until `until()`, pressing the transport station's button when asked. A fault fails the
        wait, unless `faults` is given (the machine stands still): then each is noted there once."""
        def step() -> bool:
            if faults is None:
                check_healthy(self.sup)
            else:
                supervise(self.sup)
            lo = self.logic()
            if lo["procedure"] == "transport" and lo["procedure_state"] in ("running", "timed_out"):
                self.sup.plc_sim.press_button()
            if lo["state"] == MachineState.FAULT:
                why = f"the machine went to FAULT while waiting for {what}: {lo['message']}"
                if faults is None:
                    raise BenchError(why)
                if why not in faults:
                    faults.append(why)
            return until()
        self.sup.wait_until(step, timeout_s, what)

    def reset_and_home(self) -> None:
        """Reset (drives on), home, and wait until the machine is READY with the planner idle."""
        self.ask("reset", Reset())
        self.sup.wait_until(lambda: self.sup.servo()["state"] == ServoState.HOLDING, 10.0, "the drives to come on")
        self.ask("home", Home())
        self.wait(lambda: self.logic()["state"] == MachineState.READY and self.sup.motion()["state"] == PlannerState.IDLE,
                  120.0, "homing")

    def recover(self) -> None:
        """After a fault: reset until cycle start is allowed again (READY or STOPPED), homing again (in
        MANUAL, then back to AUTO) only when an axis lost its reference (homing a homed machine trips
        its soft limit); BenchError when the machine does not come back."""
        every_axis = (1 << len(self.sup.config.axis_names)) - 1
        deadline = time.monotonic() + RECOVER_TIMEOUT_S
        while (state := MachineState(self.logic()["state"])) not in (MachineState.READY, MachineState.STOPPED):
            if time.monotonic() > deadline:
                raise BenchError(f"the machine did not come back after a fault: {state.name}, {self.logic()['message']}")
            if state == MachineState.IDLE and self.sup.servo()["homed_mask"] != every_axis:
                self.ask("MANUAL mode", SetMode("MANUAL"))
                self.reset_and_home()
                self.ask("AUTO mode", SetMode("AUTO"))
                continue
            self.sup.logic.request(Reset())  # refused while the stop is still under way: asked again
            settle = time.monotonic() + 0.5
            while time.monotonic() < settle:
                supervise(self.sup)
                time.sleep(0.02)

    def attempt(self, what: str, step: Callable[[], T], notes: list[str], before_retry: Callable[[], None] = lambda: None
                ) -> T:
        """`step()`, and again after a reset when it ends in a fault (ATTEMPTS in all: this machine is
        shared); each fault is noted. A process lost for good, or the last attempt's fault, is raised."""
        for n in range(1, ATTEMPTS + 1):
            try:
                return step()
            except BenchError as exc:
                if n == ATTEMPTS or self.sup.failed:
                    raise
                notes.append(f"{what}, attempt {n}, faulted: {exc}; reset and again")
                before_retry()
                self.recover()
        raise AssertionError("unreachable")

    def send(self, name: str, text: str) -> Future:
        """Upload in the background (the caller keeps supervising); the future's result is an Upload."""
        data = text.encode()
        digest = hashlib.sha256(data).hexdigest()

        result: Future = Future()

        def upload() -> None:
            t0 = time.monotonic()
            try:
                reply = self.station.upload(name, text)
                loaded = time.monotonic() - t0 if self.sup.motion()["program_hash"] == digest else None
                result.set_result(Upload(text.count("\n"), len(data), reply, time.monotonic() - t0, loaded))
            except BaseException as exc:  # the waiting thread gets it from the future
                result.set_exception(exc)
        threading.Thread(target=upload, name=f"upload-{name}", daemon=True).start()  # never holds up an exit
        return result

    def load(self, name: str, text: str, faults: list[str] | None = None) -> Upload:
        """Upload and wait until the planner has the program, even when the reply gave up first
        (`faults`: as for `wait`)."""
        digest = hashlib.sha256(text.encode()).hexdigest()
        t0, seen = time.monotonic(), len(self.sup.events)
        pending = self.send(name, text)

        def loaded() -> bool:
            lost = [e for e in self.sup.events[seen:] if e.startswith("planner process")]
            if lost:
                raise BenchError(f"the planner was lost while loading {name}: {lost[0]}")
            return self.sup.motion()["program_hash"] == digest
        self.wait(loaded, LOAD_TIMEOUT_S, f"the planner to load {name}", faults)
        loaded_s = time.monotonic() - t0
        self.wait(pending.done, UPLOAD_TIMEOUT_S, f"the reply to the upload of {name}", faults)
        return replace(pending.result(), loaded_s=loaded_s)

    def run_cycle(self, during_cut: Callable[[], None] = lambda: None) -> tuple[Snapshot, Snapshot, int, int]:
        """One automatic cycle; `during_cut` is called once the cut has gone on for UPLOAD_DELAY_S.
        Returns the controller's snapshots at the cut's start and end, with their wall clock ns."""
        self.ask("cycle start", CycleStart(cycles=1))
        self.wait(lambda: self.logic()["phase"] == CyclePhase.CUTTING, CYCLE_TIMEOUT_S, "the cut to start")
        before, t0_ns, started = Snapshot.take(self.sup), time.time_ns(), time.monotonic()
        called = False

        def cut_over() -> bool:
            nonlocal called
            if not called and time.monotonic() - started >= UPLOAD_DELAY_S:
                called = True
                during_cut()
            return self.logic()["phase"] != CyclePhase.CUTTING
        self.wait(cut_over, CYCLE_TIMEOUT_S, "the cut to end")
        after, t1_ns = Snapshot.take(self.sup), time.time_ns()
        self.wait(lambda: self.logic()["phase"] == CyclePhase.NONE, CYCLE_TIMEOUT_S, "the cycle to end")
        return before, after, t0_ns, t1_ns


# -- one run ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Window:
    """The controller's timing over one stretch of a run, and the status rate one observer saw."""

    name: str
    seconds: float
    wake: Latency  # tick wake latency (hardware server)
    speed_command: Latency  # tick-to-speed-command latency (servo)
    counters: dict[str, int]
    t0_ns: int
    t1_ns: int
    status_per_s: float = 0.0


def window(name: str, before: Snapshot, after: Snapshot, t0_ns: int, t1_ns: int) -> Window:
    return Window(name, (t1_ns - t0_ns) / 1e9, summarize(after.hw_hist - before.hw_hist),
                  summarize(after.servo_hist - before.servo_hist), window_counters(before, after), t0_ns, t1_ns)


def status_rate(times: list[tuple[int, int]], t0_ns: int, t1_ns: int) -> float:
    """Statuses received per second within [t0_ns, t1_ns)."""
    received = sum(1 for _, recv in times if t0_ns <= recv < t1_ns)
    return received / ((t1_ns - t0_ns) / 1e9)


@dataclass
class Run:
    """Everything one run measured."""

    label: str
    sessions: int
    windows: list[Window] = field(default_factory=list)
    planned_cut_s: float = 0.0
    during_cut: Upload | None = None  # the large program sent during the cut
    load: Upload | None = None  # and after the cycle
    preview: Preview | None = None
    statuses_min: int = 0  # over the sessions
    status_gaps_max: int = 0
    alarms_expected: int = 0  # history entries written while the sessions were subscribed
    alarms_missed: int = 0  # summed over the sessions
    memory_mb: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    failure: str = ""


def measure(config: MachineConfig, sessions: int, cut_seconds: float, big: str | None, idle_s: float) -> Run:
    """One run on a fresh controller: `sessions` observers, the cut, then the idle window (`big`
    None) or the large program's load and preview (a preview process watching throughout)."""
    run = Run("loaded" if big is not None else "unloaded", sessions)
    with tempfile.TemporaryDirectory(prefix="load_bench_") as tmp, ExitStack() as cleanup:
        sup = Supervisor(on_free_port(config), clock="realtime", history_path=Path(tmp) / "history.sqlite",
                         log_level=logging.WARNING, plc_sim_times=BRISK_PLANT)
        cleanup.callback(sup.stop)  # the callbacks run last first: the controller stops last
        observers = preview = None
        first_alarm = 0
        try:
            sup.start()
            sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 30.0, "the PLC link")
            time.sleep(SETTLE_S)  # the controller's own start-up is over (see servo_timing.SETTLE_S)
            observers = Observers(sup, sessions)
            cleanup.callback(observers.kill)
            if big is not None:
                preview = PreviewProcess(sup)
                cleanup.callback(preview.close)
            observers.wait_ready(sup)
            if preview is not None:
                preview.wait_ready(sup)
            if sup.hw()["watchdog_tripped"]:
                run.notes.append(f"the drive watchdog tripped at tick {sup.hw()['watchdog_trip_tick']} while the "
                                 f"observer{' and preview' if preview else ''} processes started (drives off; reset)")
            first_alarm = sup.area.reader("logic").read_dict()["alarm_seq"]
            operator = Operator(sup)
            cleanup.callback(operator.close)
            _cycle_and_after(sup, operator, run, preview, cut_seconds, big, idle_s)
        except (BenchError, SupervisorError, TimeoutError) as exc:
            run.failure = str(exc)
        if observers is not None:
            try:
                _observers_done(sup, observers, run, first_alarm)
            except BenchError as exc:
                run.failure = "; ".join(filter(None, (run.failure, str(exc))))
        if preview is not None:
            run.memory_mb["preview (screen)"] = rss_mb(preview.process.pid, "VmHWM")
    return run


def _cycle_and_after(sup: Supervisor, operator: Operator, run: Run, preview: PreviewProcess | None,
                     cut_seconds: float, big: str | None, idle_s: float) -> None:
    """Home, load the cut, run the cycle (sending `big` during the cut), then the second window."""
    operator.attempt("homing", operator.reset_and_home, run.notes)
    cut = cut_program(cut_seconds)
    operator.load("load_cut.ngc", cut)
    sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 600.0, "the cut's cycle time to be planned")
    run.planned_cut_s, cut_hash = sup.motion()["planned_s"], sup.motion()["program_hash"]
    operator.ask("AUTO mode", SetMode("AUTO"))
    time.sleep(SETTLE_S)
    pending: list[Future] = []

    def cycle() -> tuple[Snapshot, Snapshot, int, int]:
        if sup.motion()["program_hash"] != cut_hash:  # the large program came in after a fault
            operator.load("load_cut.ngc", cut)
        pending.clear()
        return operator.run_cycle((lambda: pending.append(operator.send("load_big.ngc", big))) if big else lambda: None)

    def upload_answered() -> None:
        if pending:
            operator.wait(pending[0].done, UPLOAD_TIMEOUT_S, "the reply to the upload during the cut", faults=[])
    before, after, t0_ns, t1_ns = operator.attempt("the cycle", cycle, run.notes, upload_answered)
    run.windows.append(window("cut", before, after, t0_ns, t1_ns))
    if pending:
        operator.wait(pending[0].done, UPLOAD_TIMEOUT_S, "the reply to the upload during the cut")
        run.during_cut = pending[0].result()
    before, t0_ns = Snapshot.take(sup), time.time_ns()
    if big is None:
        _hold(sup, idle_s)
        name = "idle, holding"
    else:
        run.load = operator.load("load_big.ngc", big, faults=run.notes)  # the machine stands still: noted
        run.preview = preview.wait_for(sup, hashlib.sha256(big.encode()).hexdigest(), PREVIEW_TIMEOUT_S)
        name = f"{run.load.lines // 1000}k-line load + preview"
        for proc in ("planner", "gateway"):
            run.memory_mb[proc] = rss_mb(sup.children[proc].process.pid, "VmHWM")
    run.windows.append(window(name, before, Snapshot.take(sup), t0_ns, time.time_ns()))


def _hold(sup: Supervisor, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        check_healthy(sup)
        time.sleep(0.02)


def _observers_done(sup: Supervisor, observers: Observers, run: Run, first_alarm: int) -> None:
    """Collect what every session received: status rate per window, gaps, alarm events missed."""
    last_alarm = sup.area.reader("logic").read_dict()["alarm_seq"]
    time.sleep(0.5)  # the last events are on their way
    summaries = observers.collect()
    expected = set(range(first_alarm + 1, last_alarm + 1))
    measuring = summaries[0].status_times
    run.windows = [replace(w, status_per_s=status_rate(measuring, w.t0_ns, w.t1_ns)) for w in run.windows]
    run.statuses_min = min(s.statuses for s in summaries)
    run.status_gaps_max = max(s.status_gaps for s in summaries)
    run.alarms_expected = len(expected)
    run.alarms_missed = sum(len(expected - set(s.alarm_seqs)) for s in summaries)


def machine_overrides(settings: list[str]) -> dict[str, Any]:
    """`--set key=value` options as load_machine's overrides, each value a TOML literal
    (`plc.cycle_ms=100`, `gateway.status_rate_hz=50.0`, `zenoh.listen=["tcp/0.0.0.0:7447"]`)."""
    out: dict[str, Any] = {}
    for setting in settings:
        key, sep, value = setting.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--set {setting!r}: expected key=value")
        try:
            out[key.strip()] = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"--set {setting!r}: the value is not a TOML value: {exc}") from None
    return out


def rss_mb(pid: int, field_name: str = "VmRSS") -> float:
    """A process's resident memory (VmRSS) or its peak (VmHWM) from /proc, in MB; 0 when it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field_name + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


# -- report -------------------------------------------------------------------------------------

LABEL = 44


def _ratio(loaded: float, unloaded: float) -> str:
    return f"{loaded / unloaded:.2f}" if unloaded > 0 else "-"


def _row(label: str, unloaded: float | None, loaded: float | None, fmt: str = "{:.0f}") -> str:
    cells = "".join(f"{fmt.format(v) if v is not None else '-':>12}" for v in (unloaded, loaded))
    ratio = _ratio(loaded, unloaded) if unloaded is not None and loaded is not None else "-"
    return f"{label:<{LABEL}}{cells}{ratio:>8}"


WINDOW_ROWS: tuple[tuple[str, Callable[[Window], float], str], ...] = (
    ("  window, s", lambda w: w.seconds, "{:.1f}"),
    *((f"  tick wake latency {p}, us", lambda w, k=k: getattr(w.wake, k), "{:.0f}")
      for p, k in (("p50", "p50_us"), ("p99", "p99_us"), ("max", "max_us"))),
    *((f"  tick-to-speed-command {p}, us", lambda w, k=k: getattr(w.speed_command, k), "{:.0f}")
      for p, k in (("p50", "p50_us"), ("p99", "p99_us"), ("max", "max_us"))),
    *((f"  {label}", lambda w, k=k: w.counters[k], "{:.0f}")
      for label, k in (("overruns", "overruns"), ("underruns", "underruns"), ("late ticks", "late_ticks"),
                       ("missed ticks (servo late for board)", "missed_ticks"))),
    ("  status messages/s, one observer", lambda w: w.status_per_s, "{:.1f}"),
)


def window_rows(a: Window | None, b: Window | None) -> list[str]:
    """One window of each run side by side (either may be missing after a failure)."""
    rows = [f"{a.name if a else '-'} / {b.name if b else '-'}"]
    for label, value, fmt in WINDOW_ROWS:
        rows.append(_row(label, value(a) if a else None, value(b) if b else None, fmt))
    return rows


def report(config: MachineConfig, unloaded: Run, loaded: Run) -> str:
    lines = [f"load: machine {config.machine.name!r}, real-time clock, status published at "
             f"{config.gateway.status_rate_hz:g} Hz; {system_text()}",
             f"cut: load_cut.ngc, planned {unloaded.planned_cut_s:.1f} s per cycle (jet on/off included)",
             "", f"{'figure':<{LABEL}}{'unloaded':>12}{'loaded':>12}{'ratio':>8}",
             _row("observer sessions", unloaded.sessions, loaded.sessions)]
    for k in range(max(len(unloaded.windows), len(loaded.windows))):
        lines += window_rows(*(run.windows[k] if k < len(run.windows) else None for run in (unloaded, loaded)))
    lines += [_row("statuses received, fewest of the sessions", unloaded.statuses_min, loaded.statuses_min),
              _row("status seq gaps, worst session", unloaded.status_gaps_max, loaded.status_gaps_max),
              _row("alarm/message events published", unloaded.alarms_expected, loaded.alarms_expected),
              _row("  missed, all sessions together", unloaded.alarms_missed, loaded.alarms_missed), ""]
    lines += big_program_rows(config, loaded)
    for run in (unloaded, loaded):
        lines += [f"{run.label} run: {note}" for note in run.notes]
        if run.failure:
            lines.append(f"{run.label} run FAILED: {run.failure}")
    return "\n".join(lines)


def big_program_rows(config: MachineConfig, run: Run) -> list[str]:
    """The large program's figures, each beside its limit or peer."""
    rows = [f"{'large program':<{LABEL}}{'figure':>12}{'limit/peer':>12}{'ratio':>8}"]
    up = run.during_cut or run.load
    if up is None:
        return rows + ["  not sent"]
    limit = config.gcode.max_program_bytes
    rows.append(f"{'  size, MB (limit: gcode.max_program_bytes)':<{LABEL}}{up.bytes / 1e6:>12.1f}{limit / 1e6:>12.1f}"
                f"{up.bytes / limit:>8.2f}")
    if run.during_cut is not None and run.windows:
        verdict = "accepted" if run.during_cut.reply.ok else f"refused: {run.during_cut.reply.reason}"
        rows.append(f"{'  upload during the cut, checked in s':<{LABEL}}{run.during_cut.reply_s:>12.1f}"
                    f"{run.windows[0].seconds:>12.1f}{run.during_cut.reply_s / run.windows[0].seconds:>8.2f}"
                    f"  (peer: the cut; {verdict})")
    if run.load is not None:
        verdict = "ok" if run.load.reply.ok else run.load.reply.reason
        loaded = run.load.loaded_s or 0.0
        rows.append(f"{'  upload + load by the planner, s':<{LABEL}}{loaded:>12.1f}{run.planned_cut_s:>12.1f}"
                    f"{loaded / run.planned_cut_s:>8.2f}  (peer: one cycle's cut)")
        rows.append(f"{'  the upload reply, after s':<{LABEL}}{run.load.reply_s:>12.1f}{'':>12}{'':>8}  ({verdict})")
    if run.preview is not None:
        p = run.preview
        rows.append(f"{'  preview: path fetched into the model, s':<{LABEL}}{p.fetch_s:>12.1f}")
        rows.append(f"{'  preview: contour drawn, s':<{LABEL}}{p.draw_s:>12.1f}")
        rows.append(f"{'  segments in the screen model':<{LABEL}}{p.segments:>12}{up.lines:>12}"
                    f"{p.segments / up.lines:>8.2f}  (peer: program lines)")
    for name, mb in run.memory_mb.items():
        rows.append(f"{'  peak memory (VmHWM), MB: ' + name:<{LABEL}}{mb:>12.0f}")
    return rows


def to_json(unloaded: Run, loaded: Run) -> dict[str, Any]:
    def one(run: Run) -> dict[str, Any]:
        out = asdict(run)
        for w in out["windows"]:
            w.pop("t0_ns"), w.pop("t1_ns")
        return out
    return {"unloaded": one(unloaded), "loaded": one(loaded)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(DEFAULT_MACHINE), help="machine file (default machines/waterjet.toml)")
    parser.add_argument("--observers", type=int, default=50, help="observer sessions in the loaded run (default 50)")
    parser.add_argument("--lines", type=int, default=1_000_000, help="lines of the large program (default 1000000)")
    parser.add_argument("--cut-seconds", type=float, default=30.0, help="length of the cut, about (default 30)")
    parser.add_argument("--idle-seconds", type=float, default=30.0, help="the unloaded run's idle window (default 30)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a machine-file key (TOML value), e.g. plc.cycle_ms=100; repeatable")
    parser.add_argument("--json", metavar="OUT", help="also write the figures as JSON")
    args = parser.parse_args(argv)
    if args.observers < 1 or args.lines < 10 or args.cut_seconds <= UPLOAD_DELAY_S or args.idle_seconds <= 0:
        parser.error("--observers >= 1, --lines >= 10, --cut-seconds > 2 and --idle-seconds > 0")
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    try:
        config = load_machine(args.machine, machine_overrides(args.set))
    except (ConfigError, ValueError) as exc:
        print(f"load: {exc}", file=sys.stderr)
        return 1
    print(f"load: generating the {args.lines}-line program; two runs of a {args.cut_seconds:g} s cut"
          + (f"; machine file overrides: {', '.join(args.set)}" if args.set else ""), flush=True)
    big = million_line_program(args.lines)
    unloaded = measure(config, 1, args.cut_seconds, None, args.idle_seconds)
    print(f"load: unloaded run done{': FAILED ' + unloaded.failure if unloaded.failure else ''}", flush=True)
    loaded = measure(config, args.observers, args.cut_seconds, big, args.idle_seconds)
    print(report(config, unloaded, loaded))
    if args.json:
        Path(args.json).write_text(json.dumps(to_json(unloaded, loaded), indent=2, default=str) + "\n")
    return 1 if unloaded.failure or loaded.failure else 0


if __name__ == "__main__":
    sys.exit(main())
