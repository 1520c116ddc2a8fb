#!/usr/bin/env python3
"""Soak: automatic cycles on the real-time clock for N minutes; overruns, underruns, following error, memory.

Starts the whole controller (PLC simulator included) on the real-time clock with the simulated
board, homes, loads a nest (bench/load.py's cut program, about `--cut-seconds` of cutting) and
runs automatic cycles one after another in AUTO until `--minutes` are over, playing the
operator as bench/load.py does (the transport station's button pressed when the procedure asks).
A cycle that ends in a fault is counted with its reason, the machine is reset and the soak goes
on; one that cannot be recovered ends it.

Every `--report-seconds` a line shows the progress. At the end a table gives, over the soak
(after the warm-up: the first `--warmup-cycles` cycles): cycles done and faulted, servo
overruns, FIFO underruns (the servo found the FIFO dry mid-motion), late and missed ticks, the
largest following error per axis (the servo's own maximum since the drives came on, homing
included) beside the machine's following-error limit, and the servo's tick-to-speed-command
latency (p99 and peak over the soak, and in the last report interval) beside the period. Then
the resident memory (VmRSS, /proc/<pid>/status) of every controller process, of the PLC
simulator and of this process (the supervisor and the controller's Zenoh router) at start,
after the warm-up and at the end, with the growth per hour fitted over every sample after the
warm-up; a growth above `--growth-limit` MB/h is flagged.

    .venv/bin/python bench/soak.py [--minutes 10] [--cut-seconds 10] [--json OUT]

Exits 1 when the soak could not run to its end or a process's memory grows beyond the limit.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import tempfile
import time
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from load import BRISK_PLANT, CYCLE_TIMEOUT_S, Operator, cut_program, machine_overrides, rss_mb  # noqa: E402
from servo_timing import BenchError, Snapshot, on_free_port, percentile_us, system_text, window_counters  # noqa: E402

from cnc.bus.messages import CycleStart, SetMode  # noqa: E402
from cnc.config import ConfigError, MachineConfig, load_machine  # noqa: E402
from cnc.data.layout import LinkState, RunResult  # noqa: E402
from cnc.logic.states import CyclePhase  # noqa: E402
from cnc.runtime.supervisor import Supervisor, SupervisorError  # noqa: E402

DEFAULT_MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"
SUPERVISOR = "supervisor + router (this process)"
PLC_SIM = "plc simulator"


@dataclass
class MemoryTrack:
    """One process's resident memory over the soak."""

    start_mb: float = 0.0
    warm_mb: float = 0.0
    end_mb: float = 0.0
    samples: list[tuple[float, float]] = field(default_factory=list)  # (soak seconds, MB) after the warm-up

    def growth_mb_h(self) -> float:
        """The least-squares slope of the samples after the warm-up, per hour (0 with fewer than 3)."""
        if len(self.samples) < 3:
            return 0.0
        t, mb = np.array(self.samples).T
        return float(np.polyfit(t, mb, 1)[0] * 3600.0)


@dataclass
class Soak:
    """What the soak measured."""

    minutes: float
    cycles: int = 0
    faults: list[str] = field(default_factory=list)  # one per faulted cycle: when and why
    counters: dict[str, int] = field(default_factory=dict)  # over the soak, after the warm-up
    max_following_error_mm: list[float] = field(default_factory=list)
    latency_p99_us: int = 0
    latency_peak_us: int = 0
    last_interval_p99_us: int = 0
    last_interval_peak_us: int = 0
    memory: dict[str, MemoryTrack] = field(default_factory=dict)
    supervisor_events: list[str] = field(default_factory=list)
    failure: str = ""


def pids(sup: Supervisor) -> dict[str, int]:
    """Every process of the controller by name (a restarted one under its new pid)."""
    out = {name: child.process.pid for name, child in sup.children.items()}
    if sup.plc_sim is not None:
        out[PLC_SIM] = sup.plc_sim.process.pid
    out[SUPERVISOR] = os.getpid()
    return out


def memory_now(sup: Supervisor) -> dict[str, float]:
    return {name: rss_mb(pid) for name, pid in pids(sup).items()}


def one_cycle(sup: Supervisor, operator: Operator) -> None:
    """Start one cycle and wait until it has ended; BenchError when it did not end DONE."""
    runs = sup.motion()["run_seq"]
    operator.ask("cycle start", CycleStart(cycles=1))
    operator.wait(lambda: sup.motion()["run_seq"] > runs and operator.logic()["phase"] == CyclePhase.NONE,
                  CYCLE_TIMEOUT_S, "the cycle to end")
    result = RunResult(sup.motion()["run_result"])
    if result != RunResult.DONE:
        raise BenchError(f"the program run ended {result.name}: {sup.motion()['error']}")


