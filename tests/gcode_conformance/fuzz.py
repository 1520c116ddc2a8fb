#!/usr/bin/env python3
"""Differential fuzz of our interpreter against LinuxCNC's `rs274`: random CAM-like programs.

    python tests/gcode_conformance/fuzz.py 0 1000      # seeds 0..999; prints each difference

Each seed makes a program as a nesting post or a hand edit would write it: parts with kerf
compensation (G41/G42 with a tool's D, G41.1/G42.1 with a diameter) on rounded rectangles,
full circles (P turns), slots of R semicircles and stars of acute corners, holes clockwise,
written in G90 or G91, in G20 or G21 (switched between parts), in rotated and offset work
systems (G10 L2 R, G92), with O-word subroutines, expressions, line numbers, spaces inside
words, Z moves and dwells. Both interpreters read it: where rs274 refuses it, ours must refuse
it at the same line; where rs274 runs it, ours must make the same segments (the comparison of
test_gcode_conformance.py). Differences found this way are fixed and pinned down as
conformance programs (kerf_full_circle_rotated_incremental, arc_rounded_to_cam_decimals,
errors/kerf_inch_arc_sweeps_past_its_corner).

Known and accepted: a G20 semicircle in R form written to 4 decimals misses its radius by
exactly 0.00005 inch, LinuxCNC's tolerance; rounding alone decides rs274's comparison, and it
refuses some such arcs that we run (`gcode.arcs.R_FORM_SLACK_MM`).
"""

from __future__ import annotations

import math
import random
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

def _number(rng: random.Random, v: float) -> str:
    """A coordinate as CAM posts and hand edits write it: 4 or 2 decimals, sometimes an expression."""
    c = rng.random()
    if c < 0.1:
        return f"[{v/2:.4f}*2]"
    if c < 0.15:
        return f"[{v + 1:.4f} - 1]"
    if c < 0.2 and abs(v) < 1e4:
        return f"{v:.2f}"
    return f"{v:.4f}"

def _word(rng: random.Random, letter: str, v: float) -> str:
    sp = " " if rng.random() < 0.05 else ""
    return f"{letter}{sp}{_number(rng, v)}"

def _contour(rng: random.Random, ox: float, oy: float, hole: bool) -> list[tuple]:
    """Segments (kind, x, y, extra) of a closed shape from (ox, oy): a rounded rectangle (I/J or R
    corners), a full circle, a slot of R semicircles or a star of acute corners; a hole runs clockwise."""
    w, h = rng.uniform(8, 50), rng.uniform(8, 50)
    r = rng.uniform(0.3, min(w, h) / 2.2)
    k = rng.random()
    if k < 0.4:
        pts = [("L", ox + w - r, oy), ("A", ox + w, oy + r, (0, r)), ("L", ox + w, oy + h - r), ("A", ox + w - r, oy + h, (-r, 0)),
               ("L", ox + r, oy + h), ("A", ox, oy + h - r, (0, -r)), ("L", ox, oy + r), ("A", ox + r, oy, (r, 0))]
    elif k < 0.6:
        rad = rng.uniform(2, 15)
        pts = [("C", ox, oy, (0, rad))]
    elif k < 0.8:  # slot with R arcs (half circles)
        ln, rad = rng.uniform(5, 30), rng.uniform(1, 6)
        pts = [("L", ox + ln, oy), ("R", ox + ln, oy + 2 * rad, rad), ("L", ox, oy + 2 * rad), ("R", ox, oy, rad)]
    else:  # star-ish polygon with acute corners
        n = rng.randint(3, 7)
        pts = []
        for i in range(1, 2 * n + 1):
            a = math.pi * i / n
            rr = (w / 2) if i % 2 == 0 else (w / 2) * rng.uniform(0.3, 0.8)
            pts.append(("L", ox + rr * math.sin(a), oy + w / 2 - rr * math.cos(a)))
        pts[-1] = ("L", ox, oy)
    if hole:  # reverse direction: CW
        rev = []
        seq = [(ox, oy)] + [(p[1], p[2]) for p in pts]
        for i in range(len(pts) - 1, -1, -1):
            p = pts[i]
            start = seq[i]
            if p[0] == "L":
                rev.append(("L", start[0], start[1]))
            elif p[0] == "A":
                cx, cy = seq[i][0] + p[3][0], seq[i][1] + p[3][1]
                rev.append(("Acw", start[0], start[1], (cx - p[1], cy - p[2])))
            elif p[0] == "R":
                rev.append(("Rcw", start[0], start[1], p[3]))
            else:
                rev.append(("Ccw", p[1], p[2], p[3]))
        if seq[-1] != (ox, oy):
            rev.insert(0, ("L", seq[-1][0], seq[-1][1]))
        pts = rev
    return pts

