#!/usr/bin/env python3
"""How long the planner takes to make a restart inside a large CAM nest: "continue" a cut stopped
half-way through the nest, "start at part N" and "run from line L" (`cnc/planner/recovery.py`,
with the travel check the planner runs on it), beside the program's interpretation (the peer: a
start that had to interpret the program again would wait that long). The restart is made on the
planner's helper thread while its loop answers stop and hold; this is how long the operator
waits between the cycle's start and the rapid to the restart point. From the repository root:

    .venv/bin/python bench/restart.py [--parts 40000] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.nests import cam_nest  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.machine_dialect import dialect_for  # noqa: E402
from cnc.planner.preflight import preflight  # noqa: E402
from cnc.planner.recovery import continue_at, cut_starts, run_from_line, start_at_part  # noqa: E402
from gcode.interp import Interpreter  # noqa: E402

MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"


def _best_of(runs: int, make) -> tuple[float, object]:
    """The fastest of `runs` calls of `make()` (wall seconds) and its result."""
    best, out = float("inf"), None
    for _ in range(runs):
        t0 = time.perf_counter()
        out = make()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--parts", type=int, default=40000, help="parts of the CAM nest (about 24 lines each)")
    ap.add_argument("--runs", type=int, default=3, help="each figure is the fastest of this many")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    config = load_machine(MACHINE)
    text = cam_nest(args.parts).encode()
    dialect = dataclasses.replace(dialect_for(config), start_position_mm=(0.0, 0.0, 0.0))
    interpret_s, program = _best_of(args.runs, lambda: Interpreter(dialect, "nest.ngc").run(text))
    homed = dict.fromkeys(config.axis_names, True)
    head = (1.0, 1.0, 0.0)
    middle = cut_starts(program)[args.parts // 2] + 3  # a contour's move half-way through the nest
    seg = program.segments[middle]
    stopped = tuple((seg["start"][:2] + seg["end"][:2]) / 2.0) if int(seg["kind"]) == 1 else tuple(seg["end"][:2])
    restarts = {
        "continue (half-way)": lambda: continue_at(program, middle, stopped, 2.0, head),
        "start at part N/2": lambda: start_at_part(program, args.parts // 2, head),
        "run from line L/2": lambda: run_from_line(program, program.stats.lines // 2, head),
    }
    rows = []
    for name, make in restarts.items():
        def checked(make=make):
            restart = make()
            preflight(restart.program.segments, config, homed, "nest.ngc")
            return restart
        seconds, restart = _best_of(args.runs, checked)
        rows.append({"restart": name, "seconds": seconds, "segments": len(restart.program.segments),
                     "ratio_to_interpretation": seconds / interpret_s})
    lines = program.stats.lines
    print(f"cam_nest({args.parts}): {lines} lines, {len(program.segments)} segments; fastest of {args.runs}")
    print(f"{'':28s}{'seconds':>9s}  {'/ interpretation':>16s}")
    print(f"{'interpretation (the peer)':28s}{interpret_s:9.3f}  {1.0:16.2f}")
    for r in rows:
        print(f"{r['restart']:28s}{r['seconds']:9.3f}  {r['ratio_to_interpretation']:16.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"parts": args.parts, "lines": lines, "interpret_s": interpret_s,
                                               "restarts": rows}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
