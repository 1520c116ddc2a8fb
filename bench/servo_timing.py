#!/usr/bin/env python3
"""Servo timing benchmark: how late the 1 kHz loop runs, next to the machine's own timer latency.

The controller's base tick and servo loop are Python processes under SCHED_FIFO. Whether
that is good enough depends on two numbers: how late the hardware server wakes after each
absolute deadline (tick wake latency) and how long after the deadline the servo has
published its speed command (tick-to-speed-command latency, the delay the drives see).
Neither means much alone: a noisy virtual machine without PREEMPT_RT wakes late for any
program. So the script measures both while the servo does real work (the simulated table
travels across its travel for the whole run), then runs `cyclictest`, the standard C
timer-latency test, with the same period, priority and duration, and reports our
latencies as multiples of the machine's own.

Two producers can keep the table moving (`--feeder`; by default both, one run after the
other, each compared with the same cyclictest run):

- direct: the controller runs without its planner process, and this script pushes a
  repeating tour of point-to-point moves into the setpoint FIFO, 2 s ahead of the servo;
- planner: the whole controller homes and runs a G-code program (the same diagonal tour at
  500 mm/s, a circle, a CAM polyline of short chords and a chain of small arcs); the
  planner process interpolates it and refills the FIFO in bursts between its low and high
  watermarks. This run also reports the lowest FIFO fill the planner saw.

The controller's histograms are taken as the difference between a snapshot after start-up
(see SETTLE_S) and one at the end of the measurement, so start-up is excluded.

    python bench/servo_timing.py [--seconds 30] [--feeder direct|planner|both]
                                 [--machine machines/waterjet.toml] [--json OUT]

Exits 1 only when the controller fails (does not start, loses a process, servo fault, the
planner refuses or abandons the program), never because the figures are high; after a
failure during a measurement the figures gathered up to it are still printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import logging
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cnc.bus.messages import (
    Home, LoadProgram, LogSetting, LogStart, LogState, LogStop, Reply, Start, Stop, decode, encode,
)
from cnc.config import ConfigError, MachineConfig, load_machine
from cnc.sim.demo import free_port
from cnc.data.fifo import SetpointFifo
from cnc.data.layout import ClockKind, PlannerState, ServoFault, ServoState
from cnc.ptp import move_setpoints
from cnc.runtime.supervisor import DIRECT_FEED, MOTION_ONLY, Supervisor, SupervisorError

DEFAULT_MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"
FEEDERS = ("direct", "planner", "logging")
TRACE_VARIABLES = 20  # variables the logging run records at every tick
CYCLICTEST_BINS = 5000  # 1 us bins up to 5 ms, as the controller's own histograms
LEAD_S = 2.0  # how far ahead of the servo the direct feed keeps the FIFO filled
POLL_S = 0.02
# The servo closes the loop while the last processes (gateway, Zenoh sessions) are still
# starting; for about a second after that the loop sees wake-ups several ms late. The
# table holds still through it, so that start-up neither trips the servo nor counts.
# The planner feed also lets its program run this long before measuring.
SETTLE_S = 2.0
TOUR_FRACTIONS = (0.1, 0.9)  # tour points sit at 10 % and 90 % of each axis' travel
HOMING_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 30.0

# The planner feed's program (see busy_program)
PROGRAM_NAME = "servo_timing.ngc"
PROGRAM_FEED_MM_MIN = 30000.0  # 500 mm/s
PROGRAM_TOLERANCE_MM = 0.05  # G64 P0.05
PROGRAM_MARGIN_S = 5.0  # the program runs at least this long past the end of the measurement
FIGURE_FRACTION = 0.25  # circle and flower radius, of the shorter axis' travel
FLOWER_PETALS, FLOWER_DEPTH = 6, 0.15  # r = R (1 + depth sin(petals theta))
FLOWER_CHORDS = 2400  # about 1 mm each, as CAM output approximating a spline
ARC_RADIUS_MM = 20.0
ARC_COUNT = 8  # tangent semicircles, alternately left and right turns


class BenchError(RuntimeError):
    """The controller failed during the run: servo fault, drive watchdog, the planner refused or stopped."""


# ---------------------------------------------------------------------------------------
# histograms


@dataclass(frozen=True)
class Latency:
    """Percentiles of one latency histogram in whole microseconds.

    Bin b of a histogram holds latencies in [b, b+1) us, and the last bin collects
    everything at or beyond it; a figure equal to `overflow_us` therefore reads ">= N us".
    """

    samples: int
    p50_us: int
    p99_us: int
    p999_us: int
    max_us: int
    overflow_us: int


def percentile_us(hist: np.ndarray, fraction: float) -> int:
    """Smallest bin (us) whose cumulative count reaches `fraction` of all samples."""
    cumulative = np.cumsum(hist)
    if cumulative[-1] == 0:
        raise ValueError("empty histogram")
    return int(np.searchsorted(cumulative, fraction * cumulative[-1], side="left"))


def summarize(hist: np.ndarray) -> Latency:
    """p50, p99, p99.9 and max (highest non-empty bin) of a 1 us histogram with an overflow bin."""
    return Latency(
        samples=int(hist.sum()),
        p50_us=percentile_us(hist, 0.50),
        p99_us=percentile_us(hist, 0.99),
        p999_us=percentile_us(hist, 0.999),
        max_us=int(np.flatnonzero(hist)[-1]),
        overflow_us=len(hist) - 1,
    )


def parse_cyclictest(text: str) -> tuple[np.ndarray, int]:
    """Histogram and reported maximum from the output of `cyclictest -h N -q`.

    Lines `000123 000456` give the count of the 123 us bin (summed over the thread
    columns); `# Histogram Overflows:` counts the samples of N us and beyond, which become
    the last bin, as in the controller's histograms. `# Total:` excludes the overflows.
    Returns (histogram, `# Max Latencies` in us).
    """
    bins: dict[int, int] = {}
    overflows = max_us = 0
    for line in text.splitlines():
        fields = line.split()
        if fields and fields[0].isdigit():
            bins[int(fields[0])] = sum(int(f) for f in fields[1:])
        elif line.startswith("# Histogram Overflows:"):
            overflows = sum(int(f) for f in fields[3:])
        elif line.startswith("# Max Latencies:"):
            max_us = max(int(f) for f in fields[3:])
    if not bins:
        raise ValueError("no histogram in the cyclictest output")
    hist = np.zeros(max(bins) + 2, dtype=np.int64)
    for b, count in bins.items():
        hist[b] = count
    hist[-1] = overflows
    return hist, max_us


# ---------------------------------------------------------------------------------------
# the controller under load


@dataclass(frozen=True)
class Snapshot:
    """The controller's cumulative histograms and counters at one moment."""

    hw_hist: np.ndarray
    servo_hist: np.ndarray
    hw: dict[str, Any]
    servo: dict[str, Any]
    motion: dict[str, Any]
    pushed: int  # records pushed into the FIFO since the controller started

    @classmethod
    def take(cls, sup: Supervisor) -> "Snapshot":
        return cls(
            sup.timing("hw_timing")["hist"], sup.timing("servo_timing")["hist"],
            sup.hw(), sup.servo(), sup.motion(), int(sup.fifo.head()),
        )