def soak(config: MachineConfig, minutes: float, cut_seconds: float, warmup_cycles: int, report_s: float) -> Soak:
    """Run cycles for `minutes`; the figures, with `failure` set when it could not go on."""
    result = Soak(minutes)
    with tempfile.TemporaryDirectory(prefix="soak_") as tmp, ExitStack() as cleanup:
        sup = Supervisor(on_free_port(config), clock="realtime", history_path=Path(tmp) / "history.sqlite",
                         log_level=logging.WARNING, plc_sim_times=BRISK_PLANT)
        cleanup.callback(sup.stop)
        try:
            sup.start()
            sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 30.0, "the PLC link")
            start_memory = memory_now(sup)
            operator = Operator(sup)
            cleanup.callback(operator.close)
            operator.attempt("homing", operator.reset_and_home, result.faults)
            operator.load("soak_cut.ngc", cut_program(cut_seconds))
            operator.ask("AUTO mode", SetMode("AUTO"))
            _cycles(sup, operator, result, start_memory, minutes, warmup_cycles, report_s)
        except (BenchError, SupervisorError, TimeoutError) as exc:
            result.failure = str(exc)
        result.supervisor_events = list(sup.events)
    return result


def _cycles(sup: Supervisor, operator: Operator, result: Soak, start_memory: dict[str, float], minutes: float,
            warmup_cycles: int, report_s: float) -> None:
    """The soak proper: warm-up cycles, then cycles until the time is up, sampling as it goes."""
    t_start = time.monotonic()
    end = t_start + minutes * 60.0
    warm: Snapshot | None = None
    t_warm = t_start
    interval = Snapshot.take(sup)
    next_report = time.monotonic() + report_s
    try:
        while time.monotonic() < end or warm is None:
            try:
                one_cycle(sup, operator)
                result.cycles += 1
            except BenchError as exc:
                result.faults.append(f"{(time.monotonic() - t_start) / 60:.1f} min: {exc}")
                operator.recover()
            now = time.monotonic()
            if warm is None and result.cycles >= warmup_cycles:
                warm, t_warm = Snapshot.take(sup), now
                for name, mb in memory_now(sup).items():
                    result.memory[name] = MemoryTrack(start_memory.get(name, 0.0), mb, mb, [(0.0, mb)])
            if warm is not None and (now >= next_report or now >= end):
                latest = Snapshot.take(sup)
                _sample(sup, result, now - t_warm)
                hist = latest.servo_hist - interval.servo_hist
                result.last_interval_p99_us, result.last_interval_peak_us = _p99_peak(hist)
                _progress(sup, result, warm, latest, now - t_start)
                interval, next_report = latest, now + report_s
    finally:
        if warm is not None:  # the figures up to a failure count too
            _totals(sup, result, warm, Snapshot.take(sup))


def _sample(sup: Supervisor, result: Soak, seconds: float) -> None:
    for name, mb in memory_now(sup).items():
        track = result.memory.setdefault(name, MemoryTrack(0.0, mb, mb))
        track.end_mb = mb
        track.samples.append((seconds, mb))


def _p99_peak(hist: np.ndarray) -> tuple[int, int]:
    if hist.sum() == 0:
        return 0, 0
    return percentile_us(hist, 0.99), int(np.flatnonzero(hist)[-1])


def _totals(sup: Supervisor, result: Soak, warm: Snapshot, end: Snapshot) -> None:
    result.counters = window_counters(warm, end)
    result.max_following_error_mm = [float(v) for v in sup.servo()["max_following_error_mm"]]
    result.latency_p99_us, result.latency_peak_us = _p99_peak(end.servo_hist - warm.servo_hist)


def _progress(sup: Supervisor, result: Soak, warm: Snapshot, now: Snapshot, seconds: float) -> None:
    c = window_counters(warm, now)
    total = sum(t.end_mb for t in result.memory.values())
    print(f"soak: {seconds / 60:5.1f} min  {result.cycles} cycles ({len(result.faults)} faulted)  "
          f"overruns {c['overruns']}  underruns {c['underruns']}  late ticks {c['late_ticks']}  "
          f"tick-to-speed-command p99/peak {result.last_interval_p99_us}/{result.last_interval_peak_us} us "
          f"this interval  RSS {total:.0f} MB in all", flush=True)


# -- report -------------------------------------------------------------------------------------

LABEL = 46


