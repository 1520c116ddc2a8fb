#!/usr/bin/env python3
"""Fault reactions on the real-time clock: every fault of `cnc.sim.faultinject` injected into a cut.

On the real-time clock a tick is a millisecond of wall time, so the figures count everything
from the injection: the detection of a fault the controller learns of in wall time (a process
dying: the supervisor's poll; the PLC link: its exchanges; the pump: the next PLC read; a hung
process: its heartbeat or the FIFO running dry) and the reaction. For each fault it prints the
worst of the injections: ticks to the tick that acted, ticks from there to the jet closed, the
stop distance against its bound (v T_detect + v^2/2a + v a/2j + 1 mm, with the T_detect
measured) and the ratio; the tests (`tests/test_fault_injection.py`, `tests/test_safety_matrix.py`)
check the same on the virtual clock and on the tick rig.

    python bench/faults.py [--repeat N] [--only TEXT]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from cnc.config import load_machine
from cnc.sim.demo import free_port
from cnc.sim.faultinject import (
    FAST_PLANT, SCENARIO_OVERRIDES, Reaction, catalogue, inject_during_cut, pause_on_the_straight, recover,
)
from cnc.data.layout import ServoFault
from cnc.runtime.supervisor import Supervisor

REPO = Path(__file__).resolve().parent.parent


def run(machine: str, repeat: int, workdir: Path, only: str = "") -> list[tuple[str, list[Reaction]]]:
    """Every fault (those whose name holds `only`) `repeat` times (the hardware server once, last:
    it ends the controller)."""
    config = load_machine(machine, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **SCENARIO_OVERRIDES})
    faults = [f for f in catalogue() if only in f.name]
    results: dict[str, list[Reaction]] = {f.name: [] for f in faults}
    unexpected.clear()
    with Supervisor(config, clock="realtime", history_path=workdir / "history.sqlite", plc_sim_times=FAST_PLANT) as sup:
        for _ in range(repeat):
            for fault in faults:
                if fault.process == "hardware":
                    continue
                try:
                    pause_on_the_straight(sup, workdir, fault.speed_mm_s)
                except TimeoutError as exc:  # a trip nobody injected stopped the set-up: this injection is skipped
                    unexpected.append(f"before {fault.name}: {exc}; {_trip(sup)}")
                    continue
                try:
                    results[fault.name].append(inject_during_cut(sup, fault))
                finally:
                    fault.clear(sup)
                try:
                    recover(sup, fault, workdir, fault.speed_mm_s)
                except TimeoutError as exc:  # the next fault's set-up resets and starts a cut again
                    unexpected.append(f"after {fault.name}: {exc}; {_trip(sup)}")
        hardware = next((f for f in faults if f.process == "hardware"), None)
        for _ in range(3 if hardware is not None else 0):
            try:
                pause_on_the_straight(sup, workdir, hardware.speed_mm_s)
            except TimeoutError as exc:
                unexpected.append(f"before {hardware.name}: {exc}; {_trip(sup)}")
                continue
            results[hardware.name].append(inject_during_cut(sup, hardware))
            break
    return [(f.name, results[f.name]) for f in faults]


# Trips nobody injected, seen while the machine was brought back to cutting: on a real-time clock
# they are the host's latency (a servo that missed 5 ticks is a watchdog trip) and belong in the
# report rather than ending the run.
unexpected: list[str] = []


def _trip(sup: Supervisor) -> str:
    sv, hw = sup.servo(), sup.area.reader("hw").read_dict()
    return (f"servo trip {ServoFault(sv['trip_fault']).name} (trip {sv['trip_seq']}), servo overruns {sv['overruns']}, "
            f"late ticks {hw['late_ticks']}, servo missed ticks {hw['servo_missed_total']}")


def report(results: list[tuple[str, list[Reaction]]], repeat: int) -> list[str]:
    lines = [f"fault reactions on the real-time clock (1 tick = 1 ms), {repeat} injection(s) each, the worst shown",
             f"{'fault':<34}{'v mm/s':>7}{'detect':>8}{'jet off':>8}{'stop mm':>9}{'bound mm':>10}{'ratio':>7}   "
             f"{'state reached':<44}alarm"]
    for name, reactions in results:
        if not reactions:
            continue
        worst = max(reactions, key=lambda r: (r.stop_mm / r.bound_mm) if r.bound_mm else r.stop_mm)
        if worst.jet_off_ticks < 0 and worst.bound_mm is None and worst.detect_ticks < 0:
            lines.append(f"{name:<34}{'':>7}{'-':>8}{'-':>8}{'-':>9}{'':>10}{'':>7}   "
                         f"{worst.state} after {worst.detect_ms:.0f} ms; {worst.alarm}")
            continue
        detect = max(r.detect_ticks for r in reactions)
        jet = max(r.jet_off_ticks for r in reactions)
        bound = "coast" if worst.bound_mm is None else f"{worst.bound_mm:.2f}"
        ratio = "" if worst.bound_mm is None else f"{worst.stop_mm / worst.bound_mm:.2f}x"
        lines.append(f"{name:<34}{worst.speed_mm_s:>7.0f}{detect:>8}{jet:>8}{worst.stop_mm:>9.2f}{bound:>10}{ratio:>7}   "
                     f"{worst.state:<44}{worst.alarm}{'; ' + worst.restarted if worst.restarted else ''}")
    lines.append("detect: ticks from the injection to the tick that acted (its wall-time detection included); jet off: "
                 "ticks from that tick to the jet valve closed; bound: v T_detect + v^2/2a + v a/2j + 1 mm "
                 "(a feed hold: plus the FIFO's lead); coast: category 0, the drives lost their power")
    lines += [f"unexpected trip while recovering {u}" for u in unexpected] or ["no unexpected trip while recovering"]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--repeat", type=int, default=3, help="injections of each fault (default 3)")
    parser.add_argument("--only", default="", help="only the faults whose name holds this text (e.g. 'bug in')")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="wj-faults-") as tmp:
        results = run(args.machine, args.repeat, Path(tmp), args.only)
    print("\n".join(report(results, args.repeat)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
