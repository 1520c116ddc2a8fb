#!/usr/bin/env python3
"""What corners solved as linear programmes would give: the comparison's zigzags at or under LinuxCNC.

A study for issue 19, point 4, not the planner's code. The planner passes a stop corner by an
overlap (`cnc/planner/overlap.py`) or by a connection of Ruckig's (`connection.py`): the time-
optimal motion of each axis between a state of the last section's braking and one of the next
one's speeding up. Where two straight moves meet at a gentle corner at speed (the zigzag's 30 and
60 degree turns at 200 and 500 mm/s) neither serves: the axes' own optima leave P, and the
fastest path within P drifts to the outside of the corner first and passes it through the whole
band (docs/benchmarks.md, "Where the corners lose"). So the zigzags at P 0.05 stay 1.07x and 1.10x
of LinuxCNC 2.9 while their jerk-limited bound is under it.

Here a connection's samples are solved for at once. Between the last section's sample n_a - p
and the next one's sample j (the furthest a connection reaches on either side,
`CornerOverlap.connection_reach`), the fewest servo periods m and the m - 1 samples such that

- every axis keeps its velocity, acceleration and jerk limit on the backward differences of the
  joined samples, the sections' own `CONTEXT` samples on either side included;
- every sample lies within P of one of the two programmed lines at the corner: the first ones of
  the incoming line, the rest of the outgoing one (in the rectangle of width 2 P along each,
  which lies within its P-neighbourhood);
- the path speed into every sample, and into the join, keeps the overlap's cap
  (`overlap._speed_cap`), in a polygon inscribed in its circle with corners along both lines'
  steps at the joins and between (`programme.speed_sides`) (the sections' own speed at the joins is
  within it);

each limit kept `LP_MARGIN` inside the connection's own check, which checks the result again
(`connection._Search.keeps_rules`). For a given m and a given k (how many of the samples lie near
the incoming line) that is a linear programme, solved by HiGHS (`scipy.optimize.milp` without
integers); m by bisection (a connection that takes m periods taken to fit in m + 1), k by branch
and bound over ranges of k whose samples need only lie in the hull of both rectangles, the k of
the last feasible programme tried first, at most `PROGRAMMES` programmes a corner (a count, so
the runner and the program's timing choose alike). Only the widest window is searched: a
connection over a narrower one is also one over the widest (following the sections' own samples
to it), so the widest saves no less, short of the margins. It may last `--path-ms` (120 ms: the
zigzag's connections take 95 to 115 periods), committed as any connection: a hold, a stop or an
override change made during it would act when it ends.

The planner's own corners, with such a connection tried wherever the planner searches one (two
straight lines meeting where the axis limits held the overlap short), run by the planner's runner
(`ProgramRunner`, its corners replaced) and timed by its timing (`ProgramTiming`), against
LinuxCNC 2.9 on the same programs in the same run (`linuxcnc_compare.run_theirs`). Why it is a
bench and not the planner: a corner takes 1 to 3 s of solving (tens of programmes of 30 to 50 ms
each), where the planner's worker has the time of one leg, 100 to 250 ms at these feeds, to decide
it; decided late, the refill would wait for it and the setpoint FIFO run dry. The planner now
makes such connections itself, on a spline's control points in tens of milliseconds
(`cnc/planner/programme.py`): its own corners, which this bench's "ours" column runs, include
them, and the per-sample programme here is the reference that spline is measured against. From the
repository root (about 4 minutes):

    .venv/bin/python bench/corner_programmed.py [--only zigzag] [--json OUT]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.optimize import LinearConstraint, milp

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import linuxcnc_compare as lc  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.planner.connection import CornerPlan, _Corner, _Search, corner_window  # noqa: E402
from cnc.planner.overlap import CornerOverlap  # noqa: E402
from cnc.planner.programme import _Programme, fewest, speed_sides  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402
from cnc.planner.sections import iter_steps  # noqa: E402
from cnc.planner.steps import ProgramTiming  # noqa: E402
from gcode.canon import LINE, RAPID  # noqa: E402

LP_MARGIN = 1e-6  # each limit kept this share inside its check's (`connection._Search.keeps_rules`)
HULL_SIDES = 16  # sides of the polygon around both rectangles where k is not yet chosen
PROGRAMMES = 200  # linear programmes at most per corner (a count: the same choice in the run and the timing)
PATH_MS = 120.0  # the longest programmed connection (`--path-ms`)
SOLVES: list[dict] = []  # each programmed corner's search: programmes, wall seconds, periods saved
_PROGRAMMES = [0]  # linear programmes solved so far


def programmed_connection(corners: CornerOverlap, corner: _Corner, p: int, j: int, beat: int,
                          max_periods: int) -> CornerPlan | None:
    """The programmed connection from the last section's sample n_a - p to the next one's sample j
    (`corner.tail[-1 - p]`, `corner.head[j]`), if it saves more than `beat` periods within
    `max_periods`; None where the corner is not two straight lines or none does."""
    near = corner.near
    if len(near) != 2 or any(e.kind not in (LINE, RAPID) or e.length_mm <= 0.0 for e in near):
        return None
    problem = _Problem(corners, corner, len(corner.tail) - 1 - p, j)
    found = fewest(problem, problem.fewest_periods(), min(max_periods, p + j - beat - 1), PROGRAMMES)
    if found is None:
        return None
    m, path = found
    return CornerPlan(p + j - m, p, j - 1, path)  # a connection of m periods saves p + j - m


class _Problem(_Programme):
    """The linear programmes of one corner's window over every sample, for any number of periods m
    (the planner's `programme._Programme` solves for a spline's control points instead: its window,
    joins and lines are these)."""

    def __init__(self, corners: CornerOverlap, corner: _Corner, i: int, j: int) -> None:
        super().__init__(corners, corner, i, j)
        self.legs = []  # (u, n, along-from, along-to, across) of each programmed line, relative to the origin
        for e in corner.near:
            s, t = np.array(e.start[:2]) - self.origin, np.array(e.end[:2]) - self.origin
            u = (t - s) / np.linalg.norm(t - s)
            n = np.array([-u[1], u[0]])
            self.legs.append((u, n, float(u @ s), float(u @ t), float(n @ s)))
        self.hint: float | None = None  # where the last feasible one switched lines, as a share of its samples

    def solve(self, m: int) -> np.ndarray | None:
        """The connection's m - 1 samples (X, Y, Z) if the programme is feasible for some k: those
        near the last feasible one's (`hint`) first, then any (branch and bound)."""
        if self.count >= PROGRAMMES:
            return None
        n = m - 1
        base = self._base(n)
        if self.hint is not None:
            k = round(self.hint * n)
            for k in sorted({min(max(k + d, 0), n) for d in (0, 1, -1, 2, -2)}, key=lambda q: abs(q - k)):
                x = self._programme(base, n, k, k)
                if x is not None:
                    return self._found(x, n, k)
        stack = [(0, n)]  # k in a range: the samples from k1 to k2 - 1 in the hull of both lines
        while stack and self.count < PROGRAMMES:
            k1, k2 = stack.pop()
            x = self._programme(base, n, k1, k2)
            if x is None:
                continue
            if k1 == k2:
                return self._found(x, n, k1)
            mid = (k1 + k2) // 2
            stack += [(mid + 1, k2), (k1, mid)]  # the earlier half first
        return None

    def _found(self, x: np.ndarray, n: int, k: int) -> np.ndarray:
        self.hint = k / n if n else 0.0
        path = np.repeat(self.corner.tail[-1:], n, axis=0)  # Z as at the corner (the corner is flat)
        path[:, :2] = x.reshape(n, 2) + self.origin
        return path

    def _base(self, n: int) -> tuple[sparse.csr_matrix, np.ndarray, np.ndarray]:
        """Rows (over the 2 n unknowns) of the axes' limits and the speed's polygon: A, low, high."""
        nb, na = len(self.before), len(self.after)
        total = nb + n + na
        margin = 1.0 - LP_MARGIN
        rows, cols, vals, low, high = [], [], [], [], []
        row = 0
        for axis in range(2):
            fixed = np.concatenate((self.before[:, axis], np.zeros(n), self.after[:, axis]))
            for order, limit in ((1, self.corners.velocity[axis]), (2, self.corners.accel[axis]),
                                 (3, self.corners.jerk[axis])):
                if not math.isfinite(limit):
                    continue
                coefs = [math.comb(order, q) * (-1) ** q for q in range(order + 1)]  # on t, t - 1, ... t - order
                bound = limit * self.dt ** order * margin
                for t in range(max(order, nb), min(total, nb + n + order)):  # rows that reach an unknown
                    const = 0.0
                    for q, c in enumerate(coefs):
                        s = t - q
                        if nb <= s < nb + n:
                            rows.append(row); cols.append(2 * (s - nb) + axis); vals.append(float(c))
                        else:
                            const += c * fixed[s]
                    low.append(-bound - const); high.append(bound - const)
                    row += 1
        cap = self.corner.cap_mm_s
        if math.isfinite(cap):
            radius = cap * self.dt * margin
            sides = speed_sides(self.before[-1] - self.before[-2], self.after[1] - self.after[0])
            for t in range(nb, nb + n + 1):  # the step into each unknown, and into the join
                for q0, q1 in sides:
                    mid, reach = (q0 + q1) / 2.0, radius * math.cos((q1 - q0) / 2.0)
                    d = (math.cos(mid), math.sin(mid))
                    const = 0.0
                    for s, c in ((t, 1.0), (t - 1, -1.0)):
                        if nb <= s < nb + n:
                            rows += [row, row]; cols += [2 * (s - nb), 2 * (s - nb) + 1]; vals += [c * d[0], c * d[1]]
                        else:
                            pt = self.before[s] if s < nb else self.after[s - nb - n]
                            const += c * (d[0] * pt[0] + d[1] * pt[1])
                    low.append(-np.inf); high.append(reach - const)
                    row += 1
        a = sparse.csr_matrix((vals, (rows, cols)), shape=(row, 2 * n))
        return a, np.array(low), np.array(high)

    def _programme(self, base: tuple, n: int, k1: int, k2: int) -> np.ndarray | None:
        """Feasible positions (2 n, relative to the origin) with samples before k1 near the incoming
        line, from k2 on near the outgoing one, those between in the hull of both; None if none."""
        self.count += 1
        _PROGRAMMES[0] += 1
        tol = self.corner.tolerance_mm * (1.0 - LP_MARGIN)
        blocks, lows, highs = [base[0]], [base[1]], [base[2]]
        t = np.arange(n)

        def along(samples: np.ndarray, d: np.ndarray, lo: float, hi: float) -> None:
            m = len(samples)
            if not m:
                return
            blocks.append(sparse.csr_matrix((np.tile(d, m), (np.repeat(np.arange(m), 2),
                                             np.column_stack((2 * samples, 2 * samples + 1)).ravel())), shape=(m, 2 * n)))
            lows.append(np.full(m, lo)); highs.append(np.full(m, hi))

        for leg, samples in ((0, t[t < k1]), (1, t[t >= k2])):
            u, nrm, a0, a1, c0 = self.legs[leg]
            along(samples, nrm, c0 - tol, c0 + tol)
            along(samples, u, a0, a1)
        between = t[(t >= k1) & (t < k2)]
        if len(between):
            points = np.array([u * x + nrm * (c0 + y) for u, nrm, a0, a1, c0 in self.legs for x in (a0, a1)
                               for y in (-tol, tol)])
            for q in range(HULL_SIDES):
                d = np.array([math.cos(2.0 * math.pi * q / HULL_SIDES), math.sin(2.0 * math.pi * q / HULL_SIDES)])
                along(between, d, -np.inf, float((points @ d).max()))
        result = milp(np.zeros(2 * n), constraints=LinearConstraint(sparse.vstack(blocks).tocsr(), np.concatenate(lows),
                                                                    np.concatenate(highs)),
                      bounds=(-np.inf, np.inf))
        return result.x if result.status == 0 else None