def program(seed: int) -> str:
    """A CAM-like program of 1-4 parts, the same for the same seed."""
    rng = random.Random(seed)
    inch = rng.random() < 0.2
    u = 25.4 if inch else 1.0
    out = [rng.choice(["G17 G21 G40 G90 G94", "g17 g21 g40 g90 g94", "G17G21G40G90G94"]).replace("G21", "G20" if inch else "G21").replace("g21", "g20" if inch else "g21")]
    subs = rng.random() < 0.25
    if subs:
        out.append("o100 sub")
        out.append("G91 G1 X#1 Y0")
        out.append("G2 X0 Y0 I[#2] J0" if rng.random() < 0.5 else "G3 X0 Y0 I0 J[#2]")
        out.append("G90")
        out.append("o100 endsub")
    if rng.random() < 0.2:
        out.append(f"G10 L2 P2 X{rng.uniform(-30, 30)/u:.3f} Y{rng.uniform(-30, 30)/u:.3f} R{rng.choice([0, 10, 45, 90, 180, -30])}")
        out.append("G55")
    if rng.random() < 0.2:
        out.append(f"G92 X{rng.uniform(-20, 20)/u:.3f} Y{rng.uniform(-20, 20)/u:.3f}")
    tool = rng.randint(1, 4)
    out.append(f"T{tool} M6")
    out.append(rng.choice(["G64 P0.05", "G61", "G64", "G64 P0.01 Q0.01"]))
    out.append(f"F{rng.choice([300, 600, 2400, 6000]) / u:.3f}")
    for p in range(rng.randint(1, 4)):
        ox, oy = rng.uniform(-150, 150), rng.uniform(-150, 150)
        hole = rng.random() < 0.35
        comp = rng.choice(["", "G41", "G42", "G41", "G42", "G41.1", "G42.1"])
        dword = f"D{rng.randint(1, 4)}" if not comp.endswith(".1") else f"D{rng.choice([0.5, 1.0, 2.0]) / u:.4f}"
        pre = f"N{100 + p * 10} " if rng.random() < 0.2 else ""
        out.append(f"{pre}G0 X{(ox - 4)/u:.4f} Y{(oy - 4)/u:.4f}")
        if rng.random() < 0.3:
            out.append(f"G0 Z{rng.choice([5, 1, 0])/u:.3f}")
        out.append("M3" if rng.random() < 0.5 else "M7")
        if rng.random() < 0.3:
            out.append(f"G4 P{rng.choice([0.1, 0.5])}")
        if rng.random() < 0.3:
            out.append(f"G1 Z{rng.choice([-1, 0])/u:.3f}")
        lead = f"G1 {_word(rng, 'X', ox/u)} {_word(rng, 'Y', oy/u)}"
        if comp:
            lead = (f"{comp} {dword} " if rng.random() < 0.7 else f"{comp} {dword}\n") + lead
        out.append(lead)
        if subs and rng.random() < 0.5 and not comp:
            out.append(f"o100 call [{rng.uniform(1, 5)/u:.4f}] [{rng.uniform(2, 9)/u:.4f}]")
        else:
            inc = rng.random() < 0.25
            if inc:
                out.append("G91")
            cx, cy = ox, oy
            for s in _contour(rng, ox, oy, hole):
                x, y = s[1], s[2]
                dx, dy = (x - cx, y - cy) if inc else (x, y)
                ep = f"{_word(rng, 'X', dx/u)} {_word(rng, 'Y', dy/u)}"
                if s[0] == "L":
                    out.append(f"G1 {ep}")
                elif s[0] in ("A", "Acw"):
                    g = "G3" if s[0] == "A" else "G2"
                    i, j = s[3]
                    if rng.random() < 0.3:
                        out.append(f"{g} {ep} R{math.hypot(i, j)/u:.4f}")
                    else:
                        out.append(f"{g} {ep} I{i/u:.4f} J{j/u:.4f}")
                elif s[0] in ("R", "Rcw"):
                    g = "G3" if s[0] == "R" else "G2"
                    out.append(f"{g} {ep} R{s[3]/u:.4f}")
                else:
                    g = "G3" if s[0] == "C" else "G2"
                    i, j = s[3]
                    ep = "X0 Y0" if inc else f"X{cx/u:.4f} Y{cy/u:.4f}"
                    out.append(f"{g} {ep} I{i/u:.4f} J{j/u:.4f}" + (f" P{rng.randint(1, 3)}" if rng.random() < 0.2 else ""))
                cx, cy = x, y
            if inc:
                out.append("G90")
        if comp:
            out.append(f"G40 G1 X{(ox - 3)/u:.4f} Y{(oy - 3)/u:.4f}" if rng.random() < 0.7 else "G40")
        out.append("M5" if rng.random() < 0.6 else "M9")
        if rng.random() < 0.1:
            out.append(f"T{rng.randint(1, 4)} M6")
        if rng.random() < 0.1:
            inch = not inch
            u = 25.4 if inch else 1.0
            out.append(f"G20 F{600/25.4:.3f}" if inch else f"G21 F600")
    if rng.random() < 0.2:
        out.append("G53 G0 X0 Y0")
    out.append(rng.choice(["M2", "M30"]))
    seen = {}
    final = []
    for l in "\n".join(out).split("\n"):
        seen[l] = seen.get(l, 0) + 1
        final.append(l if seen[l] == 1 else f"{l} (#{seen[l]})")
    return "\n".join(final) + "\n"


