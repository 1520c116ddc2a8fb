#!/usr/bin/env python3
"""Servo timing benchmark: how late the 1 kHz loop runs, next to the machine's own timer latency.

The controller's base tick and servo loop are Python processes under SCHED_FIFO. Whether
that is good enough depends on two numbers: how late the hardware server wakes after each
absolute deadline (tick wake latency) and how long after the deadline the servo has
published its speed command (tick-to-speed-command latency, the delay the drives see).
Neither means much alone: a noisy virtual machine without PREEMPT_RT wakes late for any
program. So the script measures both while the servo does real work (the simulated table
runs back and forth across its travel for the whole run), then runs `cyclictest`, the
standard C timer-latency test, with the same period, priority and duration, and reports
our latencies as multiples of the machine's own. The controller's histograms are taken
as the difference between a snapshot when the servo holds (after a short settle, see
SETTLE_S) and one at the end, so start-up is excluded.

    python bench/servo_timing.py [--seconds 30] [--machine machines/waterjet.toml] [--json OUT]

Exits 1 only when the controller fails (does not start, loses a process, servo fault),
never because the figures are high; after a failure during the run the figures gathered
up to it are still printed.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import os
import platform
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cnc.config import ConfigError, MachineConfig, load_machine
from cnc.demo import free_port
from cnc.fifo import SetpointFifo
from cnc.layout import ClockKind, ServoFault, ServoState
from cnc.ptp import move_setpoints
from cnc.supervisor import Supervisor, SupervisorError

DEFAULT_MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"
CYCLICTEST_BINS = 5000  # 1 us bins up to 5 ms, as the controller's own histograms
LEAD_S = 2.0  # how far ahead of the servo the FIFO is kept filled
POLL_S = 0.02
# The servo closes the loop while the last processes (gateway, Zenoh sessions) are still
# starting; for about a second after that the loop sees wake-ups several ms late. The
# table holds still through it, so that start-up neither trips the servo nor counts.
SETTLE_S = 2.0
TOUR_FRACTIONS = (0.1, 0.9)  # tour points sit at 10 % and 90 % of each axis' travel


class BenchError(RuntimeError):
    """The controller failed during the run: servo fault or drive watchdog."""


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
    hw_hist: np.ndarray
    servo_hist: np.ndarray
    hw: dict[str, Any]
    servo: dict[str, Any]

    @classmethod
    def take(cls, sup: Supervisor) -> "Snapshot":
        return cls(sup.timing("hw_timing")["hist"], sup.timing("servo_timing")["hist"], sup.hw(), sup.servo())


@dataclass(frozen=True)
class ControllerRun:
    wake: Latency
    speed_command: Latency
    counters: dict[str, int]  # during the measurement window
    realtime_granted: bool
    moves: int  # moves started
    measured_s: float  # the window the figures cover
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


def check_healthy(sup: Supervisor) -> None:
    """Supervise once; raise when a process is lost, the servo faulted or the watchdog tripped."""
    sup.poll()
    if sup.failed:
        raise SupervisorError(sup.failed)
    servo = sup.servo()
    if servo["state"] == ServoState.FAULT:
        fault = ServoFault(servo["fault"]).name
        raise BenchError(f"servo fault {fault} on axis {servo['fault_axis']} (value {servo['fault_value']:g})")
    if sup.hw()["watchdog_tripped"]:
        raise BenchError("the drive watchdog tripped: the servo missed too many ticks")


def measure_controller(config: MachineConfig, seconds: float) -> ControllerRun:
    """Run the controller on the real-time clock with the table in motion for `seconds`.

    A controller that does not start raises; one that fails during the run (servo fault,
    lost process) returns the figures gathered up to the failure, with `failure` set.
    """
    points = tour_points(config)
    tour = [move_setpoints(config, a, b) for a, b in zip(points, points[1:] + points[:1])]
    sup = Supervisor(config, clock="realtime", log_level=logging.WARNING)
    try:
        sup.start()
        sup.enable()
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 5.0, "the servo to close the loop")
        settle(sup, SETTLE_S)
        first = move_setpoints(config, sup.servo()["commanded_mm"], points[0])
        feeder = MotionFeeder(sup.fifo, first, tour, lead=int(LEAD_S * config.timing.base_rate_hz))
        before, started = Snapshot.take(sup), time.monotonic()
        after, failure = None, ""
        try:
            keep_feeding(sup, feeder, until=started + seconds)
            after = Snapshot.take(sup)
            keep_feeding(sup, feeder, until=None)  # finish the move under way: stop at rest
            sup.wait_motion_done(timeout_s=30.0)
            check_healthy(sup)
        except (BenchError, SupervisorError, TimeoutError) as exc:
            failure = str(exc) if after is None else f"{exc}, after the measurement while the last move finished"
        if after is None:
            after = Snapshot.take(sup)
        measured_s = min(time.monotonic() - started, seconds)
    finally:
        sup.stop()
    return ControllerRun(
        wake=summarize(after.hw_hist - before.hw_hist),
        speed_command=summarize(after.servo_hist - before.servo_hist),
        counters=window_counters(before, after),
        realtime_granted=after.hw["clock_kind"] == ClockKind.REALTIME,
        moves=feeder.moves_started,
        measured_s=measured_s,
        failure=failure,
    )


def settle(sup: Supervisor, seconds: float) -> None:
    """Hold still (and keep supervising) for `seconds`."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        check_healthy(sup)
        time.sleep(POLL_S)