@dataclass(frozen=True)
class ControllerRun:
    feeder: str  # "direct" or "planner"
    motion: str  # what kept the table moving
    wake: Latency
    speed_command: Latency
    counters: dict[str, int]  # during the measurement window
    realtime_granted: bool
    measured_s: float  # the window the figures cover
    fifo_min_fill: int | None  # planner feed: lowest fill at a refill since the program started (-1: none)
    failure: str = ""  # why the run stopped early; empty when it did not


def tour_points(config: MachineConfig) -> list[tuple[float, ...]]:
    """Four points inside travel: low corner, high corner, then the other diagonal."""
    lo, hi = TOUR_FRACTIONS
    n = len(config.axes)
    patterns = [(lo,) * n, (hi,) * n, (hi,) + (lo,) * (n - 1), (lo,) + (hi,) * (n - 1)]
    return [
        tuple(a.travel_min_mm + f * (a.travel_max_mm - a.travel_min_mm) for a, f in zip(config.axes, fractions))
        for fractions in patterns
    ]


class MotionFeeder:
    """Keeps the FIFO about `lead` records ahead of the servo with a repeating tour of moves.

    Each move ends at rest exactly on its target, and the next one starts there, so the
    servo tracks without a pause; a move once started is always pushed to its end, so the
    FIFO never runs dry in the middle of a motion.
    """

    def __init__(self, fifo: SetpointFifo, first_move: np.ndarray, tour: list[np.ndarray], lead: int) -> None:
        self.fifo, self.lead = fifo, min(lead, fifo.capacity)
        self.pending = first_move
        self.tour = itertools.cycle(tour)
        self.moves_started = 1

    def feed(self, start_new_moves: bool) -> None:
        """Top the FIFO up to the lead; begin the next move of the tour only if `start_new_moves`."""
        while (room := self.lead - self.fifo.fill()) > 0:
            if len(self.pending) == 0:
                if not start_new_moves:
                    return
                self.pending = next(self.tour)
                self.moves_started += 1
            taken = self.fifo.push(self.pending[:room])
            self.pending = self.pending[taken:]
            if taken == 0:
                return

    @property
    def move_finished_pushing(self) -> bool:
        return len(self.pending) == 0