@dataclasses.dataclass(frozen=True)
class ProgrammedCorners(CornerOverlap):
    """The planner's corners (`CornerOverlap`), with a programmed connection tried wherever the
    planner searches a connection, taken where it saves more."""

    path_samples: int = 0  # the longest programmed connection, in servo periods

    @classmethod
    def of_config(cls, config, path_ms: float) -> "ProgrammedCorners":  # noqa: ANN001 - a MachineConfig
        base = CornerOverlap.of(config)
        fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(CornerOverlap)}
        return cls(**fields, path_samples=int(round(path_ms / 1000.0 / base.dt)))

    def plan(self, a, b, a_summed: int = 0, book=None, index: int = -1) -> CornerPlan:  # noqa: ANN001 - SectionStreams, a ProgrammeBook
        # the planner's own choice first, untouched; the overlap's check and the window are made again
        # here (milliseconds, against seconds of solving) rather than reaching into `plan`
        plan = super().plan(a, b, a_summed, book, index)
        _, could_grow = self._overlap(a, b, a_summed)
        if self.connection_samples < 1 or not could_grow:
            return plan
        window = corner_window(self, a, b, a_summed)
        if window is None:
            return plan
        corner, most_p, most_j = window
        wall = time.perf_counter()
        before = _PROGRAMMES[0]
        programmed = programmed_connection(self, corner, most_p, most_j, plan.saved, self.path_samples + 1)
        kept = programmed is not None and _Search(self, corner).keeps_rules(most_p, most_j, programmed.path)
        SOLVES.append({"programmes": _PROGRAMMES[0] - before, "wall_s": time.perf_counter() - wall,
                       "saved": programmed.saved if kept else 0, "planner_saved": plan.saved})
        return programmed if kept else plan