def keep_feeding(sup: Supervisor, feeder: MotionFeeder, until: float | None) -> None:
    """Feed and supervise until the monotonic time `until`; with None, start no new move
    and return once the move under way has been pushed to its end."""
    while (time.monotonic() < until) if until is not None else not feeder.move_finished_pushing:
        feeder.feed(start_new_moves=until is not None)
        check_healthy(sup)
        time.sleep(POLL_S)


def window_counters(before: Snapshot, after: Snapshot) -> dict[str, int]:
    """What the controller's cumulative counters added between the two snapshots."""
    delta = {
        "overruns": after.servo["overruns"] - before.servo["overruns"],
        "underruns": after.servo["underruns"] - before.servo["underruns"],
        "late_ticks": after.hw["late_ticks"] - before.hw["late_ticks"],
        "missed_ticks": after.hw["servo_missed_total"] - before.hw["servo_missed_total"],
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


def report(config: MachineConfig, run: ControllerRun, ref: Reference) -> str:
    """The plain-text result: latency table, ratios to cyclictest, counters."""
    period_us = round(1e6 / config.timing.base_rate_hz)
    lines = [
        f"servo timing: machine {config.machine.name!r}, {run.measured_s:.0f} s of motion "
        f"({run.moves} moves), base tick {period_us} us",
        system_text(),
    ]
    if run.failure:
        lines.append(f"FAILED: {run.failure}; the figures cover {run.measured_s:.1f} s")
    lines += ["", *latency_table(run, ref), "", *ratio_table(run, ref), "", *counter_lines(config, run)]
    if ref.latency is not None:
        lines.append(f"cyclictest: {' '.join(ref.command[1:])}")
    return "\n".join(lines)


def latency_table(run: ControllerRun, ref: Reference) -> list[str]:
    lines = [f"{'latency after the tick deadline, us':<{LABEL_WIDTH}}{_header()}{'samples':>10}"]
    rows = [
        ("tick wake latency (hardware server)", run.wake),
        ("tick-to-speed-command latency (servo)", run.speed_command),
        ("cyclictest wake latency (reference)", ref.latency),
    ]
    for label, lat in rows:
        if lat is None:
            lines.append(f"{label:<{LABEL_WIDTH}}  not run: {ref.error}")
            continue
        cells = "".join(f"{format_us(getattr(lat, key), lat.overflow_us):>8}" for _, key in PERCENTILES)
        lines.append(f"{label:<{LABEL_WIDTH}}{cells}{lat.samples:>10}")
    return lines


def ratio_table(run: ControllerRun, ref: Reference) -> list[str]:
    if ref.latency is None:
        return ["ratio to cyclictest: none (no reference)"]
    lines = [f"{'ratio to cyclictest':<{LABEL_WIDTH}}{_header()}"]
    for label, lat in (("tick wake latency", run.wake), ("tick-to-speed-command latency", run.speed_command)):
        cells = "".join(f"{ratio_text(lat, ref.latency, key):>8}" for _, key in PERCENTILES)
        lines.append(f"{label:<{LABEL_WIDTH}}{cells}")
    return lines


def counter_lines(config: MachineConfig, run: ControllerRun) -> list[str]:
    c = run.counters
    granted = (
        f"granted (SCHED_FIFO {config.timing.realtime_priority} + mlockall)"
        if run.realtime_granted
        else "NOT granted (fallback: no SCHED_FIFO or no mlockall)"
    )
    rows = [
        ("overruns (servo skipped a tick)", c["overruns"]),
        ("underruns (FIFO dry mid-motion)", c["underruns"]),
        ("late ticks (tick woke a period late)", c["late_ticks"]),
        ("missed ticks (servo late for board)", c["missed_ticks"]),
        ("drive watchdog", "TRIPPED" if c["watchdog_tripped"] else "ok"),
        ("real-time scheduling", granted),
    ]
    return ["during the measurement", *(f"  {label:<38}{value}" for label, value in rows)]


def _header() -> str:
    return "".join(f"{name:>8}" for name, _ in PERCENTILES)


def to_json(config: MachineConfig, seconds: int, run: ControllerRun, ref: Reference) -> dict[str, Any]:
    ratios = {}
    if ref.latency is not None:
        for name, lat in (("wake", run.wake), ("speed_command", run.speed_command)):
            ratios[name] = {key: ratio_text(lat, ref.latency, key) for _, key in PERCENTILES}
    return {
        "machine": config.machine.name,
        "seconds": seconds,
        "measured_s": round(run.measured_s, 3),
        "failure": run.failure,
        "base_period_us": round(1e6 / config.timing.base_rate_hz),
        "system": {"kernel": platform.release(), "version": platform.version(), "cpus": os.cpu_count()},
        "realtime_granted": run.realtime_granted,
        "moves": run.moves,
        "latency_us": {
            "tick_wake": asdict(run.wake),
            "tick_to_speed_command": asdict(run.speed_command),
            "cyclictest": asdict(ref.latency) if ref.latency else None,
        },
        "cyclictest": {"command": ref.command, "reported_max_us": ref.reported_max_us, "error": ref.error},
        "ratio_to_cyclictest": ratios,
        "counters": run.counters,
    }


# ---------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=int, default=30, help="length of each measurement (default 30)")
    parser.add_argument("--machine", default=str(DEFAULT_MACHINE), help="machine file (default machines/waterjet.toml)")
    parser.add_argument("--json", metavar="OUT", help="also write every figure to this JSON file")
    args = parser.parse_args(argv)
    if args.seconds < 1:
        parser.error("--seconds must be at least 1")
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    try:
        config = load_machine(args.machine, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"]})
    except ConfigError as exc:
        print(f"servo_timing: {exc}", file=sys.stderr)
        return 1
    print(f"servo_timing: {args.seconds} s of the controller in motion, then {args.seconds} s of cyclictest", flush=True)
    try:
        run = measure_controller(config, args.seconds)
    except (SupervisorError, TimeoutError) as exc:
        print(f"servo_timing: FAILED: {exc}", file=sys.stderr)
        return 1
    period_us = round(1e6 / config.timing.base_rate_hz)
    ref = run_cyclictest(args.seconds, config.timing.realtime_priority, period_us)
    print(report(config, run, ref))
    if args.json:
        Path(args.json).write_text(json.dumps(to_json(config, args.seconds, run, ref), indent=2) + "\n")
    if run.failure:
        print(f"servo_timing: FAILED: {run.failure}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