class DirectFeed:
    """This process feeds the FIFO with the tour; the controller runs without its planner."""

    name = "direct"
    processes = DIRECT_FEED
    winding_down = "the last move finished"

    def __init__(self, config: MachineConfig) -> None:
        self.config = config
        self.feeder: MotionFeeder | None = None

    def begin(self, sup: Supervisor) -> None:
        """Plan the tour from where the servo holds; the first feed starts the first move."""
        points = tour_points(self.config)
        tour = [move_setpoints(self.config, a, b) for a, b in zip(points, points[1:] + points[:1])]
        first = move_setpoints(self.config, sup.servo()["commanded_mm"], points[0])
        self.feeder = MotionFeeder(sup.fifo, first, tour, lead=int(LEAD_S * self.config.timing.base_rate_hz))

    def keep_going(self, sup: Supervisor) -> None:
        """Top the FIFO up, starting the next move of the tour whenever one has been pushed."""
        self.feeder.feed(start_new_moves=True)

    def wind_down(self, sup: Supervisor) -> None:
        """Push the move under way to its end, start no other, and wait until the table is at rest."""
        while not self.feeder.move_finished_pushing:
            self.feeder.feed(start_new_moves=False)
            check_healthy(sup)
            time.sleep(POLL_S)
        sup.wait_motion_done(timeout_s=30.0)

    def motion_text(self) -> str:
        return f"{self.feeder.moves_started} moves from rest to rest, pushed {LEAD_S:g} s ahead by this script"

    def fifo_min_fill(self, after: Snapshot) -> int | None:
        return None  # the direct feed keeps the FIFO LEAD_S ahead: its fill is not in question


class PlannerFeed:
    """The whole controller: the planner process runs a G-code program and feeds the FIFO."""

    name = "planner"
    processes = MOTION_ONLY
    winding_down = "the program stopped"

    def __init__(self, config: MachineConfig, seconds: float) -> None:
        self.program = busy_program(config, SETTLE_S + seconds + PROGRAM_MARGIN_S)
        self.error_seq = 0
        self.planned_s = 0.0

    def begin(self, sup: Supervisor) -> None:
        """Home, load and start the program, and let it run for SETTLE_S before the measurement."""
        self.error_seq = sup.motion()["error_seq"]
        ask(sup, Home())
        self.wait_idle(sup, HOMING_TIMEOUT_S, "homing")
        with tempfile.TemporaryDirectory(prefix="servo_timing_") as tmp:
            path = Path(tmp) / PROGRAM_NAME
            path.write_text(self.program.text)
            ask(sup, LoadProgram(str(path)))  # the planner keeps the text: the file may go
        sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 600.0, "the cycle time to be planned")
        self.planned_s = sup.motion()["planned_s"]
        ask(sup, Start())
        supervise(sup, self, until=time.monotonic() + SETTLE_S)

    def keep_going(self, sup: Supervisor) -> None:
        """The program must run through the whole measurement: fail when the planner left it."""
        self.check_no_error(sup)
        state = PlannerState(sup.motion()["state"])
        if state != PlannerState.RUNNING:
            raise BenchError(f"the planner left the program ({state.name}) before the measurement ended")

    def wind_down(self, sup: Supervisor) -> None:
        """Stop the program (the planner brings the table to rest on the path) and wait until the planner is idle."""
        ask(sup, Stop())
        self.wait_idle(sup, STOP_TIMEOUT_S, "the planner to stop the program")

    def wait_idle(self, sup: Supervisor, timeout_s: float, what: str) -> None:
        """Until the planner is idle again (homing done, the program stopped), without an error on the way."""
        sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE, timeout_s, what)
        self.check_no_error(sup)

    def check_no_error(self, sup: Supervisor) -> None:
        """Raise when the planner has reported a failure since `begin` (a servo trip, a planning error)."""
        motion = sup.motion()
        if motion["error_seq"] != self.error_seq:
            raise BenchError(f"the planner failed: {motion['error']}")

    def motion_text(self) -> str:
        loops = f"{self.program.loops} loop{'s' if self.program.loops > 1 else ''}"
        return (
            f"{PROGRAM_NAME} run by the planner: {loops} of the tour, a circle, a {FLOWER_CHORDS}-chord polyline "
            f"and {ARC_COUNT} arcs, F{PROGRAM_FEED_MM_MIN:g} G64 P{PROGRAM_TOLERANCE_MM:g} (planned {self.planned_s:.0f} s)"
        )

    def fifo_min_fill(self, after: Snapshot) -> int | None:
        return int(after.motion["fifo_min_fill"])


