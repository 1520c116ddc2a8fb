#!/usr/bin/env python3
"""How long the planner's refills take, the worker's work done between them, against the FIFO's slack.

The planner process tops the setpoint FIFO up with a burst of `fifo_high_ms - fifo_low_ms`
records (20 at 1 ms) whenever it holds less than `fifo_low_ms`; a refill that takes longer than
the motion left in the FIFO lets it run dry. Everything slow is kept off the refill: the worker
thread makes the steps ahead, plans the look-ahead windows, solves the programmed corners ahead
(`cnc/planner/programme.py`, tens of milliseconds a corner) and decides the corner of the section
under way (`ProgramRunner.decide_corner`). This runs that order in one thread, as the process
interleaves it (the worker's turn after every refill), times each refill alone and the worker's
turns, and counts the corners the worker had not solved when the refill needed them (passed by the
planner's own plan: 0 when the worker kept ahead), on:

- the comparison's zigzag at 500 mm/s (`bench/linuxcnc_compare.py`: five programmed corners, 50 mm
  legs of about 0.15 s each),
- the comparison's nest (1823 lines at 40 mm/s: 66 programmed corners, rapid into lead-in), and
- the 60k-line CAM nest of `gcode_speed.py` (kerf compensation, arcs: none programmed).

From the repository root:

    .venv/bin/python bench/refill_latency.py [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import linuxcnc_compare as lc  # noqa: E402
from gcode_speed import nesting_program  # noqa: E402

from cnc.config import load_machine  # noqa: E402
from cnc.machine_dialect import dialect_for  # noqa: E402
from cnc.planner.process import PLAN_AHEAD_S  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402
from gcode.interp import Interpreter  # noqa: E402


def measure(name: str, program, config) -> dict:  # noqa: ANN001 - a Program, a MachineConfig
    """Refill by refill to the program's end, the worker's turn between: their wall times."""
    burst = round((config.planner.fifo_high_ms - config.planner.fifo_low_ms) / 1000.0 / config.timing.period_s)
    runner = ProgramRunner(program, config)
    runner.planned_ticks()  # the timing first, as loading makes it (not timed here)
    runner.solves_ahead = True
    refills, turns, records = [], [], 0
    while not runner.finished:
        wall = time.perf_counter()
        runner.build_ahead()
        while (job := runner.plan_job(PLAN_AHEAD_S)) is not None:
            job.compute()
            job.stream.accept(job)
        runner.solve_ahead()
        runner.decide_corner()
        turns.append(time.perf_counter() - wall)
        wall = time.perf_counter()
        made, _ = runner.take(burst)
        refills.append(time.perf_counter() - wall)
        records += len(made)
    refill_ms, turn_ms = np.array(refills) * 1e3, np.array(turns) * 1e3
    return {"program": name, "records": records, "burst": burst, "refills": len(refills),
            "refill_p99_ms": float(np.percentile(refill_ms, 99)), "refill_max_ms": float(refill_ms.max()),
            "turn_max_ms": float(turn_ms.max()), "late": runner.book.late,
            "slack_ms": config.planner.fifo_low_ms}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", metavar="OUT", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    rows = []
    for bench in lc.corner_benches() + [lc.nest_bench()]:
        if bench.name in ("zigzag F30000 P0.05", "nest 1823 lines F2400"):
            program, _ = lc.interpret_from_start(bench.text, config)
            rows.append(measure(bench.name, program, config))
    text = nesting_program(60_000)
    program = Interpreter(dialect_for(config), "nest60k.ngc").run(text.encode() if isinstance(text, str) else text)
    rows.append(measure("nesting 60k (gcode_speed)", program, config))
    print("refills of the setpoint FIFO with the worker's turn between (machines/waterjet.toml, one thread)")
    print(f"{'program':<28}{'records':>9}{'refills':>9}{'p99 ms':>8}{'max ms':>8}{'slack ms':>9}{'ratio':>7}"
          f"{'worker max ms':>14}{'late':>6}")
    for r in rows:
        print(f"{r['program']:<28}{r['records']:>9}{r['refills']:>9}{r['refill_p99_ms']:>8.2f}{r['refill_max_ms']:>8.2f}"
              f"{r['slack_ms']:>9.1f}{r['refill_max_ms'] / r['slack_ms']:>7.2f}{r['turn_max_ms']:>14.1f}"
              f"{r['late']:>6}")
    print("a refill: `take` of one burst (fifo_high_ms - fifo_low_ms records); slack: the motion the FIFO holds when a "
          "refill starts (fifo_low_ms); ratio: the slowest refill over it; worker: its slowest turn between two refills; "
          "late: corners not solved ahead when needed")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
