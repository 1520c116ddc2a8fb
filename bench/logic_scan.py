#!/usr/bin/env python3
"""Soft-PLC scan time and jitter, measured in the whole controller running automatic cycles.

Starts the complete controller (hardware server, servo, planner, PLC link, control logic,
gateway) on the real-time clock with the simulated board and the PLC simulator on a pty pair,
and lets the control logic run automatic cycles of the demo nest (transport, pump, cut,
unload) for the measurement window, pressing the transport-station button when the
procedure asks. The control logic records, in 1 us histograms, how long each scan takes and
how late after its tick's deadline it woke (the jitter of its 4 ms period); the servo's
tick-to-speed-command latency and the PLC link's exchanges are read over the same window.
The figures are compared with the scan period (`logic_divisor` base ticks) and with the
servo's period.

    .venv/bin/python bench/logic_scan.py [--seconds 30] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from servo_timing import on_free_port, summarize  # noqa: E402

from cnc.bus.messages import CycleStart, Home, LoadProgram, Reset, SetMode  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.sim.demo import demo_program  # noqa: E402
from cnc.data.layout import ClockKind, LinkState, PlannerState  # noqa: E402
from cnc.logic.states import MachineState  # noqa: E402
from cnc.runtime.supervisor import Supervisor  # noqa: E402
from plc_link.sim_model import PlantTimes  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def ask(sup: Supervisor, command) -> None:
    reply = sup.logic.request(command)
    if not reply.ok:
        raise SystemExit(f"logic_scan: {type(command).__name__} refused: {reply.reason}")


def histograms(sup: Supervisor) -> dict[str, np.ndarray]:
    return {name: sup.timing(name)["hist"] for name in ("logic_scan", "logic_wake", "servo_timing")}


def run(machine: str, seconds: float) -> dict:
    config = on_free_port(load_machine(machine))
    with tempfile.TemporaryDirectory() as tmp:
        program = Path(tmp) / "nest.ngc"
        program.write_text(demo_program())
        sup = Supervisor(config, clock="realtime", history_path=Path(tmp) / "history.sqlite", log_level=logging.WARNING,
                         plc_sim_times=PlantTimes(feed_s=1.0, gripper_s=0.3, unload_s=1.0))
        sup.start()
        try:
            sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 20.0, "the PLC link")
            ask(sup, Reset())
            ask(sup, Home())
            logic = lambda: sup.area.reader("logic").read_dict()  # noqa: E731
            sup.wait_until(lambda: logic()["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                           120.0, "homing")
            ask(sup, LoadProgram(str(program)))
            ask(sup, SetMode("AUTO"))
            ask(sup, CycleStart(cycles=0))
            before, plc0, servo0, t0 = histograms(sup), sup.area.reader("plc").read_dict(), sup.servo(), time.monotonic()
            while time.monotonic() - t0 < seconds:
                lo = logic()
                if lo["procedure"] == "transport" and lo["procedure_state"] in ("running", "timed_out"):
                    sup.plc_sim.press_button()
                sup.poll()
                if sup.failed:
                    raise SystemExit(f"logic_scan: {sup.failed}")
                time.sleep(0.05)
            after, plc1, servo1, lo = histograms(sup), sup.area.reader("plc").read_dict(), sup.servo(), logic()
            elapsed = time.monotonic() - t0
            realtime = sup.hw()["clock_kind"] == ClockKind.REALTIME
        finally:
            sup.stop()
    period_us = config.timing.logic_divisor * config.timing.period_s * 1e6
    exchanges = plc1["exchanges"] - plc0["exchanges"]
    return {
        "seconds": elapsed,
        "realtime_granted": realtime,
        "scan_period_us": period_us,
        "scan": summarize(after["logic_scan"] - before["logic_scan"]).__dict__,
        "wake": summarize(after["logic_wake"] - before["logic_wake"]).__dict__,
        "servo": summarize(after["servo_timing"] - before["servo_timing"]).__dict__,
        "servo_period_us": config.timing.period_s * 1e6,
        "overruns": servo1["overruns"] - servo0["overruns"],
        "underruns": servo1["underruns"] - servo0["underruns"],
        "plc_exchanges": exchanges,
        "plc_failed": plc1["failed"] - plc0["failed"],
        "plc_mean_period_ms": 1000.0 * elapsed / exchanges if exchanges else float("nan"),
        "plc_target_ms": config.plc.cycle_ms,
        "cycles_done": lo["cycles_done"],
        "state": MachineState(lo["state"]).name,
    }


def report(r: dict) -> str:
    rows = [
        ("soft-PLC scan time", r["scan"], r["scan_period_us"], "scan period"),
        ("soft-PLC wake latency (jitter)", r["wake"], r["scan_period_us"], "scan period"),
        ("servo tick-to-speed-command", r["servo"], r["servo_period_us"], "servo period"),
    ]
    lines = [
        f"logic scan: whole controller on the real-time clock ({'SCHED_FIFO granted' if r['realtime_granted'] else 'NOT real-time'}), "
        f"automatic cycles for {r['seconds']:.0f} s ({r['cycles_done']} cycles done, state {r['state']})",
        "",
        f"{'us':<32}{'p50':>7}{'p99':>7}{'p99.9':>7}{'max':>7}{'samples':>9}   {'limit':>6}  max/limit",
    ]
    for name, lat, limit, what in rows:
        lines.append(f"{name:<32}{lat['p50_us']:>7}{lat['p99_us']:>7}{lat['p999_us']:>7}{lat['max_us']:>7}"
                     f"{lat['samples']:>9}   {limit:>6.0f}  {lat['max_us'] / limit:.2f} ({what})")
    lines += [
        "",
        f"servo overruns {r['overruns']}, FIFO underruns {r['underruns']}",
        f"PLC link: {r['plc_exchanges']} exchanges, {r['plc_failed']} failed, mean period {r['plc_mean_period_ms']:.1f} ms "
        f"(target {r['plc_target_ms']:.0f} ms, ratio {r['plc_mean_period_ms'] / r['plc_target_ms']:.2f})",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--json", metavar="OUT")
    args = parser.parse_args(argv)
    r = run(args.machine, args.seconds)
    print(report(r))
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