def differs(seed: int, tmp: Path, rs274: str) -> str | None:
    """What differs between rs274 and us on the program of `seed`, None when nothing does."""
    from tests.test_gcode_conformance import compare_segments, error_line, load_jsonl, regen, run_check

    prog = tmp / f"fuzz{seed}.ngc"
    prog.write_text(program(seed))
    proc = regen.run_rs274(prog, rs274)
    err = regen.rs274_error(proc)
    out = tmp / f"fuzz{seed}.jsonl"
    ours = run_check(prog, tmp, out)
    said = (ours.stdout + ours.stderr)[-400:]
    if err is not None:
        try:
            want = regen.error_line_number(prog, err[1])
        except regen.RegenError:
            want = None  # rs274 named a line whose text is not unique: the exit code is compared
        line = error_line(ours.stdout + "\n" + ours.stderr)
        if ours.returncode != 1 or (want is not None and line != want):
            return f"rs274 refuses it at line {want} ({err[0]}); ours exits {ours.returncode} naming line {line}: {said}"
        return None
    if ours.returncode != 0:
        return f"rs274 runs it; ours refuses it: {said}"
    problem = compare_segments(load_jsonl(out), regen.canon_to_segments(proc.stdout))
    return None if problem is None else f"the segments differ: {problem}"


def main(argv: list[str] | None = None) -> int:
    from tests.test_gcode_conformance import regen

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    rs274 = regen.find_rs274()
    if rs274 is None:
        print("fuzz: rs274 not found; install LinuxCNC (Debian: apt-get install linuxcnc-uspace)", file=sys.stderr)
        return 2
    lo, hi = int(args[0]), int(args[1])
    found = 0
    with tempfile.TemporaryDirectory(prefix="gcode-fuzz-") as tmp:
        for seed in range(lo, hi):
            problem = differs(seed, Path(tmp), rs274)
            if problem:
                found += 1
                print(f"seed {seed}: {problem}", flush=True)
    print(f"{hi - lo} programs, {found} differ")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
