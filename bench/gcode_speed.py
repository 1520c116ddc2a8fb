"""G-code interpretation speed and memory, beside gcodeparser (tokenising only) and LinuxCNC's rs274.

Two generated programs:
- a 60k-line nesting program: many small leather parts (rounded rectangles, circles, slots)
  with pierce dwell, kerf-compensated lead-in and lead-out, lines, I/J arcs, R arcs, jet on/off;
- the same nesting program with the kerf already applied by the CAM system (no G41/G40),
  as many CAM posts write it; it separates the cost of our kerf compensation;
- a 1M-line program: long CAM polylines (splines broken into short lines) with some arcs;
- CAM nests of 7000 parts as a waterjet post writes them (`bench/nests.py`: a comment, rapid,
  jet on, pierce dwell, G41/G42 lead-in, lines and arcs, G40 lead-out, jet off per part), also
  with every third part in inches, and with each part an O-word subroutine call.

Every tool runs in its own fresh process on the same file, so that peak memory is
comparable: the high-water mark of resident memory (VmHWM) of the measuring process, which
includes the Python interpreter and numpy for the Python tools; rs274's is its own max RSS.
Targets (issues 3 and 19): full interpretation at >= 2x gcodeparser's tokenise-only rate and
faster than rs274 on every program without subroutines, at least half rs274's rate on the
subroutine nest; the 1M-line program in under 4 s and 400 MB.

    python bench/gcode_speed.py [--out DIR] [--json FILE]
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import re
import random
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
RS274 = shutil.which("rs274")
TOOL_TABLE = "T1 P1 D0.25 Z0 ;0.25 mm kerf\nT2 P2 D0.4 Z0\n"


def nesting_program(target_lines: int = 60_000, seed: int = 2) -> str:
    """Many small parts on a 1600 x 1200 sheet, as a nesting CAM post would write them."""
    rng = random.Random(seed)
    out = ["%", "(nesting: leather parts, generated)", "G21 G90 G17 G64 P0.05", "T1 M6", "F3000"]
    col = row = 0
    while len(out) < target_lines:
        ox, oy = 20 + col * 55.0, 20 + row * 45.0
        col += 1
        if ox > 1500:
            col, row = 0, row + 1
            if oy > 1100:
                row = 0
        kind = rng.random()
        out.append(f"G0 X{ox:.3f} Y{oy - 3:.3f}")
        out.append("M3")
        out.append("G4 P0.3")
        out.append(f"G41 D1 G1 X{ox:.3f} Y{oy:.3f} F2400")
        if kind < 0.5:  # rounded rectangle, corners as I/J arcs, long sides as short polylines
            w, h, r = rng.uniform(20, 45), rng.uniform(15, 35), rng.uniform(2, 5)
            out.extend(_rounded_rect(ox, oy, w, h, r, rng))
        elif kind < 0.8:  # circle approximated by R arcs and short lines
            rad = rng.uniform(8, 18)
            cx, cy = ox, oy + rad
            n = rng.randint(24, 60)
            for k in range(1, n + 1):
                a = -math.pi / 2 + 2 * math.pi * k / n
                x, y = cx + rad * math.cos(a), cy + rad * math.sin(a)
                out.append(f"G3 X{x:.4f} Y{y:.4f} R{rad:.4f}" if k % 3 == 0 else f"G1 X{x:.4f} Y{y:.4f}")
        else:  # slot: two lines and two half circles
            ln, rad = rng.uniform(15, 35), rng.uniform(3, 6)
            out += [
                f"G1 X{ox + ln:.3f} Y{oy:.3f}",
                f"G3 X{ox + ln:.3f} Y{oy + 2 * rad:.3f} I0 J{rad:.3f}",
                f"G1 X{ox:.3f} Y{oy + 2 * rad:.3f}",
                f"G3 X{ox:.3f} Y{oy:.3f} I0 J{-rad:.3f}",
            ]
        out.append(f"G40 G1 X{ox - 2:.3f} Y{oy - 2:.3f}")
        out.append("M5")
    out += ["G0 X0 Y0", "M2", "%"]
    return "\n".join(out) + "\n"


def _rounded_rect(x: float, y: float, w: float, h: float, r: float, rng: random.Random) -> list[str]:
    return rounded_rect(x, y, w, h, r, rng.randint(4, 12))


def rounded_rect(x: float, y: float, w: float, h: float, r: float, steps: int,
                 fmt=lambda v: f"{v:.3f}", top_r: bool = False) -> list[str]:
    """A rounded rectangle from its lower-left corner (x, y), counter-clockwise: the long sides as
    `steps` short lines, three corners as I/J arcs (the top right one an R arc with `top_r`)."""
    top = f"R{fmt(r)}" if top_r else f"I{fmt(-r)} J0"
    lines = [f"G1 X{fmt(x + (w - r) * k / steps)} Y{fmt(y)}" for k in range(1, steps + 1)]
    lines += [f"G3 X{fmt(x + w)} Y{fmt(y + r)} I0 J{fmt(r)}", f"G1 X{fmt(x + w)} Y{fmt(y + h - r)}",
              f"G3 X{fmt(x + w - r)} Y{fmt(y + h)} {top}"]
    lines += [f"G1 X{fmt(x + w - r - (w - 2 * r) * k / steps)} Y{fmt(y + h)}" for k in range(1, steps + 1)]
    lines += [f"G3 X{fmt(x)} Y{fmt(y + h - r)} I0 J{fmt(-r)}", f"G1 X{fmt(x)} Y{fmt(y)}"]
    return lines


def million_line_program(target_lines: int = 1_000_000, seed: int = 3) -> str:
    """Long polylines (splines as short lines) with some arcs, jet on along each contour."""
    rng = random.Random(seed)
    out = ["G21 G90 G17", "F6000"]
    while len(out) < target_lines:
        x, y = rng.uniform(100, 1500), rng.uniform(100, 1100)
        out += [f"G0 X{x:.3f} Y{y:.3f}", "M3"]
        heading = rng.uniform(0, 2 * math.pi)
        for _ in range(rng.randint(500, 3000)):
            heading += rng.uniform(-0.08, 0.08)
            step = rng.uniform(0.2, 1.5)
            nx = min(max(x + step * math.cos(heading), 1.0), 1599.0)
            ny = min(max(y + step * math.sin(heading), 1.0), 1199.0)
            if rng.random() < 0.03 and math.hypot(nx - x, ny - y) > 0.1:
                out.append(f"G2 X{nx:.4f} Y{ny:.4f} R{rng.uniform(5, 50):.4f}")
            else:
                out.append(f"G1 X{nx:.4f} Y{ny:.4f}")
            x, y = nx, ny
        out.append("M5")
    out.append("M2")
    return "\n".join(out[:target_lines]) + "\nM2\n"


_OURS = """
import sys, time, json
from cnc.config import load_machine
from cnc.machine_dialect import dialect_for
from gcode.interp import Interpreter
cfg = load_machine(sys.argv[2])
dialect = dialect_for(cfg, sys.argv[3])
data = open(sys.argv[1], 'rb').read()
t = time.perf_counter()
p = Interpreter(dialect, sys.argv[1]).run(data)
dt = time.perf_counter() - t
hwm = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM:'))
print(json.dumps({"seconds": dt, "lines": p.stats.lines, "segments": int(p.stats.segments), "peak_mb": hwm / 1024}))
"""

_GCODEPARSER = """
import sys, time, json, warnings
warnings.simplefilter('ignore')
from gcodeparser import GcodeParser
text = open(sys.argv[1]).read()
t = time.perf_counter()
lines = GcodeParser(text).lines
dt = time.perf_counter() - t
hwm = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM:'))
print(json.dumps({"seconds": dt, "lines": text.count(chr(10)), "segments": len(lines), "peak_mb": hwm / 1024}))
"""

_RS274 = """
import os, resource, subprocess, sys, tempfile, time, json
home = tempfile.mkdtemp()  # rs274 keeps a tool mmap in $HOME and a .var file in its cwd
t = time.perf_counter()
proc = subprocess.run(sys.argv[1:], capture_output=True, text=True, cwd=home, env={**os.environ, "HOME": home})
dt = time.perf_counter() - t
note = "" if proc.returncode == 0 else "FAILED: " + (proc.stderr.strip().splitlines() or ["?"])[min(1, len(proc.stderr.strip().splitlines()) - 1)][:70]
print(json.dumps({"seconds": dt, "peak_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, "note": note}))
"""


def run_python(code: str, *args: str) -> dict:
    """Run a measurement in a fresh interpreter, which reports its time and its own peak RSS."""
    proc = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=REPO, timeout=1800)
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or ["failed"])[-1][:100]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_rs274(path: str, tool_table: str) -> dict:
    """LinuxCNC's standalone interpreter (output to /dev/null), timed and measured by a wrapper process.

    Standalone rs274 reads tool-table diameters in inches, so it gets a copy converted from mm.
    """
    if RS274 is None:
        return {"error": "rs274 not installed (Debian package linuxcnc-uspace)"}
    inch_table = Path(tool_table).with_suffix(".inch.tbl")
    inch_table.write_text(re.sub(r"D([0-9.]+)", lambda m: f"D{float(m.group(1)) / 25.4:.6f}", Path(tool_table).read_text()))
    res = run_python(_RS274, RS274, "-t", str(inch_table), "-g", path, "/dev/null")
    if "error" not in res:
        with open(path) as f:
            res["lines"] = sum(1 for _ in f)
    return res


def best_of(repeat: int, tools: dict) -> dict:
    """Each tool run `repeat` times, the tools taking turns (so that a slow spell of the host
    falls on all of them); the fastest run of each, with how many runs were made."""
    runs = {name: [] for name in tools}
    for _ in range(max(1, repeat)):
        for name, run in tools.items():
            runs[name].append(run())
    best = {}
    for name, results in runs.items():
        good = [r for r in results if "error" not in r]
        best[name] = dict(min(good, key=lambda r: r["seconds"]), runs=len(results)) if good else results[0]
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="where to write the generated programs (default: a temp dir)")
    ap.add_argument("--json", default=None, help="write all figures as JSON")
    ap.add_argument("--lines", type=int, default=1_000_000, help="size of the large program")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs per tool and program, each in a fresh process; the fastest counts (this VM's speed varies)")
    args = ap.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="gcode_speed_"))
    out.mkdir(parents=True, exist_ok=True)
    tool_table = out / "tool.tbl"
    tool_table.write_text(TOOL_TABLE)
    machine = REPO / "machines" / "waterjet.toml"
    files = {
        "nesting 60k": out / "nesting_60k.ngc",
        f"polyline {args.lines // 1000}k": out / "polyline_1m.ngc",
    }
    nesting = nesting_program()
    files["nesting 60k"].write_text(nesting)
    # the same parts with the kerf already applied by the CAM system (no G41/G40 in the program)
    files["nesting, CAM kerf"] = out / "nesting_60k_cam_kerf.ngc"
    files["nesting, CAM kerf"].write_text(nesting.replace("G41 D1 ", "").replace("G40 ", ""))
    del nesting
    files[f"polyline {args.lines // 1000}k"].write_text(million_line_program(args.lines))
    sys.path.insert(0, str(REPO))
    from bench.nests import cam_nest

    for name, options in (("cam nest 7000", {}), ("cam nest, inch mix", {"inch_every": 3}),
                          ("cam nest, subroutines", {"subroutines": True})):
        files[name] = out / (name.replace(" ", "_").replace(",", "") + ".ngc")
        files[name].write_text(cam_nest(7000, comments=True, **options))
    gc.collect()  # the measuring processes start small: nothing of the generated text stays here
    results = {}
    for name, path in files.items():
        results[name] = best_of(args.repeat, {
            "ours (full interpretation)": lambda: run_python(_OURS, str(path), str(machine), str(tool_table)),
            "gcodeparser (tokenise only)": lambda: run_python(_GCODEPARSER, str(path)),
            "rs274 (LinuxCNC, full)": lambda: run_rs274(str(path), str(tool_table)),
        })
    print(render(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return 0


def render(results: dict) -> str:
    rows = [f"{'program':<22} {'tool':<28} {'lines':>9} {'seconds':>8} {'lines/s':>10} {'peak MB':>8} "
            f"{'vs gcodeparser':>15} {'vs rs274':>9}"]
    for name, tools in results.items():
        refs = [tools["gcodeparser (tokenise only)"], tools["rs274 (LinuxCNC, full)"]]
        ref_rates = [r["lines"] / r["seconds"] if "seconds" in r else None for r in refs]
        for tool, r in tools.items():
            if "error" in r:
                rows.append(f"{name:<22} {tool:<28} {'-':>9} {'-':>8} {'-':>10} {'-':>8} {'-':>15} {'-':>9}  ({r['error']})")
                continue
            rate = r["lines"] / r["seconds"]
            ratios = [f"{rate / ref:.2f}x" if ref else "-" for ref in ref_rates]
            peak = f"{r['peak_mb']:.0f}" if r.get("peak_mb") else "-"
            note = f"  ({r['note']})" if r.get("note") else ""
            rows.append(f"{name:<22} {tool:<28} {r['lines']:>9} {r['seconds']:>8.2f} {rate:>10,.0f} {peak:>8} "
                        f"{ratios[0]:>15} {ratios[1]:>9}{note}")
    rows.append("targets: ours >= 2x gcodeparser's rate and above rs274's on programs without subroutines, >= 0.5x "
                "rs274's on the subroutine nest; the 1M-line program in < 4 s and < 400 MB peak")
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main())
