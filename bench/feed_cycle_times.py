#!/usr/bin/env python3
"""Cycle time of a CAM nest at the feeds a waterjet cuts at, against what no planner can beat.

A waterjet cuts slowly (a few hundred to a few thousand mm/min) and stops at every pierce, so
its cycle time is made of many short speed changes from rest to the cutting feed and back.
This plans the LinuxCNC comparison's nest (`linuxcnc_compare.nest_bench`: about 70 parts of
bench/gcode_speed.py, kerf applied by CAM, no jet) written at each feed, with the code the
planner runs (`ProgramTiming`, the planned profile's servo periods), and prints beside it, for
the same program and limits:

- the feed bound: every element at its feed (or its axes' top speed) with no acceleration;
- the jerk-limited bound: the feed bound plus the least a jerk- and acceleration-limited
  start and stop cost (`linuxcnc_compare.jerk_bound_s`; corners not counted).

The ratio is ours over the jerk-limited bound. From the repository root:

    .venv/bin/python bench/feed_cycle_times.py [--feeds 300,600,1200,2400,6000] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import linuxcnc_compare as lc  # noqa: E402

from cnc.config import load_machine  # noqa: E402
from cnc.planner.steps import ProgramTiming  # noqa: E402

NEST_FEED = "F2400"  # the feed the nest is written at (`gcode_speed.nesting_program`)


def measure(feed_mm_min: int, config) -> dict:  # noqa: ANN001 - a MachineConfig
    text = lc.nest_bench().text
    assert NEST_FEED in text, "the nest's feed is no longer written as F2400"
    program, _ = lc.interpret_from_start(text.replace(NEST_FEED, f"F{feed_mm_min}"), config)
    wall = time.perf_counter()
    timing = ProgramTiming.of(program, config)
    wall = time.perf_counter() - wall
    if timing.failure is not None:
        raise timing.failure
    ours = timing.total_ticks * timing.dt
    return {"feed_mm_min": feed_mm_min, "ours_s": ours, "feed_bound_s": lc.feed_bound_s(program, config),
            "jerk_bound_s": lc.jerk_bound_s(program, config), "planning_wall_s": wall}


def render(rows: list[dict]) -> str:
    out = ["nest of the LinuxCNC comparison, planned at each feed (machines/waterjet.toml, no jet delays)",
           f"{'feed mm/min':>11}  {'ours s':>9}  {'feed bound s':>12}  {'jerk bound s':>12}  {'ours / jerk bound':>17}"]
    for r in rows:
        out.append(f"{r['feed_mm_min']:>11}  {r['ours_s']:>9.3f}  {r['feed_bound_s']:>12.3f}  {r['jerk_bound_s']:>12.3f}"
                   f"  {r['ours_s'] / r['jerk_bound_s']:>17.4f}")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--feeds", default="300,600,1200,2400,6000", help="mm/min, comma-separated")
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args(argv)
    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    rows = [measure(int(f), config) for f in args.feeds.split(",")]
    print(render(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