def measure(bench: lc.Bench, config, path_ms: float, workdir: Path) -> dict:  # noqa: ANN001 - a MachineConfig
    """LinuxCNC's time, the planner's, and the planner's with programmed corners (timed and run)."""
    program, start = lc.interpret_from_start(bench.text, config)
    dt = config.timing.period_s
    ours = lc.every_record(ProgramRunner(program, config))["position"]  # the planner as it is, as the comparison runs it
    corners = ProgrammedCorners.of_config(config, path_ms)
    SOLVES.clear()
    wall = time.perf_counter()
    timing = ProgramTiming(dt, corners).compute(iter_steps(program, config))
    timing_wall = time.perf_counter() - wall
    solves = list(SOLVES)
    runner = ProgramRunner(program, config, timing=timing)
    runner.corners = corners
    records = lc.every_record(runner)
    xy = np.concatenate(([start], records["position"]))
    tags = np.concatenate((records["segment"][:1], records["segment"]))
    path = lc.ProgrammedPath(program.segments)
    deviation = path.distance(xy, tags, lc.TAG_WINDOW)
    peaks = lc.peak_figures(xy, dt)
    kinds, parts = lc.line_kinds(bench.text), lc.line_parts(bench.text)
    program_file = workdir / (bench.name.replace(" ", "_") + ".ngc")
    program_file.write_text(bench.text)
    theirs = lc.run_theirs(program_file, program, start, config, kinds, parts)
    tolerance = float(program.segments["tolerance"].max())
    return {"program": bench.name, "tolerance_mm": tolerance, "linuxcnc_s": theirs.cycle_time_s,
            "ours_s": lc.motion_time_s(np.concatenate(([start], ours)), dt), "programmed_s": lc.motion_time_s(xy, dt), "planned_ticks": timing.total_ticks, "run_ticks": len(records),
            "deviation_mm": float(deviation.max()), "peaks": peaks, "corners": len(solves),
            "programmes": [s["programmes"] for s in solves], "solve_s": [s["wall_s"] for s in solves],
            "saved": [s["saved"] for s in solves], "planner_saved": [s["planner_saved"] for s in solves],
            "timing_wall_s": timing_wall}


