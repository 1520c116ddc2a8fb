"""CAM nests as a waterjet post writes them: per part a rapid, jet on, a pierce dwell, a G41/G42
lead-in, the contour in lines and arcs, a G40 lead-out, jet off; optionally each part a call of an
O-word subroutine, and inch parts among metric ones. Deterministic for a seed; used by the
interpretation tests (N against 2N parts) and `bench/gcode_speed.py`.
"""

from __future__ import annotations

import math
import random

from bench.gcode_speed import rounded_rect

SHEET_X, SHEET_Y = 1500.0, 1100.0  # the parts' origins stay on a 1600 x 1200 sheet


def cam_nest(parts: int, seed: int = 7, subroutines: bool = False, inch_every: int = 0, comments: bool = False) -> str:
    """A nest of `parts` parts (about 30 lines each). `subroutines`: each part's contour is an
    O-word subroutine called with its origin (#1, #2); `inch_every`: every n-th part is written in
    inches (G20, then G21 again); `comments`: a comment line before each part (a comment ends a
    bulk run of the fast path, so without them the runs are long)."""
    rng = random.Random(seed)
    out = ["%", f"(cam nest: {parts} parts, seed {seed})", "G21 G90 G17 G64 P0.05", "T1 M6", "F3000"]
    if subroutines:
        out += _subroutine()
    per_row = int(SHEET_X // 55.0)
    for p in range(parts):
        col, row = p % per_row, (p // per_row) % int(SHEET_Y // 45.0)
        ox, oy = 40.0 + col * 55.0, 40.0 + row * 45.0
        inch = inch_every > 0 and p % inch_every == inch_every - 1
        if comments:
            out.append(f"(part {p + 1})")
        if subroutines:
            out += [f"G0 X{ox:.3f} Y{oy - 3:.3f}", "M3", "G4 P0.3", f"O100 CALL [{ox:.3f}] [{oy:.3f}] [{rng.uniform(8, 18):.3f}]",
                    "M5"]
            continue
        s = 1 / 25.4 if inch else 1.0
        fmt = (lambda v: f"{v * s:.5f}") if inch else (lambda v: f"{v:.3f}")  # noqa: E731
        if inch:
            out.append("G20")
        side = "G41" if rng.random() < 0.7 else "G42"
        out += [f"G0 X{fmt(ox)} Y{fmt(oy - 3)}", "M3", "G4 P0.3", f"{side} D1 G1 X{fmt(ox)} Y{fmt(oy)} F{2400 * s:.1f}"]
        w, h, r = rng.uniform(20, 45), rng.uniform(15, 35), rng.uniform(2, 5)
        out += rounded_rect(ox, oy, w, h, r, rng.randint(4, 10), fmt, top_r=True)
        out += [f"G40 G1 X{fmt(ox - 2)} Y{fmt(oy - 2)}", "M5"]
        if inch:
            out.append("G21")
    out += ["G0 X0 Y0", "M2", "%"]
    return "\n".join(out) + "\n"


def production_nest(parts: int, shapes: int = 12, seed: int = 7, free: bool = False) -> str:
    """A production nest: `parts` copies of `shapes` different parts of `cam_nest`'s kind (lead-in
    with G41/G42, rounded rectangle in lines and arcs, lead-out), on a 55 x 45 mm grid, each part
    `shapes` places after its last copy: how a sheet of the same few parts is cut in a run. `free`:
    each part moved off its grid place by up to 4 mm, as a nesting program places them, so that its
    coordinates, written to 3 decimals, differ from its copies' by up to a micrometre."""
    rng = random.Random(seed)
    place = random.Random(seed + 1)
    kinds = [("G41" if rng.random() < 0.7 else "G42", rng.uniform(20, 45), rng.uniform(15, 35), rng.uniform(2, 5),
              rng.randint(4, 10)) for _ in range(shapes)]
    out = ["%", f"(production nest: {parts} parts of {shapes} shapes, seed {seed})", "G21 G90 G17 G64 P0.05", "T1 M6",
           "F3000"]
    per_row = int(SHEET_X // 55.0)
    fmt = lambda v: f"{v:.3f}"  # noqa: E731
    for p in range(parts):
        col, row = p % per_row, (p // per_row) % int(SHEET_Y // 45.0)
        ox, oy = 40.0 + col * 55.0, 40.0 + row * 45.0
        if free:
            ox, oy = ox + place.uniform(0.0, 4.0), oy + place.uniform(0.0, 4.0)
        side, w, h, r, steps = kinds[p % shapes]
        out += [f"G0 X{fmt(ox)} Y{fmt(oy - 3)}", "M3", "G4 P0.3", f"{side} D1 G1 X{fmt(ox)} Y{fmt(oy)} F2400.0"]
        out += rounded_rect(ox, oy, w, h, r, steps, fmt, top_r=True)
        out += [f"G40 G1 X{fmt(ox - 2)} Y{fmt(oy - 2)}", "M5"]
    out += ["G0 X0 Y0", "M2", "%"]
    return "\n".join(out) + "\n"


def turned_nest(parts: int, shapes: int = 12, seed: int = 7) -> str:
    """`production_nest`'s parts, each copy turned by a quarter, a half or three quarters of a turn
    or mirrored (across X, Y or a diagonal) about its pierce point, as a nesting program turns parts
    to fit and pairs left and right ones; a mirrored copy is compensated on the other side (G41 for
    G42) so that its kerf lies where the mirrored part's does. Copies of one shape in one orientation
    are placed as in `production_nest`; the orientations repeat every eight copies of a shape."""
    lines = production_nest(parts, shapes, seed).splitlines()
    out, part = [], -1
    pivot = turn = None
    for ln in lines:
        if ln.startswith("G0 X") and part + 1 < parts:
            part += 1
            words = _words(ln)
            ox, oy = 100.0 + (part % 14) * 100.0, 100.0 + ((part // 14) % 10) * 100.0  # room to turn
            shift = (ox - words["X"], oy - words["Y"])
            pivot = (words["X"], words["Y"])
            turn = _TURNS[(part // shapes) % len(_TURNS)]
            out.append(f"G0 X{ox:.3f} Y{oy:.3f}")
            continue
        if pivot is None or not ln.startswith(("G1", "G2", "G3", "G41", "G42", "G40")):
            out.append(ln)
            continue
        out.append(_turned(ln, pivot, shift, turn))
    return "\n".join(out) + "\n"


# (swap X and Y, sign of X, sign of Y): the identity, mirrors and quarter turns about the pivot
_TURNS = ((False, 1, 1), (True, -1, 1), (False, -1, -1), (True, 1, -1),
          (False, -1, 1), (False, 1, -1), (True, 1, 1), (True, -1, -1))


def _words(line: str) -> dict[str, float]:
    return {w[0]: float(w[1:]) for w in line.split() if w[0] in "XYIJR"}


def _turned(line: str, pivot: tuple[float, float], shift: tuple[float, float], turn: tuple[bool, int, int]) -> str:
    """One motion line of a part turned about `pivot` (its pierce point), then moved by `shift`."""
    swap, fx, fy = turn
    mirrored = (fx * fy < 0) != swap
    words = _words(line)
    codes = [w for w in line.split() if w[0] not in "XYIJR"]
    if mirrored:
        flip = {"G2": "G3", "G3": "G2", "G41": "G42", "G42": "G41"}
        codes = [flip.get(c, c) for c in codes]

    def vec(x: float, y: float) -> tuple[float, float]:
        if swap:
            x, y = y, x
        return fx * x, fy * y
    out = list(codes)
    if "X" in words:
        x, y = vec(words["X"] - pivot[0], words["Y"] - pivot[1])
        out += [f"X{pivot[0] + shift[0] + x:.3f}", f"Y{pivot[1] + shift[1] + y:.3f}"]
    if "I" in words:
        i, j = vec(words["I"], words["J"])
        out += [f"I{i:.3f}", f"J{j:.3f}"]
    if "R" in words:
        out.append(f"R{words['R']:.3f}")
    return " ".join(out)


def _subroutine() -> list[str]:
    """O100: a round part of radius #3 at (#1, #2), lead-in with G41, 24 chords and two arcs."""
    body = ["O100 SUB", "G41 D1 G1 X[#1 + #3] Y#2 F2400"]
    for k in range(1, 23):
        a = 2 * math.pi * k / 24
        body.append(f"G1 X[#1 + #3 * COS[{math.degrees(a):.4f}]] Y[#2 + #3 * SIN[{math.degrees(a):.4f}]]")
    body += ["G3 X[#1 + #3] Y#2 R#3", "G40 G1 X[#1 + #3 + 2] Y[#2 - 2]", "O100 ENDSUB"]
    return body