class LoggingFeed(PlannerFeed):
    """The planner's run, with the data logger recording every trace variable at every tick: the
    servo writes a trace record per tick and the logger process drains and records them."""

    name = "logging"
    processes = (*MOTION_ONLY, "logger")
    winding_down = "the program and the log run stopped"

    def __init__(self, config: MachineConfig, seconds: float) -> None:
        super().__init__(config, seconds)
        self.seconds = seconds
        self.samples = self.dropped = self.variables = 0

    def begin(self, sup: Supervisor) -> None:
        super().begin(sup)
        state = self._ask(sup, "state", LogState)
        trace = [v.name for v in state.variables if not v.name.startswith("plc.")][:TRACE_VARIABLES]
        self.variables = len(trace)
        reply = self._ask(sup, "start", Reply, LogStart([LogSetting(n, "timed", 1, 0.0, self.seconds + 60.0) for n in trace]))
        if not reply.ok:
            raise BenchError(f"the logger refused the run: {reply.reason}")
        self.dropped = sup.trace.dropped()

    def wind_down(self, sup: Supervisor) -> None:
        reply = self._ask(sup, "stop", Reply, LogStop())
        if not reply.ok:
            raise BenchError(f"the logger could not stop the run: {reply.reason}")
        self.samples = int(reply.reason.split(": ")[-1].split()[0])
        self.dropped = sup.trace.dropped() - self.dropped
        super().wind_down(sup)

    @staticmethod
    def _ask(sup: Supervisor, what: str, kind: type, payload: Any = None) -> Any:
        options = {"payload": encode(payload)} if payload is not None else {}
        for reply in sup.router.get(sup.keys.log(what), timeout=10.0, **options):
            if reply.ok is None:
                raise BenchError(f"log/{what}: {reply.err.payload.to_string()}")
            return decode(reply.ok.payload.to_bytes(), kind)
        raise BenchError(f"log/{what}: the logger did not answer")

    def motion_text(self) -> str:
        return (f"{super().motion_text()}; the logger recording {self.variables} variables at every tick "
                f"({self.samples} samples, {self.dropped} trace records dropped)")


def ask(sup: Supervisor, command: Any) -> None:
    """Send one command to the planner; a refusal fails the run."""
    reply = sup.planner.request(command)
    if not reply.ok:
        raise BenchError(f"the planner refused: {reply.reason}")


# ---------------------------------------------------------------------------------------
# the planner feed's program


@dataclass(frozen=True)
class BusyProgram:
    text: str
    loops: int


class ToolPath:
    """G-code moves in the XY plane, and the length of the path they make."""

    def __init__(self, start: tuple[float, float]) -> None:
        self.position = start
        self.length_mm = 0.0
        self.lines: list[str] = []

    def line(self, end: tuple[float, float]) -> None:
        self.lines.append(f"G1 X{end[0]:.3f} Y{end[1]:.3f}")
        self.length_mm += math.dist(self.position, end)
        self.position = end

    def arc(self, end: tuple[float, float], centre: tuple[float, float], clockwise: bool) -> None:
        """G2 or G3 to `end` around `centre`; ending where it starts makes a full circle."""
        (x0, y0), (cx, cy) = self.position, centre
        a0, a1 = math.atan2(y0 - cy, x0 - cx), math.atan2(end[1] - cy, end[0] - cx)
        sweep = ((a0 - a1) if clockwise else (a1 - a0)) % math.tau or math.tau
        self.lines.append(f"{'G2' if clockwise else 'G3'} X{end[0]:.3f} Y{end[1]:.3f} I{cx - x0:.3f} J{cy - y0:.3f}")
        self.length_mm += math.dist(self.position, centre) * sweep
        self.position = end