def render(rows: list[dict], config) -> str:  # noqa: ANN001 - a MachineConfig
    limits = [(config.axis[a].max_accel_mm_s2, config.axis[a].max_jerk_mm_s3) for a in ("x", "y")]
    out = ["corners solved as linear programmes (a study; machines/waterjet.toml's limits, LinuxCNC 2.9 in the same run)",
           f"{'program':<24}{'LCNC s':>8}{'ours s':>8}{'ratio':>7}{'solved s':>10}{'ratio':>7}{'p - run':>8}"
           f"{'dev/P':>7}{'|a|/A':>7}{'|j|/J':>7}{'corners':>8}  {'saved (planner)':<34}{'solve s max':>11}"]
    for r in rows:
        a_ratio = max(r["peaks"]["peak_accel_mm_s2"][k] / limits[k][0] for k in range(2))
        j_ratio = max(r["peaks"]["peak_jerk_mm_s3"][k] / limits[k][1] for k in range(2))
        saved = " ".join(f"{s}({p})" for s, p in zip(r["saved"], r["planner_saved"]))
        out.append(f"{r['program']:<24}{r['linuxcnc_s']:>8.3f}{r['ours_s']:>8.3f}{r['ours_s'] / r['linuxcnc_s']:>7.3f}"
                   f"{r['programmed_s']:>10.3f}{r['programmed_s'] / r['linuxcnc_s']:>7.3f}{r['planned_ticks'] - r['run_ticks']:>8}"
                   f"{r['deviation_mm'] / r['tolerance_mm']:>7.3f}{a_ratio:>7.3f}{j_ratio:>7.3f}{r['corners']:>8}  "
                   f"{saved:<34}{max(r['solve_s'], default=0.0):>11.2f}")
    out.append("ours: the planner as it is; solved: with programmed connections where it searches a connection (the "
               "comparison's motion time of the runner's records; p - run: the timing's periods less the run's); saved: periods each programmed corner saves over a "
               "stop (the planner's own overlap or connection in brackets); solve s: one corner's search, wall seconds")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="only the comparison's corner programs whose name has this")
    parser.add_argument("--path-ms", type=float, default=PATH_MS, help="longest programmed connection (ms)")
    parser.add_argument("--json", metavar="OUT", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        for bench in lc.corner_benches():
            if args.only in bench.name:
                rows.append(measure(bench, config, args.path_ms, Path(workdir)))
                print(f"{bench.name}: done", file=sys.stderr)
    print(render(rows, config))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
