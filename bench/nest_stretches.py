"""The comparison nest's stretches between parts beside the least time any jerk-limited trajectory needs there.

`bench/linuxcnc_compare.py` finds the nest 0.4 % slower than LinuxCNC 2.9 and its closed-form bound
(`jerk_bound_s`) far below both: it counts no corner, so it cannot say whether the rest of the gap is
the jerk limit (which LinuxCNC does not have) or our planner. Between two parts the head runs a
lead-out, a rapid of 55 mm to the next part and its lead-in: two sharp corners within a rapid's ramp
of each other, where each part of the nest is slower than LinuxCNC (the contours are not). This
bench takes each such stretch, from the middle of the lead-out to the middle of the lead-in, and
states three times for it, from the same program run the same way:

- the least servo periods of any trajectory holding the axes' velocity, acceleration and jerk, the
  leads' feed and G64 P (`corner_bound.stretch_ticks`: the optimum of that problem, states at both
  cuts free; one programme per shape of stretch, the nest's in-row stretches are all alike),
- LinuxCNC's periods over it (its simulator, `linuxcnc_sim.py`, the same limits, no jerk limit),
- ours (`ProgramRunner`, the code the planner process runs).

Each is counted from the first sample past the cut in the lead-out to the first past the cut in the
lead-in. Stretches whose rapid reaches the axes' top speed (a row's end to the next row's start)
are left out: there the cut-up windows of `corner_bound.py` are tight and the programme would be
long. Needs LinuxCNC (Debian `linuxcnc-uspace`); from the repository root:

    .venv/bin/python bench/nest_stretches.py            # the table
    .venv/bin/python bench/nest_stretches.py --trace    # how one optimal trajectory passes the corners
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import corner_bound  # noqa: E402
import linuxcnc_compare as lc  # noqa: E402
import linuxcnc_sim  # noqa: E402

from cnc.config import MachineConfig, load_machine  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402

RAPID_KIND = 0  # a segment's kind: 0 rapid, 1 line, 2 and 3 arcs (gcode's segment table)
LINE_KIND = 1
LONGEST_RAPID_MM = 200.0  # longer rapids (a row's end to the next row's start) are left out


@dataclass(frozen=True)
class Stretch:
    """A lead-out, the rapid after it and the next part's lead-in, cut at the leads' middles."""

    lead_out_line: int
    lead_in_line: int
    points: tuple[tuple[float, float], ...]  # middle of the lead-out, its end, the rapid's end, middle of the lead-in
    feeds: tuple[float, float, float]  # mm/s; the rapid's math.inf

    def shape(self) -> tuple:
        """The stretch relative to its first point, rounded: stretches alike share one programme."""
        x0, y0 = self.points[0]
        return tuple((round(x - x0, 6), round(y - y0, 6)) for x, y in self.points), self.feeds


def stretches(program) -> list[Stretch]:  # noqa: ANN001 - the interpreted program
    """Every lead-out (a line), rapid, lead-in (a line) in a row, the rapid at most LONGEST_RAPID_MM."""
    seg = program.segments
    out = []
    for k in range(1, len(seg) - 1):
        before, rapid, after = seg[k - 1], seg[k], seg[k + 1]
        if rapid["kind"] != RAPID_KIND or before["kind"] != LINE_KIND or after["kind"] != LINE_KIND:
            continue
        a, b, c, d = (tuple(map(float, p[:2])) for p in (before["start"], before["end"], after["start"], after["end"]))
        if math.dist(b, c) > LONGEST_RAPID_MM or math.dist(b, c) == 0.0:
            continue
        middle = lambda p, q: ((p[0] + q[0]) / 2.0, (p[1] + q[1]) / 2.0)  # noqa: E731
        out.append(Stretch(int(before["line"]), int(after["line"]), (middle(a, b), b, c, middle(c, d)),
                           (float(before["feed"]) / 60.0, math.inf, float(after["feed"]) / 60.0)))
    return out


def periods_over(xy: np.ndarray, lines: np.ndarray, s: Stretch) -> int:
    """Periods from the first sample past the cut in the lead-out to the first past the cut in the
    lead-in, on a trajectory sampled every period with each sample's program line."""
    def first_past(line: int, a: tuple[float, float], b: tuple[float, float], after: int) -> int:
        u = np.subtract(b, a) / math.dist(a, b)
        idx = np.flatnonzero((lines == line) & (np.arange(len(lines)) >= after))
        past = idx[(xy[idx, :2] - a) @ u >= 0.0]
        if not len(past):
            raise ValueError(f"no sample past the cut on line {line}")
        return int(past[0])

    start = first_past(s.lead_out_line, s.points[0], s.points[1], 0)
    (x2, y2), (x3, y3) = s.points[2], s.points[3]
    end = first_past(s.lead_in_line, s.points[3], (2 * x3 - x2, 2 * y3 - y2), start)  # along the lead-in
    return end - start


def ours(program, start: tuple[float, float], config: MachineConfig) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN001
    """Our run of the program (`ProgramRunner`, the code the planner process runs) from its start:
    every sample's XY and program line, the start first."""
    records = lc.every_record(ProgramRunner(program, config))
    xy = np.concatenate(([start], records["position"][:, :2]))
    return xy, program.segments["line"][np.concatenate((records["segment"][:1], records["segment"]))]