def busy_program(config: MachineConfig, min_duration_s: float) -> BusyProgram:
    """A program that keeps the table moving for at least `min_duration_s` at 100 % feed.

    No point of the path moves faster than the programmed feed, so a loop takes at least its
    length over that feed: enough loops for `min_duration_s` follow from the length alone.
    """
    start = tour_points(config)[0]
    loop = one_loop(config)
    loops = math.ceil(min_duration_s * PROGRAM_FEED_MM_MIN / 60.0 / loop.length_mm)
    header = [
        "( servo_timing.py: keeps the table busy for the planner feed; the jet stays off )",
        "G21 G90 G17 G94",
        f"G64 P{PROGRAM_TOLERANCE_MM:g}",
        f"F{PROGRAM_FEED_MM_MIN:g}",
        f"G1 X{start[0]:.3f} Y{start[1]:.3f}",
    ]
    return BusyProgram("\n".join(header + loop.lines * loops + ["M2"]) + "\n", loops)


def one_loop(config: MachineConfig) -> ToolPath:
    """From the tour's first point back to it: the direct feed's diagonal tour, then around the
    middle of the travel a full circle, a CAM-style polyline (a flower in short chords, the
    input the look-ahead works hardest on) and a chain of tangent semicircles."""
    points = tour_points(config)
    x, y = config.axis["x"], config.axis["y"]
    centre = ((x.travel_min_mm + x.travel_max_mm) / 2.0, (y.travel_min_mm + y.travel_max_mm) / 2.0)
    radius = FIGURE_FRACTION * min(x.travel_max_mm - x.travel_min_mm, y.travel_max_mm - y.travel_min_mm)
    path = ToolPath(points[0])
    for p in points[1:] + points[:1]:
        path.line(p)
    east = (centre[0] + radius, centre[1])
    path.line(east)
    path.arc(east, centre, clockwise=False)
    for p in flower(centre, radius):
        path.line(p)
    path.line(east)
    for k in range(ARC_COUNT):
        x0, y0 = path.position
        path.arc((x0 - 2.0 * ARC_RADIUS_MM, y0), (x0 - ARC_RADIUS_MM, y0), clockwise=k % 2 == 1)
    path.line(points[0])
    return path


def flower(centre: tuple[float, float], radius: float) -> list[tuple[float, float]]:
    """The inner vertices of a closed polyline r = R (1 + depth sin(petals theta)) that
    starts and ends at theta = 0, counter-clockwise."""
    theta = np.linspace(0.0, math.tau, FLOWER_CHORDS + 1)[1:-1]
    r = radius * (1.0 + FLOWER_DEPTH * np.sin(FLOWER_PETALS * theta))
    return list(zip((centre[0] + r * np.cos(theta)).tolist(), (centre[1] + r * np.sin(theta)).tolist()))


# ---------------------------------------------------------------------------------------
# one measurement


def measure_controller(config: MachineConfig, feed: DirectFeed | PlannerFeed, seconds: float) -> ControllerRun:
    """Run the controller on the real-time clock with `feed` keeping the table moving for `seconds`.

    A controller that does not start or fails before the measurement raises; one that fails
    during it (servo fault, lost process, the program abandoned) returns the figures
    gathered up to the failure, with `failure` set.
    """
    state = tempfile.TemporaryDirectory(prefix="servo_timing_state_")  # the logger's runs, not the user's
    sup = Supervisor(on_free_port(config), clock="realtime", processes=feed.processes, log_level=logging.WARNING,
                     history_path=Path(state.name) / "history.sqlite")
    try:
        sup.start()
        sup.enable()
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 5.0, "the servo to close the loop")
        settle(sup, SETTLE_S)
        feed.begin(sup)
        before, started = Snapshot.take(sup), time.monotonic()
        after, failure = None, ""
        try:
            supervise(sup, feed, until=started + seconds)
            after = Snapshot.take(sup)
            feed.wind_down(sup)
            check_healthy(sup)
        except (BenchError, SupervisorError, TimeoutError) as exc:
            failure = str(exc) if after is None else f"{exc}, after the measurement while {feed.winding_down}"
        if after is None:
            after = Snapshot.take(sup)
        measured_s = min(time.monotonic() - started, seconds)
    finally:
        sup.stop()
        state.cleanup()
    return ControllerRun(
        feeder=feed.name,
        motion=feed.motion_text(),
        wake=summarize(after.hw_hist - before.hw_hist),
        speed_command=summarize(after.servo_hist - before.servo_hist),
        counters=window_counters(before, after),
        realtime_granted=after.hw["clock_kind"] == ClockKind.REALTIME,
        measured_s=measured_s,
        fifo_min_fill=feed.fifo_min_fill(after),
        failure=failure,
    )


def on_free_port(config: MachineConfig) -> MachineConfig:
    """`config` with the controller's Zenoh router on a port free now: each run opens its own."""
    return dataclasses.replace(config, zenoh=dataclasses.replace(config.zenoh, listen=[f"tcp/127.0.0.1:{free_port()}"]))


