#!/usr/bin/env python3
"""Planner throughput: seconds of motion planned and interpolated per wall second, against 50x real time.

The controller's planner must make setpoints much faster than the servo uses them, on a
shared 2-core machine, while the rest of the controller runs. This measures the planner's
own work on the 60k-line nesting program of `gcode_speed.py` (small leather parts: pierces,
rounded rectangles of short polylines, circles of arcs and chords, slots, kerf
compensation), in one process, with no other controller process running:

- plan only: the cycle time from the planned profile (what `waterjet check` prints);
- plan and interpolate: every setpoint record of the program, made in bursts of the size the
  planner process pushes (`[planner] fifo_high_ms - fifo_low_ms` records), as it does.

Interpretation is timed apart (the G-code benchmark covers it). Figures are medians of
`--repeat` runs, each in the same process; the target is >= 50x real time.

    python bench/planner_throughput.py [--repeat 3] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

from gcode_speed import nesting_program

from cnc.config import load_machine
from cnc.machine_dialect import dialect_for
from cnc.planner.runner import ProgramRunner
from cnc.planner.sections import Section, iter_steps
from cnc.planner.overlap import CornerOverlap
from cnc.planner.steps import ProgramTiming
from gcode.interp import interpret

REPO = Path(__file__).resolve().parent.parent
TARGET_X = 50.0


def run_once(program, config, burst: int) -> dict:
    """Plan, then plan and interpolate, the whole program; wall seconds and motion seconds."""
    dt = config.timing.period_s
    t0 = time.perf_counter()
    kinds: list[bool] = []  # per step: a section (motion) or a pause

    def noted():
        for step in iter_steps(program, config):
            kinds.append(isinstance(step, Section))
            yield step
    timing = ProgramTiming(dt, CornerOverlap.of(config)).compute(noted())
    planned = timing.total_ticks
    t1 = time.perf_counter()
    moving = sum(t for t, is_section in zip(timing.step_ticks, kinds) if is_section)
    runner = ProgramRunner(program, config)
    made = 0
    while not runner.finished:
        records, _ = runner.take(burst)
        made += len(records)
    t2 = time.perf_counter()
    return {"motion_s": made * dt, "moving_s": moving * dt, "planned_s": planned * dt, "plan_wall_s": t1 - t0,
            "interpolate_wall_s": t2 - t1}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs to take the median of (default 3)")
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--json", metavar="OUT", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    config = load_machine(args.machine)
    burst = round((config.planner.fifo_high_ms - config.planner.fifo_low_ms) / 1000.0 / config.timing.period_s)
    text = nesting_program()
    t0 = time.perf_counter()
    program = interpret(text, dialect_for(config))
    interp_s = time.perf_counter() - t0
    runs = [run_once(program, config, burst) for _ in range(args.repeat)]
    motion_s, moving_s = runs[0]["motion_s"], runs[0]["moving_s"]
    if any(abs(r["motion_s"] - r["planned_s"]) > 1e-6 for r in runs):
        print("planner_throughput: the records made differ from the planned cycle time", file=sys.stderr)
        return 1
    plan_s = statistics.median(r["plan_wall_s"] for r in runs)
    interp_wall = statistics.median(r["interpolate_wall_s"] for r in runs)
    rows = [("plan only (cycle time, as waterjet check)", plan_s), ("plan and interpolate every setpoint", interp_wall)]
    lines = [
        f"planner throughput: nesting 60k ({program.stats.lines} lines, {program.stats.segments} segments, "
        f"{program.stats.pierces} pierces), {motion_s:.1f} s of program at 100 % override, of which "
        f"{moving_s:.1f} s in motion (the rest: pierces, dwells, jet delays)",
        f"interpretation (not counted): {interp_s:.2f} s; setpoints in bursts of {burst}; median of {args.repeat} runs",
        "",
        f"{'':<44}{'wall s':>9}{'x program':>12}{'x motion':>11}{'target':>9}{'ratio':>8}",
    ]
    figures = {}
    for label, wall in rows:
        x, xm = motion_s / wall, moving_s / wall
        lines.append(f"{label:<44}{wall:>9.2f}{x:>11.1f}x{xm:>10.1f}x{TARGET_X:>8.0f}x{xm / TARGET_X:>7.2f}x")
        figures[label] = {"wall_s": wall, "x_program_time": x, "x_motion_time": xm}
    lines.append("x program: program time (pauses included) per wall second; x motion: time in motion only, "
                 "against the target")
    print("\n".join(lines))
    if args.json:
        Path(args.json).write_text(json.dumps({
            "program_lines": program.stats.lines, "segments": program.stats.segments, "motion_s": motion_s,
            "moving_s": moving_s,
            "interpretation_s": interp_s, "burst": burst, "runs": runs, "figures": figures, "target_x": TARGET_X,
        }, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
