#!/usr/bin/env python3
"""Cycle time of parts whose kerf the controller compensates, with and without the planner's
folding of the kerf arcs, beside LinuxCNC 2.9 on the same programs and limits.

Kerf compensation (G41/G42 D1) rounds every outside corner of the compensated path with an arc of
the kerf's radius (0.125 mm on the shipped machine), the few degrees between two chords of a curve
too, and enters each part with a lead-in, a kink and such an arc. Held to that radius's
centripetal jerk, the head crawls through each; the planner folds such an arc with the lines
beside it into one corner within P (`cnc/planner/sections.py` `_fold_small_turns`,
`_fold_small_arcs`). For each program this prints our cycle time, ours with the arcs kept (the
folds switched off in this process only), LinuxCNC's (`bench/linuxcnc_compare.py`'s runner, its
tool table holding the same kerf, when LinuxCNC is installed) and the ratios, and our largest
deviation from the compensated path as programmed against P. The programs:

- a circle of 60 chords (R20, clockwise), compensated on the outside (G41: an arc at every vertex)
  and on the inside (G42: none),
- regular polygons turning 30, 45, 60 and 90 degrees at each corner, on the outside and inside,
- `bench/nests.py` `cam_nest(20)` without its jet and pierce lines (rounded rectangles entered
  under G41/G42: one kerf arc per part, at its entry).

From the repository root (about three minutes with LinuxCNC, most of it LinuxCNC's real time):

    .venv/bin/python bench/kerf_corners.py [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))
sys.path.insert(0, str(BENCH))

import linuxcnc_compare as lc  # noqa: E402 - bench/ is put on the path above
import linuxcnc_sim  # noqa: E402
from nests import cam_nest  # noqa: E402
from cnc.config import MachineConfig, load_machine  # noqa: E402
from cnc.planner import sections  # noqa: E402

FEED = 2400
TOLERANCE_MM = 0.05


def _program(side: str, points: list[tuple[float, float]], lead: tuple[float, float]) -> str:
    x0, y0 = points[0]
    return "\n".join([f"G21 G90 G17 G64 P{TOLERANCE_MM:g}", f"G0 X{x0 + lead[0]:.4f} Y{y0 + lead[1]:.4f}",
                      f"{side} D1 G1 X{x0:.4f} Y{y0:.4f} F{FEED}", *[f"G1 X{x:.4f} Y{y:.4f}" for x, y in points[1:]],
                      f"G40 G1 X{x0 + 3.0:.4f} Y{y0 + 3.0:.4f}", "M2"]) + "\n"


def programs() -> list[tuple[str, str]]:
    """(name, text) of every program measured."""
    out = []
    circle = [(300.0 + 20.0 * math.sin(2.0 * math.pi * k / 60), 280.0 + 20.0 * math.cos(2.0 * math.pi * k / 60))
              for k in range(61)]
    for side, where in (("G41", "outside"), ("G42", "inside")):
        out.append((f"circle 60 chords, {where}", _program(side, circle, (0.0, 3.0))))
    for turn in (30, 45, 60, 90):
        n = 360 // turn
        polygon = [(300.0 + 20.0 * math.cos(math.radians(-turn * k)), 300.0 + 20.0 * math.sin(math.radians(-turn * k)))
                   for k in range(n + 1)]
        for side, where in (("G41", "outside"), ("G42", "inside")):
            out.append((f"polygon {turn} deg turns, {where}", _program(side, polygon, (3.0, -3.0))))
    nest = [ln for ln in cam_nest(20).splitlines() if not lc.NEST_DROPPED.match(ln)]
    out.append(("cam_nest(20), entries", "\n".join(nest) + "\n"))
    return out


def ours(text: str, config: MachineConfig, fold: bool) -> lc.Figures:
    """Our planner's figures on `text`; `fold` False: the kerf arcs kept (the folds switched off)."""
    kept = (sections._fold_small_turns, sections._fold_small_arcs)
    if not fold:
        sections._fold_small_turns = lambda run, *_: run
        sections._fold_small_arcs = lambda groups, *_: groups
    try:
        program, start = lc.interpret_from_start(text, config)
        return lc.run_ours(program, start, config, lc.line_kinds(text), lc.line_parts(text))
    finally:
        sections._fold_small_turns, sections._fold_small_arcs = kept


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, metavar="OUT", help="write every figure here")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    available, reason = linuxcnc_sim.available()
    rows = []
    with tempfile.TemporaryDirectory(prefix="kerf_corners-") as tmp:
        for name, text in programs():
            folded, kept = ours(text, config, True), ours(text, config, False)
            theirs = None
            if available:
                path = Path(tmp) / "program.ngc"
                path.write_text(text)
                program, start = lc.interpret_from_start(text, config)
                try:
                    theirs = lc.run_theirs(path, program, start, config, lc.line_kinds(text), lc.line_parts(text))
                except linuxcnc_sim.LinuxCNCUnavailable as exc:
                    available, reason = False, str(exc)
            rows.append({"program": name, "ours_s": folded.cycle_time_s, "arcs_kept_s": kept.cycle_time_s,
                         "linuxcnc_s": theirs.cycle_time_s if theirs else None,
                         "ours_deviation_mm": folded.max_deviation_mm, "tolerance_mm": TOLERANCE_MM})
            print(f"  {name}: done ({time.monotonic() - t0:.0f} s)", file=sys.stderr)
    peer = reason if available else f"LinuxCNC (unavailable: {reason})"
    print(f"kerf compensated by the controller (D1: {config.nozzle[0].kerf_mm:g} mm kerf), F{FEED}, P{TOLERANCE_MM:g}; "
          f"ours vs {peer}")
    print(f"{'program':<32} {'ours s':>8} {'arcs kept s':>12} {'kept/ours':>10} {'LCNC s':>8} {'ours/LCNC':>10} "
          f"{'dev mm':>8} {'/P':>5}")
    for r in rows:
        lcnc = f"{r['linuxcnc_s']:8.3f} {r['ours_s'] / r['linuxcnc_s']:10.3f}" if r["linuxcnc_s"] else f"{'-':>8} {'-':>10}"
        print(f"{r['program']:<32} {r['ours_s']:8.3f} {r['arcs_kept_s']:12.3f} {r['arcs_kept_s'] / r['ours_s']:10.3f} "
              f"{lcnc} {r['ours_deviation_mm']:8.4f} {r['ours_deviation_mm'] / TOLERANCE_MM:5.2f}")
    print(f"ran in {time.monotonic() - t0:.0f} s")
    if args.json:
        args.json.write_text(json.dumps({"peer": peer, "rows": rows}, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