def check_healthy(sup: Supervisor) -> None:
    """Supervise once; raise when a process is lost, the servo faulted or the watchdog tripped."""
    sup.poll()
    if sup.failed:
        raise SupervisorError(sup.failed)
    servo = sup.servo()
    if servo["state"] == ServoState.FAULT:
        fault, axis = ServoFault(servo["fault"]).name, servo["fault_axis"]
        where = f" on axis {sup.config.axis_names[axis].upper()}" if 0 <= axis < len(sup.config.axis_names) else ""
        raise BenchError(f"servo fault {fault}{where} (value {servo['fault_value']:g})")
    if sup.hw()["watchdog_tripped"]:
        raise BenchError("the drive watchdog tripped: the servo missed too many ticks")


def settle(sup: Supervisor, seconds: float) -> None:
    """Hold still (and keep supervising) for `seconds`."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        check_healthy(sup)
        time.sleep(POLL_S)


def supervise(sup: Supervisor, feed: DirectFeed | PlannerFeed, until: float) -> None:
    """Keep the table moving and the controller supervised until the monotonic time `until`."""
    while time.monotonic() < until:
        check_healthy(sup)
        feed.keep_going(sup)
        time.sleep(POLL_S)


def window_counters(before: Snapshot, after: Snapshot) -> dict[str, int]:
    """What the controller's cumulative counters added between the two snapshots."""
    delta = {
        "overruns": after.servo["overruns"] - before.servo["overruns"],
        "underruns": after.servo["underruns"] - before.servo["underruns"],
        "late_ticks": after.hw["late_ticks"] - before.hw["late_ticks"],
        "missed_ticks": after.hw["servo_missed_total"] - before.hw["servo_missed_total"],
        "records_pushed": after.pushed - before.pushed,
    }
    delta = {k: int(v) for k, v in delta.items()}
    delta["watchdog_tripped"] = int(after.hw["watchdog_tripped"])
    delta["clock_kind"] = int(after.hw["clock_kind"])
    return delta


# ---------------------------------------------------------------------------------------
# the reference


@dataclass(frozen=True)
class Reference:
    command: list[str]
    latency: Latency | None
    reported_max_us: int | None
    error: str = ""


def run_cyclictest(seconds: int, priority: int, interval_us: int) -> Reference:
    """Run cyclictest set up like our tick: one SCHED_FIFO thread sleeping to absolute
    deadlines on CLOCK_MONOTONIC, memory locked. A missing or failing cyclictest gives a
    Reference with `error` set, not an exception: our own figures still count."""
    exe = shutil.which("cyclictest")
    command = [
        exe or "cyclictest", "-t1", f"-p{priority}", f"-i{interval_us}", "-m",
        f"-h{CYCLICTEST_BINS}", "-q", f"-D{seconds}",
    ]
    if exe is None:
        return Reference(command, None, None, "cyclictest not installed (Debian/Ubuntu package rt-tests)")
    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=seconds + 60)
    except subprocess.TimeoutExpired:
        return Reference(command, None, None, f"cyclictest did not finish within {seconds + 60} s")
    if proc.returncode != 0:
        why = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        return Reference(command, None, None, f"cyclictest failed (exit {proc.returncode}): {why}")
    try:
        hist, reported_max = parse_cyclictest(proc.stdout)
    except ValueError as exc:
        return Reference(command, None, None, str(exc))
    return Reference(command, summarize(hist), reported_max)


# ---------------------------------------------------------------------------------------
# report

PERCENTILES = (("p50", "p50_us"), ("p99", "p99_us"), ("p99.9", "p999_us"), ("max", "max_us"))
LABEL_WIDTH = 40
COLUMN_WIDTH = 10


def format_us(value: int, overflow_us: int) -> str:
    return f">={value}" if value >= overflow_us else str(value)


def ratio_text(ours: Latency, ref: Latency, key: str) -> str:
    a, b = getattr(ours, key), getattr(ref, key)
    if b == 0:
        return "n/a"  # the reference is under 1 us: no meaningful ratio
    prefix = ">=" if a >= ours.overflow_us else "<=" if b >= ref.overflow_us else ""
    return f"{prefix}{a / b:.1f}x"


def system_text() -> str:
    kernel = platform.release()
    rt = "PREEMPT_RT" if "PREEMPT_RT" in platform.version() else "not PREEMPT_RT"
    return f"kernel {kernel} ({platform.version()}; {rt}), {os.cpu_count()} CPUs"


