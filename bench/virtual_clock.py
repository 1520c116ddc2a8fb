#!/usr/bin/env python3
"""How fast the virtual clock ticks: the hand-offs between the lockstep processes.

On the virtual clock the hardware server wakes its timer clients (servo every tick; planner,
control logic and logger every few) and waits for each to finish before the next tick. Each
hand-off is a semaphore; a process blocked on one is woken by the kernel, which on a virtual
machine with idle CPUs costs tens of microseconds each way. The controller polls briefly before
it blocks (`cnc.hw.timers`, VIRTUAL_SPIN_NS). The peer, in the same run, is the same controller
with polling off (every hand-off blocks).

For three controllers (no planner, the servo fed directly; motion: planner, no soft-PLC; the
whole controller with the PLC simulator), the axes holding position, it times `run_ticks(N)`
from a paused clock. Then, for the whole controller, what a test stepping the paused clock a tick
at a time pays a step (`run_ticks(1)`, which polls for its tick), against the tick running free
measured in the same run.

    .venv/bin/python bench/virtual_clock.py [--ticks 5000] [--runs 3] [--steps 1000] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cnc.config import load_machine  # noqa: E402
from cnc.data.layout import LinkState, ServoState  # noqa: E402
from cnc.hw import timers  # noqa: E402
from cnc.runtime import supervisor as supervisor_module  # noqa: E402
from cnc.runtime.supervisor import DIRECT_FEED, MOTION_ONLY, Supervisor  # noqa: E402

MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"
KINDS = {"servo fed directly": DIRECT_FEED, "motion (planner)": MOTION_ONLY, "whole controller": None}


def tick_us(kind: str, processes, ticks: int, history: Path) -> float:
    """Wall time per tick of `ticks` ticks, the axes holding (drives on, no motion)."""
    from cnc.sim.faultinject import FAST_PLANT

    config = load_machine(MACHINE)
    extra = {"processes": processes} if processes is not None else {"history_path": history, "plc_sim_times": FAST_PLANT}
    with Supervisor(config, clock="virtual", **extra) as sup:
        if processes is None:
            sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 20.0, "the PLC link")
        sup.enable()
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 20.0, "the servo to hold")
        sup.pause_virtual_clock()
        t0 = time.perf_counter()
        sup.run_ticks(ticks, timeout_s=600.0)
        return (time.perf_counter() - t0) / ticks * 1e6


def step_us(steps: int, history: Path) -> tuple[float, float]:
    """Wall time of one `run_ticks(1)` from a pause, and of a tick within `run_ticks(steps)`."""
    from cnc.sim.faultinject import FAST_PLANT

    config = load_machine(MACHINE)
    with Supervisor(config, clock="virtual", history_path=history, plc_sim_times=FAST_PLANT) as sup:
        sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 20.0, "the PLC link")
        sup.enable()
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 20.0, "the servo to hold")
        sup.pause_virtual_clock()
        t0 = time.perf_counter()
        for _ in range(steps):
            sup.run_ticks(1)
        stepped = (time.perf_counter() - t0) / steps * 1e6
        t0 = time.perf_counter()
        sup.run_ticks(steps, timeout_s=600.0)
        return stepped, (time.perf_counter() - t0) / steps * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=5000)
    ap.add_argument("--runs", type=int, default=3, help="runs of each, the median is shown")
    ap.add_argument("--steps", type=int, default=1000, help="single steps of the paused clock timed")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind, processes in KINDS.items():
            got = {}
            for way, spin in (("polling", timers.VIRTUAL_SPIN_NS), ("blocking", 0)):
                supervisor_module.VIRTUAL_SPIN_NS = spin
                got[way] = statistics.median(
                    tick_us(kind, processes, args.ticks, Path(tmp) / f"h{i}.sqlite") for i in range(args.runs))
            supervisor_module.VIRTUAL_SPIN_NS = timers.VIRTUAL_SPIN_NS
            rows.append({"controller": kind, "polling_us": got["polling"], "blocking_us": got["blocking"]})
        stepped, free = step_us(args.steps, Path(tmp) / "steps.sqlite")
    print(f"virtual clock, axes holding: wall time per tick ({args.ticks} ticks, median of {args.runs} runs)\n")
    print(f"{'controller':24s} {'polling us':>11s} {'blocking us':>12s} {'ratio':>6s}")
    for r in rows:
        print(f"{r['controller']:24s} {r['polling_us']:11.0f} {r['blocking_us']:12.0f} {r['polling_us'] / r['blocking_us']:6.2f}")
    print(f"\nwhole controller, paused clock stepped {args.steps} times a tick at a time, then {args.steps} ticks at once\n")
    print(f"{'one step us':>12s} {'a free tick us':>15s} {'ratio':>6s}")
    print(f"{stepped:12.0f} {free:15.0f} {stepped / free:6.2f}")
    if args.json:
        args.json.write_text(json.dumps({"ticks": rows, "step_us": stepped, "free_tick_us": free}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