def stretch_limits(program, config: MachineConfig) -> corner_bound.Limits:  # noqa: ANN001
    """The bound's limits for the program's stretches: the machine's axes, the leads' feed (the
    fastest of them; each leg keeps its own in `corner_bound.stretch_ticks`) and the program's P."""
    feed = max(f for s in stretches(program) for f in s.feeds if math.isfinite(f))
    return lc.corner_limits(config, 60.0 * feed, float(program.segments["tolerance"].max()))


def bound_ticks(args: tuple[Stretch, corner_bound.Limits]) -> int:
    s, limits = args
    return corner_bound.stretch_ticks(list(s.points), list(s.feeds), limits)


def measure(config: MachineConfig, workers: int) -> dict:
    bench = lc.nest_bench()
    program, start = lc.interpret_from_start(bench.text, config)
    dt = config.timing.period_s
    found = stretches(program)
    shapes: dict[tuple, Stretch] = {}
    for s in found:
        shapes.setdefault(s.shape(), s)
    wall = time.monotonic()
    limits = stretch_limits(program, config)
    with ProcessPoolExecutor(workers) as pool:
        bounds = dict(zip(shapes, pool.map(bound_ticks, [(s, limits) for s in shapes.values()])))
    bound_wall = time.monotonic() - wall
    ours_xy, ours_lines = ours(program, start, config)
    with tempfile.TemporaryDirectory(prefix="nest_stretches-") as tmp:
        path = Path(tmp) / "nest.ngc"
        path.write_text(bench.text)
        res = lc.run_linuxcnc_like_ours(path, start, config)
    rows = [{"lead_out_line": s.lead_out_line, "bound": bounds[s.shape()],
             "linuxcnc": periods_over(res["xy_mm"], res["line"], s), "ours": periods_over(ours_xy, ours_lines, s)}
            for s in found]
    return {"program": bench.name, "stretches": rows, "shapes": len(shapes), "bound_wall_s": bound_wall,
            "dt": dt, "rapids_left_out": int((program.segments["kind"] == RAPID_KIND).sum()) - len(found)}


def trace(config: MachineConfig) -> str:
    """One trajectory at the bound's least periods over the nest's first stretch, every 5th sample:
    how the optimum passes the two corners (one of possibly many at that N)."""
    program, _ = lc.interpret_from_start(lc.nest_bench().text, config)
    s = stretches(program)[0]
    limits = stretch_limits(program, config)
    n = corner_bound.stretch_ticks(list(s.points), list(s.feeds), limits)
    _, xy = corner_bound.stretch_solution(list(s.points), list(s.feeds), limits, n)
    if xy is None:
        return f"the programme at N = {n} was left undecided: no trajectory to show"
    dt = config.timing.period_s
    v = np.diff(xy, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    out = [f"the first stretch (corners at {s.points[1]} and {s.points[2]}), N = {n}: sample, x, y mm, vx, vy mm/s, "
           f"|v| mm/s, ax, ay mm/s^2"]
    for t in range(1, len(a), 5):
        out.append(f"{t:4d} {xy[t, 0]:9.3f} {xy[t, 1]:8.3f} {v[t - 1, 0]:8.1f} {v[t - 1, 1]:7.1f} "
                   f"{math.hypot(*v[t - 1]):7.1f} {a[t - 1, 0]:7.0f} {a[t - 1, 1]:7.0f}")
    return "\n".join(out)


def report(m: dict) -> str:
    rows, dt = m["stretches"], m["dt"]
    bound = np.array([r["bound"] for r in rows])
    theirs = np.array([r["linuxcnc"] for r in rows])
    mine = np.array([r["ours"] for r in rows])
    out = [f"{m['program']}: {len(rows)} stretches lead-out, rapid, lead-in (cut at the leads' middles), "
           f"{m['shapes']} shape(s) bounded in {m['bound_wall_s']:.0f} s; {m['rapids_left_out']} rapids left out",
           f"{'':24} {'bound':>9} {'LinuxCNC':>9} {'ours':>9}  {'LinuxCNC/bound':>14} {'ours/bound':>10} {'ours/LinuxCNC':>13}"]
    for name, f in (("per stretch, median ms", np.median), ("per stretch, least ms", np.min), ("per stretch, most ms", np.max)):
        b, t, o = (float(f(x)) * dt * 1e3 for x in (bound, theirs, mine))
        out.append(f"{name:24} {b:9.1f} {t:9.1f} {o:9.1f}")
    b, t, o = (float(x.sum()) * dt for x in (bound, theirs, mine))
    out.append(f"{'all, s':24} {b:9.3f} {t:9.3f} {o:9.3f}  {t / b:14.3f} {o / b:10.3f} {o / t:13.3f}")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--trace", action="store_true",
                    help="print one optimal trajectory over the first stretch instead (no LinuxCNC needed)")
    args = ap.parse_args()
    if args.trace:
        print(trace(load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)))
        return 0
    usable, why = linuxcnc_sim.available()
    if not usable:
        print(f"nest_stretches: LinuxCNC's simulator cannot run here: {why}", file=sys.stderr)
        return 2
    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    m = measure(config, len(os.sched_getaffinity(0)))
    print(report(m))
    if args.json:
        import json
        args.json.write_text(json.dumps(m, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