def report(config: MachineConfig, runs: list[ControllerRun], ref: Reference) -> str:
    """The plain-text result: what moved, latency table, ratios to cyclictest, counters."""
    period_us = round(1e6 / config.timing.base_rate_hz)
    lines = [f"servo timing: machine {config.machine.name!r}, base tick {period_us} us", system_text()]
    for run in runs:
        lines.append(f"{run.feeder} feed: {run.measured_s:.0f} s of motion, {run.motion}")
        if run.failure:
            lines.append(f"  FAILED: {run.failure}; the figures cover {run.measured_s:.1f} s")
    lines += ["", *latency_table(runs, ref), "", *ratio_table(runs, ref), "", *counter_table(config, runs)]
    if any(run.fifo_min_fill is not None for run in runs):
        lines.append(watermark_text(config))
    if ref.latency is not None:
        lines.append(f"cyclictest: {' '.join(ref.command[1:])}")
    return "\n".join(lines)


def run_latencies(run: ControllerRun) -> tuple[tuple[str, Latency], ...]:
    """The two latencies of a run, each with its label."""
    return (("tick wake latency", run.wake), ("tick-to-speed-command latency", run.speed_command))


def latency_table(runs: list[ControllerRun], ref: Reference) -> list[str]:
    lines = [f"{'latency after the tick deadline, us':<{LABEL_WIDTH}}{_header()}{'samples':>10}"]
    for run in runs:
        lines.append(f"{run.feeder} feed")
        (wake_label, wake), (command_label, command) = run_latencies(run)
        lines.append(latency_row(f"  {wake_label} (hardware server)", wake))
        lines.append(latency_row(f"  {command_label} (servo)", command))
    if ref.latency is None:
        lines.append(f"{'cyclictest wake latency (reference)':<{LABEL_WIDTH}}  not run: {ref.error}")
    else:
        lines.append(latency_row("cyclictest wake latency (reference)", ref.latency))
    return lines


def latency_row(label: str, lat: Latency) -> str:
    cells = "".join(f"{format_us(getattr(lat, key), lat.overflow_us):>8}" for _, key in PERCENTILES)
    return f"{label:<{LABEL_WIDTH}}{cells}{lat.samples:>10}"


def ratio_table(runs: list[ControllerRun], ref: Reference) -> list[str]:
    if ref.latency is None:
        return ["ratio to cyclictest: none (no reference)"]
    lines = [f"{'ratio to cyclictest':<{LABEL_WIDTH}}{_header()}"]
    for run in runs:
        lines.append(f"{run.feeder} feed")
        for label, lat in run_latencies(run):
            cells = "".join(f"{ratio_text(lat, ref.latency, key):>8}" for _, key in PERCENTILES)
            lines.append(f"{'  ' + label:<{LABEL_WIDTH}}{cells}")
    return lines


def counter_table(config: MachineConfig, runs: list[ControllerRun]) -> list[str]:
    """One column per run: the counters of the measurement window."""
    period_ms = 1000.0 / config.timing.base_rate_hz
    labels = (
        "overruns (servo skipped a tick)",
        "underruns (FIFO dry mid-motion)",
        "late ticks (tick woke a period late)",
        "missed ticks (servo late for board)",
        "setpoints pushed into the FIFO",
        f"lowest FIFO fill (records of {period_ms:g} ms)",
        "drive watchdog",
        f"real-time (SCHED_FIFO {config.timing.realtime_priority} + mlockall)",
    )
    columns = [counter_column(run) for run in runs]
    lines = [f"{'during the measurement':<{LABEL_WIDTH}}" + "".join(f"{run.feeder:>{COLUMN_WIDTH}}" for run in runs)]
    for i, label in enumerate(labels):
        lines.append(f"{'  ' + label:<{LABEL_WIDTH}}" + "".join(f"{column[i]:>{COLUMN_WIDTH}}" for column in columns))
    return lines


def counter_column(run: ControllerRun) -> list[str]:
    """A run's cells of the counter table, in the order of its labels."""
    c = run.counters
    return [
        str(c["overruns"]),
        str(c["underruns"]),
        str(c["late_ticks"]),
        str(c["missed_ticks"]),
        str(c["records_pushed"]),
        fill_text(run.fifo_min_fill),
        "TRIPPED" if c["watchdog_tripped"] else "ok",
        "granted" if run.realtime_granted else "NO",
    ]


def fill_text(fill: int | None) -> str:
    """The planner's lowest FIFO fill: "-" for a direct run, "none" when the planner recorded none."""
    if fill is None:
        return "-"  # not a planner run
    return "none" if fill < 0 else str(fill)


