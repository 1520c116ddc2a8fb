#!/usr/bin/env python3
"""Planned cycle time of CAM nests as `waterjet check` makes it, each shape of part timed once.

A production nest cuts the same few parts again and again at other places; the program's timing
(`ProgramTiming.of`) makes each run of elements between two pauses once per shape and takes the
copies' servo periods from it (`cnc.planner.sections.RunMemo`). This times, with the code
`waterjet check` runs, on one CPU (the timing whole) and on every CPU this process may use (in
pieces cut at pierces, one process each):

- `production_nest`: N copies of 12 shapes on a grid (`bench/nests.py`),
- the same placed freely (each part moved off its grid place by up to 4 mm, its coordinates written
  to 3 decimals: copies that differ by that rounding, which the memo does not take for copies),
- the same turned and mirrored (`turned_nest`: each shape's copies in eight orientations, as a
  nesting program turns parts to fit and pairs left and right ones), and
- `cam_nest`: N parts all different (the memo finds nothing to reuse but the rapids),

each against the same timing without the memo (every run made), the cycle times compared to the
tick, and the speed as a multiple of real time against issue 19's target of 10,000x. From the
repository root:

    .venv/bin/python bench/timing_memo.py [--parts 3000] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.nests import cam_nest, production_nest, turned_nest  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.machine_dialect import dialect_for  # noqa: E402
from cnc.planner.overlap import CornerOverlap  # noqa: E402
from cnc.planner.sections import iter_steps  # noqa: E402
from cnc.planner.steps import ProgramTiming, timing_workers  # noqa: E402
from gcode.interp import Interpreter  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
TARGET_X = 10_000.0


def _timed(make) -> tuple[ProgramTiming, float]:  # noqa: ANN001 - a callable giving a ProgramTiming
    wall = time.perf_counter()
    timing = make()
    wall = time.perf_counter() - wall
    if timing.failure is not None:
        raise timing.failure
    return timing, wall


def measure(name: str, text: str, config, workers: int) -> dict:  # noqa: ANN001 - a MachineConfig
    dialect = dataclasses.replace(dialect_for(config), start_position_mm=(0.0, 0.0, 0.0))
    program = Interpreter(dialect, f"{name}.ngc").run(text.encode())
    every, every_s = _timed(lambda: ProgramTiming(config.timing.period_s, CornerOverlap.of(config)).compute(
        iter_steps(program, config)))
    one, one_s = _timed(lambda: ProgramTiming.of(program, config))
    many, many_s = _timed(lambda: ProgramTiming.of(program, config, workers=workers))
    if not (list(every.step_ticks) == list(one.step_ticks) == list(many.step_ticks)):
        raise SystemExit(f"timing_memo: {name}: the memo's step ticks differ from every run made")
    cycle = every.total_ticks * every.dt
    return {"program": name, "lines": program.stats.lines, "pierces": program.stats.pierces, "cycle_s": cycle,
            "every_run_s": every_s, "memo_1cpu_s": one_s, "memo_cpus_s": many_s, "workers": workers,
            "x_real_time_1cpu": cycle / one_s, "x_real_time_cpus": cycle / many_s}


def render(rows: list[dict]) -> str:
    out = [f"planned cycle time of CAM nests, each shape timed once (machines/waterjet.toml; {rows[0]['workers']} CPUs)",
           f"{'program':<26}{'lines':>8}{'cycle s':>11}{'every run s':>13}{'memo 1 CPU s':>14}{'ratio':>7}"
           f"{'memo, CPUs s':>14}{'x real time':>13}{'target':>9}{'ratio':>7}"]
    for r in rows:
        out.append(f"{r['program']:<26}{r['lines']:>8}{r['cycle_s']:>11.1f}{r['every_run_s']:>13.2f}"
                   f"{r['memo_1cpu_s']:>14.2f}{r['memo_1cpu_s'] / r['every_run_s']:>7.3f}{r['memo_cpus_s']:>14.2f}"
                   f"{r['x_real_time_cpus']:>12.0f}x{TARGET_X:>8.0f}x{r['x_real_time_cpus'] / TARGET_X:>7.2f}")
    out.append("every run: the timing without the memo, one CPU (the peer); ratio: the memo's time over it; x real time: "
               "cycle time per wall second of the timing on every CPU")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", type=int, default=3000, help="parts of each nest (default 3000)")
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--json", metavar="OUT", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    config = load_machine(args.machine)
    workers = timing_workers()
    rows = [measure(f"production_nest({args.parts})", production_nest(args.parts), config, workers),
            measure("  placed freely", production_nest(args.parts, free=True), config, workers),
            measure("  turned and mirrored", turned_nest(args.parts), config, workers),
            measure(f"cam_nest({args.parts})", cam_nest(args.parts), config, workers)]
    print(render(rows))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
