#!/usr/bin/env python3
"""Fault reactions on the real-time clock: every fault of `cnc.faultinject` injected into a cut.

On the real-time clock a tick is a millisecond of wall time, so the figures count everything
from the injection: the detection of a fault the controller learns of in wall time (a process
dying: the supervisor's poll, a PLC link: three exchanges, a pump: the next PLC read) and the
reaction. The tests (`tests/test_fault_injection.py`) check the reaction bounds on the virtual
clock; this prints the whole figure beside each fault's reaction bound, and the ratio.

    python bench/faults.py [--repeat N]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

from cnc.config import load_machine
from cnc.demo import free_port
from cnc.faultinject import (
    CUT_PROGRAM, FAST_PLANT, SCENARIO_OVERRIDES, Reaction, catalogue, inject_during_cut, ready_to_cut, recover, start_cut,
)
from cnc.supervisor import Supervisor

REPO = Path(__file__).resolve().parent.parent


def run(machine: str, repeat: int, workdir: Path) -> list[tuple[str, list[Reaction]]]:
    """Every fault `repeat` times (the hardware server once, last: it ends the controller)."""
    config = load_machine(machine, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **SCENARIO_OVERRIDES})
    program = workdir / "cut.ngc"
    program.write_text(CUT_PROGRAM)
    faults = catalogue()
    results: dict[str, list[Reaction]] = {f.name: [] for f in faults}
    with Supervisor(config, clock="realtime", history_path=workdir / "history.sqlite", plc_sim_times=FAST_PLANT) as sup:
        ready_to_cut(sup, program)
        start_cut(sup)
        for _ in range(repeat):
            for fault in faults:
                if fault.process == "hardware":
                    continue
                results[fault.name].append(inject_during_cut(sup, fault))
                recover(sup, fault, program)
        hardware = next(f for f in faults if f.process == "hardware")
        results[hardware.name].append(inject_during_cut(sup, hardware))
    return [(f.name, results[f.name]) for f in faults]


SUPERVISOR_POLL_MS = 50.0  # `waterjet up` polls its processes this often (Supervisor.run)


def detection_ms(name: str, config) -> float:  # noqa: ANN001 - a MachineConfig
    """How long the controller may take to learn of this fault, by design (0: at once, in the tick)."""
    plc = config.plc
    if name.startswith("kill -9"):
        return SUPERVISOR_POLL_MS
    if name == "PLC link cut":  # the exchanges under way, then lost_after_cycles failed ones
        return (plc.lost_after_cycles + 1) * (plc.cycle_ms + plc.timeout_ms)
    if name == "pump pressure drop":  # the line's pressure falls (the plant), then the next reads
        return 100.0 + 2 * plc.cycle_ms
    return 0.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--repeat", type=int, default=3, help="injections of each fault (default 3)")
    args = parser.parse_args(argv)
    bounds = {f.name: f for f in catalogue()}
    with tempfile.TemporaryDirectory(prefix="wj-faults-") as tmp:
        results = run(args.machine, args.repeat, Path(tmp))
    config = load_machine(args.machine)
    print(f"fault reactions on the real-time clock (1 tick = 1 ms), {args.repeat} injection(s) each, worst shown;")
    print("limit = the time the controller may take to learn of the fault (by design) + the reaction bound")
    print(f"{'fault':<34}{'jet off':>8}{'limit':>7}{'ratio':>7}{'stopped':>9}{'limit':>7}{'ratio':>7}   {'state reached':<22}alarm")
    for name, reactions in results:
        b = bounds[name]
        if reactions[0].jet_off_ticks < 0:
            r = reactions[0]
            print(f"{name:<34}{'-':>8}{'':>7}{'':>7}{'-':>9}{'':>7}{'':>7}   {r.state} after {r.detect_ms:.0f} ms; {r.alarm}")
            continue
        jet = max(x.jet_off_ticks for x in reactions)
        stop = max(x.stopped_ticks for x in reactions)
        budget = round(detection_ms(name, config))
        jet_limit, stop_limit = budget + b.jet_ticks, budget + b.stop_ticks
        r = reactions[-1]
        print(f"{name:<34}{jet:>8}{jet_limit:>7}{jet / jet_limit:>6.2f}x{stop:>9}{stop_limit:>7}{stop / stop_limit:>6.2f}x   "
              f"{r.state:<22}{r.alarm}{'; ' + r.restarted if r.restarted else ''}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
