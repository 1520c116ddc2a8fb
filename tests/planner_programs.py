"""Seeded random G-code for planner tests: polylines, tangent and angled arcs, rapids, dwells,
jet switching, feed and tolerance changes, all within the shipped machine's travel."""

from __future__ import annotations

import math
import random


def random_program(seed: int, n: int = 40) -> str:
    """A valid program of about n moves, the same for the same seed."""
    rng = random.Random(seed)
    x, y = 800.0, 600.0
    heading = rng.uniform(0, 2*math.pi)
    out = ["G21 G90", f"G64 P{rng.choice([0.01, 0.05, 0.2])}", f"G0 X{x:.4f} Y{y:.4f}"]
    feed = rng.choice([600, 3000, 12000, 30000])
    out.append(f"F{feed}")
    jet = False
    for _ in range(n):
        r = rng.random()
        if r < 0.08:
            out.append(rng.choice(["G61", "G64 P0.05", "G64 P0.01", "G64 P0.5"]))
        if r < 0.15:
            jet = not jet
            out.append("M3" if jet else "M5")
        kind = rng.random()
        if kind < 0.5:  # line
            heading += rng.choice([rng.uniform(-0.05, 0.05), rng.uniform(-1.5, 1.5), rng.uniform(-3.0, 3.0)])
            L = rng.choice([rng.uniform(0.2, 2.0), rng.uniform(2, 60)])
            x2, y2 = x + L*math.cos(heading), y + L*math.sin(heading)
            if not (20 < x2 < 1580 and 20 < y2 < 1180):
                heading += math.pi; continue
            x, y = x2, y2
            out.append(f"G1 X{x:.4f} Y{y:.4f}" + (f" F{rng.choice([600, 3000, 12000, 30000])}" if rng.random() < 0.1 else ""))
        elif kind < 0.8:  # tangent or angled arc
            R = rng.choice([rng.uniform(0.5, 5), rng.uniform(5, 80)])
            turn = rng.uniform(0.1, 3.0) * rng.choice([-1, 1])
            if rng.random() < 0.3:
                heading += rng.uniform(-1, 1)
            cw = turn < 0
            nx, ny = (-math.sin(heading), math.cos(heading)) if not cw else (math.sin(heading), -math.cos(heading))
            cx, cy = x + R*nx, y + R*ny
            a0 = math.atan2(y - cy, x - cx)
            a1 = a0 + turn
            x2, y2 = cx + R*math.cos(a1), cy + R*math.sin(a1)
            if not (20 < x2 < 1580 and 20 < y2 < 1180 and 20 < cx - R and cx + R < 1580 and 20 < cy - R and cy + R < 1180):
                continue
            out.append(f"{'G2' if cw else 'G3'} X{x2:.4f} Y{y2:.4f} I{cx-x:.4f} J{cy-y:.4f}")
            x, y = x2, y2
            heading += turn
        elif kind < 0.9:
            x2, y2 = rng.uniform(50, 1550), rng.uniform(50, 1150)
            out.append(f"G0 X{x2:.4f} Y{y2:.4f}"); x, y = x2, y2
        else:
            out.append(f"G4 P{rng.choice([0.0, 0.01, 0.1])}")
    out.append("M5"); out.append("M2")
    return "\n".join(out) + "\n"