def watermark_text(config: MachineConfig) -> str:
    p = config.planner
    period_ms = 1000.0 / config.timing.base_rate_hz
    return (
        f"planner: refills the FIFO from below {p.fifo_low_ms:g} ms up to {p.fifo_high_ms:g} ms, every {p.divisor} "
        f"base ticks ({p.divisor * period_ms:g} ms). Its lowest fill is read at its wakes since the program's start,\n"
        f"before each burst: a burst computed too slowly drains the FIFO unseen there, and shows as underruns."
    )


def _header() -> str:
    return "".join(f"{name:>8}" for name, _ in PERCENTILES)


def to_json(config: MachineConfig, seconds: int, runs: list[ControllerRun], ref: Reference) -> dict[str, Any]:
    """Every figure of the report, runs keyed by feeder."""
    return {
        "machine": config.machine.name,
        "seconds": seconds,
        "base_period_us": round(1e6 / config.timing.base_rate_hz),
        "system": {"kernel": platform.release(), "version": platform.version(), "cpus": os.cpu_count()},
        "planner": {
            "fifo_low_ms": config.planner.fifo_low_ms,
            "fifo_high_ms": config.planner.fifo_high_ms,
            "divisor": config.planner.divisor,
        },
        "cyclictest": {
            "command": ref.command,
            "latency_us": asdict(ref.latency) if ref.latency else None,
            "reported_max_us": ref.reported_max_us,
            "error": ref.error,
        },
        "runs": {run.feeder: run_json(run, ref) for run in runs},
    }


def run_json(run: ControllerRun, ref: Reference) -> dict[str, Any]:
    latencies = {"tick_wake": run.wake, "tick_to_speed_command": run.speed_command}
    ratios = {}
    if ref.latency is not None:
        for name, lat in latencies.items():
            ratios[name] = {key: ratio_text(lat, ref.latency, key) for _, key in PERCENTILES}
    return {
        "motion": run.motion,
        "measured_s": round(run.measured_s, 3),
        "failure": run.failure,
        "realtime_granted": run.realtime_granted,
        "latency_us": {name: asdict(lat) for name, lat in latencies.items()},
        "ratio_to_cyclictest": ratios,
        "counters": run.counters,
        "fifo_min_fill": run.fifo_min_fill,
    }


# ---------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=int, default=30, help="length of each measurement (default 30)")
    parser.add_argument(
        "--feeder", choices=(*FEEDERS, "both", "all"), default="both",
        help="who feeds the setpoint FIFO: this script (direct), the planner process (planner), the planner with the "
             "data logger recording at every tick (logging); both: direct then planner (default); all: the three",
    )
    parser.add_argument("--machine", default=str(DEFAULT_MACHINE), help="machine file (default machines/waterjet.toml)")
    parser.add_argument("--json", metavar="OUT", help="also write every figure to this JSON file")
    args = parser.parse_args(argv)
    if args.seconds < 1:
        parser.error("--seconds must be at least 1")
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    try:
        config = load_machine(args.machine)
    except ConfigError as exc:
        print(f"servo_timing: {exc}", file=sys.stderr)
        return 1
    names = {"both": FEEDERS[:2], "all": FEEDERS}.get(args.feeder, (args.feeder,))
    kinds = {"direct": lambda: DirectFeed(config), "planner": lambda: PlannerFeed(config, args.seconds),
             "logging": lambda: LoggingFeed(config, args.seconds)}
    feeds = [kinds[name]() for name in names]
    print(
        f"servo_timing: {args.seconds} s of the controller in motion fed by {' then by '.join(names)}, "
        f"then {args.seconds} s of cyclictest",
        flush=True,
    )
    runs = []
    for feed in feeds:
        try:
            runs.append(measure_controller(config, feed, args.seconds))
        except (BenchError, SupervisorError, TimeoutError) as exc:
            print(f"servo_timing: FAILED ({feed.name} feed): {exc}", file=sys.stderr)
            return 1
    period_us = round(1e6 / config.timing.base_rate_hz)
    ref = run_cyclictest(args.seconds, config.timing.realtime_priority, period_us)
    print(report(config, runs, ref))
    if args.json:
        Path(args.json).write_text(json.dumps(to_json(config, args.seconds, runs, ref), indent=2) + "\n")
    failed = [run for run in runs if run.failure]
    for run in failed:
        print(f"servo_timing: FAILED ({run.feeder} feed): {run.failure}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