def report(config: MachineConfig, s: Soak, growth_limit: float) -> str:
    period_us = 1e6 / config.timing.base_rate_hz
    fe_limits = [a.following_error_limit_mm for a in config.axes]
    lines = [f"soak: machine {config.machine.name!r}, real-time clock, {s.minutes:g} min of automatic cycles; "
             f"{system_text()}", "", f"{'figure':<{LABEL}}{'value':>12}{'limit':>12}{'ratio':>8}"]

    def row(label: str, value: float, limit: float | None, fmt: str = "{:.0f}") -> None:
        ratio = f"{value / limit:.2f}" if limit else "-"
        lines.append(f"{label:<{LABEL}}{fmt.format(value):>12}{fmt.format(limit) if limit is not None else '-':>12}"
                     f"{ratio:>8}")

    row("cycles done", s.cycles, None)
    row("cycles faulted", len(s.faults), 0)
    c = s.counters
    if c:
        row("servo overruns (after the warm-up)", c["overruns"], 0)
        row("FIFO underruns (dry mid-motion)", c["underruns"], 0)
        row("late ticks (tick woke a period late)", c["late_ticks"], 0)
        row("missed ticks (servo late for the board)", c["missed_ticks"], 0)
    for name, fe, limit in zip(config.axis_names, s.max_following_error_mm, fe_limits):
        row(f"max following error {name.upper()}, mm", fe, limit, "{:.4f}")
    row("tick-to-speed-command p99, us", s.latency_p99_us, period_us)
    row("tick-to-speed-command peak, us", s.latency_peak_us, period_us)
    row("  last interval p99, us", s.last_interval_p99_us, period_us)
    row("  last interval peak, us", s.last_interval_peak_us, period_us)
    lines += ["", f"{'resident memory (VmRSS), MB':<36}{'start':>9}{'warm':>9}{'end':>9}{'MB/h':>9}{'limit':>8}"]
    for name, t in sorted(s.memory.items()):
        growth = t.growth_mb_h()
        flag = "  GROWING" if growth > growth_limit else ""
        lines.append(f"{name:<36}{t.start_mb:>9.1f}{t.warm_mb:>9.1f}{t.end_mb:>9.1f}{growth:>9.1f}{growth_limit:>8g}{flag}")
    for fault in s.faults:
        lines.append(f"faulted cycle at {fault}")
    for event in s.supervisor_events:
        lines.append(f"supervisor: {event}")
    if s.failure:
        lines.append(f"FAILED: {s.failure}")
    return "\n".join(lines)


def to_json(s: Soak) -> dict[str, Any]:
    out = asdict(s)
    for name, t in s.memory.items():
        out["memory"][name]["growth_mb_h"] = t.growth_mb_h()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(DEFAULT_MACHINE), help="machine file (default machines/waterjet.toml)")
    parser.add_argument("--minutes", type=float, default=10.0, help="length of the soak (default 10)")
    parser.add_argument("--cut-seconds", type=float, default=10.0, help="cutting per cycle, about (default 10)")
    parser.add_argument("--warmup-cycles", type=int, default=2, help="cycles before the figures count (default 2)")
    parser.add_argument("--report-seconds", type=float, default=60.0, help="progress and memory sample period")
    parser.add_argument("--growth-limit", type=float, default=20.0, help="flag memory growth above this, MB/h")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a machine-file key (TOML value), e.g. plc.cycle_ms=100; repeatable")
    parser.add_argument("--json", metavar="OUT", help="also write the figures as JSON")
    args = parser.parse_args(argv)
    if args.minutes <= 0 or args.cut_seconds <= 0 or args.warmup_cycles < 1 or args.report_seconds <= 0:
        parser.error("--minutes, --cut-seconds and --report-seconds must be positive, --warmup-cycles at least 1")
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    try:
        config = load_machine(args.machine, machine_overrides(args.set))
    except (ConfigError, ValueError) as exc:
        print(f"soak: {exc}", file=sys.stderr)
        return 1
    print(f"soak: {args.minutes:g} min of automatic cycles, each cutting about {args.cut_seconds:g} s"
          + (f"; machine file overrides: {', '.join(args.set)}" if args.set else ""), flush=True)
    result = soak(config, args.minutes, args.cut_seconds, args.warmup_cycles, args.report_seconds)
    print(report(config, result, args.growth_limit))
    if args.json:
        Path(args.json).write_text(json.dumps(to_json(result), indent=2) + "\n")
    growing = any(t.growth_mb_h() > args.growth_limit for t in result.memory.values())
    return 1 if result.failure or growing else 0


if __name__ == "__main__":
    sys.exit(main())
