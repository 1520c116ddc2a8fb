"""`waterjet materials`: the machine's material library from a shell.

    waterjet materials                                   every material, calibrated or not, its thicknesses
    waterjet materials show leather                      the chart, and the speed per quality at each row
    waterjet materials cut leather --thickness 2 --quality 3
    waterjet materials ladder leather --thickness 2 --from 3000 --to 24000 > ladder.ngc
    waterjet materials record leather --thickness 2 --separation 20000 \\
        --quality 20000,16000,12000,9000,6000 --pierce 0.3 --kerf 0.2 --who "A. Operator"

The library is `materials/` beside the machine file (`cnc.materials`). The ladder is checked
against the machine (its travel, its feed limits) as `waterjet check` would, before it is printed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .config import DEFAULT_MACHINE, machine_for_command
from .calibration import machine_ladder
from .cutmodel import library_of
from .materials import QUALITIES, Ladder, MaterialError, load_library, record_calibration


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--machine", default=DEFAULT_MACHINE, help="machine file (its materials/ directory is the library)")
    sub = parser.add_subparsers(dest="action")
    sub.add_parser("list", help="every material (the default)")
    show = sub.add_parser("show", help="one material's chart")
    show.add_argument("material")
    cut = sub.add_parser("cut", help="speed, pierce time and kerf for a thickness and quality")
    cut.add_argument("material")
    cut.add_argument("--thickness", type=float, required=True, metavar="MM")
    cut.add_argument("--quality", type=int, required=True, choices=QUALITIES)
    ladder = sub.add_parser("ladder", help="print a speed-ladder test program for a calibration")
    ladder.add_argument("material")
    ladder.add_argument("--thickness", type=float, required=True, metavar="MM")
    ladder.add_argument("--from", dest="slowest", type=float, required=True, metavar="MM_MIN", help="slowest rung")
    ladder.add_argument("--to", dest="fastest", type=float, required=True, metavar="MM_MIN", help="fastest rung")
    ladder.add_argument("--rungs", type=int, default=8)
    ladder.add_argument("--pierce", type=float, default=1.0, metavar="S", help="pierce dwell per rung (default 1 s)")
    record = sub.add_parser("record", help="write what a ladder showed into the material's chart")
    record.add_argument("material")
    record.add_argument("--thickness", type=float, required=True, metavar="MM")
    record.add_argument("--separation", type=float, required=True, metavar="MM_MIN",
                        help="the fastest rung that still cut through")
    record.add_argument("--quality", required=True, metavar="Q1,Q2,Q3,Q4,Q5",
                        help="per quality 1 to 5, the fastest rung whose edge was good enough")
    record.add_argument("--pierce", type=float, required=True, metavar="S", help="pierce time that went through")
    record.add_argument("--kerf", type=float, required=True, metavar="MM", help="kerf width measured")
    record.add_argument("--who", default="", help="who calibrated (kept in the file's source line)")
    record.add_argument("--lag", default="", metavar="L1,L2,L3,L4,L5",
                        help="trail-back measured on each quality's rung, mm (the corner and arc model, cnc.cutmodel)")


def run(args: argparse.Namespace) -> int:
    """0 done, 1 refused (a material or a request its chart cannot answer), 2 a bad machine file or argument."""
    config = machine_for_command(args.machine, "materials")
    if config is None:
        return 2
    directory = library_of(config)
    try:
        library = load_library(directory)
        action = args.action or "list"
        if action == "list":
            return _list(library, directory)
        material = library.get(args.material)
        if material is None:
            known = ", ".join(sorted(library)) or "none"
            print(f"waterjet materials: no material {args.material!r} in {directory} (known: {known})", file=sys.stderr)
            return 1
        if action == "show":
            return _show(material)
        if action == "cut":
            p = material.cut(args.thickness, args.quality)
            print(f"{material.name}, {args.thickness:g} mm, quality {args.quality}: {p.speed_mm_min:.0f} mm/min, "
                  f"pierce {p.pierce_s:g} s, kerf {p.kerf_mm:g} mm")
            return 0
        if action == "ladder":
            return _ladder(material, config, args)
        speeds = [float(s) for s in args.quality.split(",")]
        if len(speeds) != len(QUALITIES):
            print("waterjet materials: --quality takes five speeds, quality 1 to 5", file=sys.stderr)
            return 2
        lags = [float(x) for x in args.lag.split(",")] if args.lag else None
        if lags is not None and len(lags) != len(QUALITIES):
            print("waterjet materials: --lag takes five trail-backs, quality 1 to 5", file=sys.stderr)
            return 2
        m = record_calibration(directory / f"{material.id}.toml", args.thickness, args.separation, speeds, args.pierce,
                               args.kerf, args.who, lags)
        lo, hi = m.thickness_range
        print(f"{m.path}: {args.thickness:g} mm recorded; the chart covers " + (f"{lo:g} to {hi:g} mm" if hi > lo else f"{lo:g} mm"))
        return 0
    except MaterialError as exc:
        print(f"waterjet materials: {exc}", file=sys.stderr)
        return 1
    except ValueError as exc:
        print(f"waterjet materials: {exc}", file=sys.stderr)
        return 2



def _list(library: dict, directory: Path) -> int:
    if not library:
        print(f"no materials in {directory}")
        return 0
    for m in library.values():
        chart = (f"{len(m.chart)} thicknesses, {m.thickness_range[0]:g} to {m.thickness_range[1]:g} mm" if m.chart
                 else "not calibrated")
        print(f"{m.id:<16} {m.kind:<9} {chart:<40} {m.name}")
    return 0


def _show(m) -> int:  # noqa: ANN001 - a Material
    print(f"{m.name} ({m.id}, {m.kind} jet)\n  source: {m.source}")
    if m.head is not None:
        h = m.head
        print(f"  head: orifice {h.orifice_mm:g} mm, mixing tube {h.mixing_tube_mm:g} mm, {h.pressure_bar:g} bar, "
              f"abrasive {h.abrasive_kg_min:g} kg/min")
    if not m.chart:
        print("  no chart yet: calibrate it (waterjet materials ladder / record)")
        return 0
    print("  thickness mm  separation mm/min  pierce s  kerf mm  speed mm/min at quality 1..5"
          + ("      trail-back mm at quality 1..5" if any(r.lag_mm for r in m.chart) else ""))
    for r in m.chart:
        speeds = [m.cut(r.thickness_mm, q).speed_mm_min for q in QUALITIES]
        print(f"  {r.thickness_mm:12g}  {r.separation_mm_min:17g}  {r.pierce_s:8g}  {r.kerf_mm:7g}  "
              + " ".join(f"{s:7.0f}" for s in speeds) + ("  " + " ".join(f"{x:6.3g}" for x in r.lag_mm) if r.lag_mm else ""))
    if m.corner_mm:
        print("  corners and arcs: the bottom edge within " + ", ".join(f"{e:g}" for e in m.corner_mm)
              + " mm at quality 1..5")
    else:
        print("  corners and arcs: no corner_mm in [quality]: cut at the straight speed (no jet-lag slow-down)")
    return 0


def _ladder(material, config, args: argparse.Namespace) -> int:  # noqa: ANN001
    ladder = Ladder(args.thickness, args.slowest, args.fastest, rungs=args.rungs, pierce_s=args.pierce)
    sys.stdout.write(machine_ladder(material, ladder, config))
    return 0
