#!/usr/bin/env python3
"""How fast a jerk-limited trajectory can run the Fig. 10 contour: one found, not a bound.

`bench/linuxcnc_compare.py` runs the paper's test contour (`cnc/control/fig10_contour.ngc`: tangent
lines and quarter arcs of 10 to 30 mm at F30000, G64 P0.005) 2.2 times as long as LinuxCNC 2.9,
which has no jerk limit. Its closed-form lower bound (0.881 s) is far under LinuxCNC's 1.335 s, so
it cannot say whether a planner that holds our jerk limit could match LinuxCNC there (issue 19,
point 4, asks for the jerk-limited bound where it cannot). This finds a trajectory that does what
the comparison measures, for the problem

    samples every servo period dt, from rest at the contour's start to rest at its end, each axis's
    backward differences within |v| <= V, |a| <= A, |j| <= J, the path speed within the feed F,
    every sample within P of the contour,

in as few periods N as it can: so the fastest jerk-limited run lies between the closed-form bound
and N dt. Linear programming over the samples' positions (scipy's HiGHS), with every constraint
kept inside the true one (so what it finds is a trajectory, checked again with the comparison's own
measures at the end): the feed's circle by the polygon inside it, and each sample's place near the
contour by a convex piece of its P-band around where the sample was guessed to be (a strip along a
line, a lens of the annulus across an arc). The guesses come from the previous solution: at each N
the programme first minimises how far the samples stray out of their pieces, then moves each guess
to where its sample came out, until none strays (then N is reached) or a few rounds change nothing
(then it is not, with these guesses). N is bisected, each try starting from the last trajectory
found, stretched or squeezed in time. Starting from our planner's own run (which keeps every
limit), the first N is always reached.

Not a lower bound: the guessing may miss faster trajectories, so the optimum can be lower than
what this finds, never higher. From the repository root (a few minutes on two CPUs):

    .venv/bin/python bench/fig10_reach.py [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.optimize import linprog

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))
sys.path.insert(0, str(BENCH.parent))

import linuxcnc_sim  # noqa: E402
from linuxcnc_compare import FIG10_FILE, every_record, interpret_from_start, jerk_bound_s, run_linuxcnc_like_ours  # noqa: E402

from cnc.config import load_machine  # noqa: E402
from cnc.planner.measure import ProgrammedPath, peaks  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402

LINUXCNC_S = 1.335  # LinuxCNC 2.9 on this contour with this machine's limits where it cannot run here (docs/benchmarks.md)
P_SHARE = 0.98  # the pieces keep this share of P (room for the solver's tolerances; checked exactly after)
LIMIT_SHARE = 1.0 - 1e-6  # and this share of each limit
FEED_SIDES = 16  # the feed's circle: the polygon inside it
LENS_SIDES = 7  # sides of the outer polygon of an arc's lens
ROUNDS = 12  # guess-moving rounds per N before it is taken as not reached
FIRST_STEP = 256  # periods taken off our planner's run at first; halved at each N not reached


@dataclass
class Piece:
    """One element of the contour: a line from a to b, or an arc (centre, radius, start angle, signed sweep)."""

    a: np.ndarray
    b: np.ndarray
    s0: float
    length: float
    center: np.ndarray | None = None
    radius: float = 0.0
    angle0: float = 0.0
    sweep: float = 0.0

    def at(self, s: float) -> np.ndarray:
        t = min(max((s - self.s0) / self.length, 0.0), 1.0)
        if self.center is None:
            return self.a + t * (self.b - self.a)
        ang = self.angle0 + t * self.sweep
        return self.center + self.radius * np.array([math.cos(ang), math.sin(ang)])

    def project(self, p: np.ndarray) -> tuple[float, float]:
        """(arc length of the nearest point, distance to it)."""
        if self.center is None:
            d = self.b - self.a
            t = min(max(float(np.dot(p - self.a, d)) / self.length**2, 0.0), 1.0)
            return self.s0 + t * self.length, float(np.hypot(*(self.a + t * d - p)))
        rel = p - self.center
        ang = math.atan2(rel[1], rel[0]) - self.angle0
        # the swept fraction of the point's angle, wrapped toward the sweep
        frac = (ang % (2 * math.pi)) / self.sweep if self.sweep > 0 else (-ang % (2 * math.pi)) / -self.sweep
        if frac > 1.0:  # beyond the end: the nearer end
            frac = 1.0 if frac - 1.0 < (2 * math.pi / abs(self.sweep) - frac) else 0.0
        s = self.s0 + frac * self.length
        return s, float(np.hypot(*(self.at(s) - p)))


def contour(segments: np.ndarray) -> list[Piece]:
    pieces, s = [], 0.0
    for seg in segments:
        a, b = np.asarray(seg["start"][:2], float), np.asarray(seg["end"][:2], float)
        if seg["kind"] == 1:
            length = float(np.hypot(*(b - a)))
            if length > 0:
                pieces.append(Piece(a, b, s, length))
                s += length
        elif seg["kind"] == 2:
            c = np.asarray(seg["center"], float)
            r = float(np.hypot(*(a - c)))
            a0, a1 = math.atan2(a[1] - c[1], a[0] - c[0]), math.atan2(b[1] - c[1], b[0] - c[0])
            sweep = (a0 - a1) % (2 * math.pi) if seg["cw"] else (a1 - a0) % (2 * math.pi)
            sweep = -sweep if seg["cw"] else sweep
            length = r * abs(sweep)
            pieces.append(Piece(a, b, s, length, c, r, a0, sweep))
            s += length
    return pieces


class Contour:
    def __init__(self, pieces: list[Piece]) -> None:
        self.pieces = pieces
        self.ends = np.array([p.s0 + p.length for p in pieces])

    def index(self, s: float) -> int:
        return int(min(np.searchsorted(self.ends, s), len(self.pieces) - 1))

    def project_run(self, xy: np.ndarray, monotone: bool = True) -> np.ndarray:
        """Arc lengths of samples taken in order along the contour (each near the one before);
        `monotone`: never less than the one before (guesses), else as projected (the checks)."""
        out, k = np.empty(len(xy)), 0
        for i, p in enumerate(xy):
            best = None
            for j in range(max(k - 1, 0), min(k + 3, len(self.pieces))):
                s, d = self.pieces[j].project(p)
                if best is None or d < best[1] - 1e-12:
                    best, kk = (s, d), j
            out[i], k = best[0], kk
        return np.maximum.accumulate(out) if monotone else out


@dataclass
class Problem:
    contour: Contour
    start: np.ndarray
    end: np.ndarray
    dt: float
    v: float  # per axis, mm/s
    a: float
    j: float
    feed: float  # path speed, mm/s
    p: float  # G64 P, mm
    path: ProgrammedPath | None = None  # the program's geometry, for exact distances


def _limit_rows(n: int, order: int, cap: float, start: np.ndarray, end: np.ndarray) -> tuple[sparse.coo_matrix, np.ndarray, np.ndarray]:
    """Rows |difference of `order` of each axis| <= cap, over samples 1..n+2 (0 and before: `start`,
    n and after: `end`, both fixed), as (matrix over [x_1..x_{n-1}, y_1..y_{n-1}, slacks], lo, hi)."""
    coef = {1: (1.0, -1.0), 2: (1.0, -2.0, 1.0), 3: (1.0, -3.0, 3.0, -1.0)}[order]
    m = n - 1  # free samples per axis
    rows, cols, vals, lo, hi = [], [], [], [], []
    r = 0
    for axis in range(2):
        fixed_start, fixed_end = start[axis], end[axis]
        for k in range(1, n + 3):
            const = 0.0
            for back, c in enumerate(coef):
                i = k - back
                if 1 <= i <= n - 1:
                    rows.append(r), cols.append(axis * m + i - 1), vals.append(c)
                else:
                    const += c * (fixed_start if i <= 0 else fixed_end)
            lo.append(-cap - const), hi.append(cap - const)
            r += 1
    return sparse.coo_matrix((vals, (rows, cols)), shape=(r, 3 * m)), np.array(lo), np.array(hi)


def _feed_rows(n: int, step: float, start: np.ndarray, end: np.ndarray) -> tuple[sparse.coo_matrix, np.ndarray, np.ndarray]:
    """|d . (p_k - p_{k-1})| <= step cos(pi / sides) for FEED_SIDES / 2 directions d (`step`: the feed
    times dt): the polygon inside the feed's circle."""
    m = n - 1
    cap = step * math.cos(math.pi / FEED_SIDES) * LIMIT_SHARE
    rows, cols, vals, lo, hi = [], [], [], [], []
    r = 0
    for side in range(FEED_SIDES // 2):
        d = (math.cos(2 * math.pi * side / FEED_SIDES), math.sin(2 * math.pi * side / FEED_SIDES))
        for k in range(1, n + 1):
            const = 0.0
            for i, c in ((k, 1.0), (k - 1, -1.0)):
                for axis in range(2):
                    if 1 <= i <= n - 1:
                        rows.append(r), cols.append(axis * m + i - 1), vals.append(c * d[axis])
                    else:
                        const += c * d[axis] * (start[axis] if i <= 0 else end[axis])
            lo.append(-cap - const), hi.append(cap - const)
            r += 1
    return sparse.coo_matrix((vals, (rows, cols)), shape=(r, 3 * m)), np.array(lo), np.array(hi)


def _band_rows(n: int, guess: np.ndarray, prob: Problem) -> tuple[sparse.coo_matrix, np.ndarray, np.ndarray]:
    """Each free sample k within the convex piece of the P-band around the contour's point at
    guess[k - 1], unless its slack sigma_k says by how much it is not: rows of the form
    w . p_k + sigma_k >= c (the lower bound) or w . p_k - sigma_k <= c (upper)."""
    m = n - 1
    tol = prob.p * P_SHARE
    rows, cols, vals, lo, hi = [], [], [], [], []
    r = 0

    def row(k: int, w: tuple[float, float], bound: float, upper: bool) -> None:
        nonlocal r
        rows.extend((r, r, r)), cols.extend((k - 1, m + k - 1, 2 * m + k - 1))
        vals.extend((w[0], w[1], -1.0 if upper else 1.0))
        lo.append(-np.inf if upper else bound), hi.append(bound if upper else np.inf)
        r += 1

    for k in range(1, n):
        s = float(guess[k - 1])
        piece = prob.contour.pieces[prob.contour.index(s)]
        if piece.center is None:
            u = (piece.b - piece.a) / piece.length
            nrm = (-u[1], u[0])
            c = float(np.dot(nrm, piece.a))
            row(k, nrm, c + tol, True), row(k, nrm, c - tol, False)
            row(k, tuple(u), float(np.dot(u, piece.b)), True), row(k, tuple(u), float(np.dot(u, piece.a)), False)
            continue
        cx, cy = piece.center
        t = min(max((s - piece.s0) / piece.length, 0.0), 1.0)
        phi = piece.angle0 + t * piece.sweep
        inner = piece.radius - tol
        row(k, (math.cos(phi), math.sin(phi)), inner + math.cos(phi) * cx + math.sin(phi) * cy, False)
        alpha = math.acos(inner / (piece.radius + tol))  # the lens's half-angle
        step = 2.0 * alpha / (LENS_SIDES - 3)
        outer = (piece.radius + tol) * math.cos(step / 2.0)  # the polygon inside the outer circle
        for side in range(LENS_SIDES):
            ang = phi - alpha - step + side * step
            row(k, (math.cos(ang), math.sin(ang)), outer + math.cos(ang) * cx + math.sin(ang) * cy, True)
        # within the arc's sector: on the inner side of the radii at its two ends
        sign = 1.0 if piece.sweep > 0 else -1.0
        for ang, at_end in ((piece.angle0, False), (piece.angle0 + piece.sweep, True)):
            # the direction of motion there: the sample is ahead of the start's radius, behind the end's
            tx, ty = -math.sin(ang) * sign, math.cos(ang) * sign
            row(k, (tx, ty), tx * cx + ty * cy, at_end)
    return sparse.coo_matrix((vals, (rows, cols)), shape=(r, 3 * m)), np.array(lo), np.array(hi)


def solve(n: int, guess: np.ndarray, prob: Problem) -> tuple[float, np.ndarray] | None:
    """The least total stray over the samples' pieces at N = n, and the samples (n + 1, 2)."""
    scale = prob.j * prob.dt**3  # positions in units of J dt^3: the jerk rows read |third difference| <= 1
    start, end = prob.start / scale, prob.end / scale
    blocks = [
        _limit_rows(n, 1, prob.v * prob.dt / scale * LIMIT_SHARE, start, end),
        _limit_rows(n, 2, prob.a * prob.dt**2 / scale * LIMIT_SHARE, start, end),
        _limit_rows(n, 3, LIMIT_SHARE, start, end),
        _feed_rows(n, prob.feed * prob.dt / scale, start, end),
    ]
    band, blo, bhi = _band_rows(n, guess, prob)
    m = n - 1
    band = band.tocsr()
    band = sparse.hstack((band[:, : 2 * m], band[:, 2 * m :] / scale)).tocsr()  # rows over scale: slack in mm
    a = sparse.vstack([b[0] for b in blocks] + [band]).tocsr()
    lo = np.concatenate([b[1] for b in blocks] + [blo / scale])
    hi = np.concatenate([b[2] for b in blocks] + [bhi / scale])
    cost = np.concatenate((np.zeros(2 * m), np.ones(m)))
    bounds = [(None, None)] * (2 * m) + [(0.0, None)] * m
    finite_lo, finite_hi = np.isfinite(lo), np.isfinite(hi)
    a_ub = sparse.vstack((a[finite_hi], -a[finite_lo])).tocsr()
    b_ub = np.concatenate((hi[finite_hi], -lo[finite_lo]))
    res = linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
    if res.status != 0:
        return None
    x = res.x
    xy = np.empty((n + 1, 2))
    xy[0], xy[n] = prob.start, prob.end
    xy[1:n, 0], xy[1:n, 1] = x[:m] * scale, x[m : 2 * m] * scale
    return float(x[2 * m :].sum() * scale), xy


def deviation_mm(xy: np.ndarray, prob: Problem) -> float:
    """The largest distance of the samples from the contour (every piece)."""
    path = prob.path
    return float(path.distance(np.c_[xy, np.zeros(len(xy))], np.zeros(len(xy), dtype=np.int64), len(path.elements)).max())


def reach(n: int, guess: np.ndarray, prob: Problem, log) -> np.ndarray | None:  # noqa: ANN001 - print-like
    """A trajectory of N = n periods, moving the guesses a few rounds; None if none was found.
    The limits hold by construction (no slack on them); a solution whose samples all lie within P
    of the contour is taken even where some strayed out of their guessed pieces (by less than the
    share of P the pieces leave out)."""
    best = math.inf
    for round_ in range(ROUNDS):
        out = solve(n, guess, prob)
        if out is None:
            log(f"  N={n} round {round_}: no solution")
            return None
        stray, xy = out
        worst = deviation_mm(xy, prob)
        log(f"  N={n} round {round_}: stray {stray:.3g} mm, farthest {worst * 1000:.3f} um from the contour")
        if stray <= 1e-9 or worst <= prob.p:
            return xy
        if stray >= best * 0.999:
            return None
        best = stray
        guess = prob.contour.project_run(xy[1:n])
    return None


def stretched(xy: np.ndarray, n: int, prob: Problem) -> np.ndarray:
    """Guesses for N = n from a trajectory: its samples' arc lengths, stretched in time."""
    s = prob.contour.project_run(xy)
    t_old = np.linspace(0.0, 1.0, len(xy))
    return np.interp(np.linspace(0.0, 1.0, n + 1), t_old, s)[1:n]


def check(xy: np.ndarray, prob: Problem) -> dict:
    """The comparison's own measures of a trajectory: peaks per axis, path speed, distance to the contour."""
    records = np.concatenate((np.repeat(xy[:1], 3, axis=0), xy, np.repeat(xy[-1:], 3, axis=0)))
    pk = peaks(np.c_[records, np.zeros(len(records))], prob.dt)
    speed = np.hypot(*np.diff(records, axis=0).T) / prob.dt
    along = prob.contour.project_run(xy, monotone=False)
    inside = (along[1:] > prob.contour.ends[0]) & (along[1:] <= prob.contour.ends[-2])  # past the first piece, before the last
    return {"backward_mm": float(max(0.0, -np.diff(along).min())),
            "slowest_inside_mm_s": float(speed[3:-3][inside].min()),
            "v": pk["velocity"][:2].tolist(), "a": pk["acceleration"][:2].tolist(), "j": pk["jerk"][:2].tolist(),
            "speed": float(speed.max()), "deviation_mm": deviation_mm(records, prob)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", help="write the figures as JSON")
    args = ap.parse_args(argv)
    config = load_machine(BENCH.parent / "machines" / "waterjet.toml")
    program, start = interpret_from_start(FIG10_FILE.read_text(), config)
    ax = [config.axis[a] for a in ("x", "y")]
    prob = Problem(Contour(contour(program.segments)), np.array(start), np.asarray(program.segments[-1]["end"][:2], float),
                   config.timing.period_s, min(a.max_velocity_mm_s for a in ax), min(a.max_accel_mm_s2 for a in ax),
                   min(a.max_jerk_mm_s3 for a in ax), float(np.nanmax(program.segments["feed"])) / 60.0,
                   float(program.segments["tolerance"].min()), ProgrammedPath(program.segments))
    wall = time.monotonic()
    runner = ProgramRunner(program, config)
    ours = every_record(runner)["position"][:, :2]
    ours = np.concatenate(([prob.start], ours))
    moving = np.flatnonzero(np.any(np.abs(np.diff(ours, axis=0)) > 0, axis=1))
    ours = ours[: moving[-1] + 2]
    n_ours = len(ours) - 1
    log = lambda text: print(text, flush=True)  # noqa: E731
    log(f"our planner: {n_ours} periods; finding shorter trajectories")
    if reach(n_ours, stretched(ours, n_ours, prob), prob, log) is None:  # the programme's own check
        raise SystemExit("our planner's run does not fit the programme: its pieces are wrong")
    # descend from our run: a shorter N from the last trajectory found, the step halved where it fails
    n, best_xy, step, tried = n_ours, ours, FIRST_STEP, []
    while step >= 1:
        xy = reach(n - step, stretched(best_xy, n - step, prob), prob, log)
        tried.append((n - step, xy is not None))
        if xy is None:
            step //= 2
        else:
            n, best_xy = n - step, xy
    log(f"tried (N, reached): {tried}")
    measures = check(best_xy, prob)
    try:  # the peer, in the same run
        linuxcnc_s, peer = float(run_linuxcnc_like_ours(FIG10_FILE, start, config)["cycle_time_s"]), "run here"
    except (linuxcnc_sim.LinuxCNCUnavailable, linuxcnc_sim.LinuxCNCRunError) as exc:
        linuxcnc_s, peer = LINUXCNC_S, f"not run here ({exc}): its time of earlier runs"
    result = {"periods": n, "seconds": n * prob.dt, "ours_s": n_ours * prob.dt, "linuxcnc_s": linuxcnc_s, "linuxcnc": peer,
              "closed_form_bound_s": jerk_bound_s(program, config), "not_reached_s": (n - 1) * prob.dt, "checks": measures,
              "limits": {"v": prob.v, "a": prob.a, "j": prob.j, "feed": prob.feed, "p": prob.p},
              "wall_s": time.monotonic() - wall}
    print()
    print("Fig. 10 contour F30000 P0.005: a jerk-limited trajectory found (machines/waterjet.toml)")
    print(f"{'':34s}{'seconds':>9s}{'/ LinuxCNC':>12s}")
    for name, sec in (("closed-form lower bound", result["closed_form_bound_s"]), ("found here (an upper bound)", result["seconds"]),
                      ("our planner", result["ours_s"]), ("LinuxCNC 2.9 (no jerk limit)", linuxcnc_s)):
        print(f"{name:34s}{sec:9.3f}{sec / linuxcnc_s:11.2f}x")
    print(f"LinuxCNC: {peer}")
    print(f"checks of the found one: |v| {max(measures['v']):.1f} <= {prob.v:g}, |a| {max(measures['a']):.1f} <= {prob.a:g}, "
          f"|j| {max(measures['j']):.0f} <= {prob.j:g}, speed {measures['speed']:.1f} <= {prob.feed:g}, "
          f"deviation {measures['deviation_mm'] * 1000:.2f} um <= {prob.p * 1000:g} um")
    print(f"not reached with these guesses at {result['not_reached_s']:.3f} s; {result['wall_s']:.0f} s of wall time")
    print(f"progress along the contour: never back by more than {measures['backward_mm'] * 1000:.3f} um; "
          f"slowest past the first line and before the last {measures['slowest_inside_mm_s']:.1f} mm/s")
    if args.json:
        result["tried"] = tried
        result["xy_mm"] = best_xy.tolist()
        Path(args.json).write_text(json.dumps(result, indent=2))
    ok = (max(measures["v"]) <= prob.v * (1 + 1e-6) and max(measures["a"]) <= prob.a * (1 + 1e-6)
          and max(measures["j"]) <= prob.j * (1 + 1e-6) and measures["deviation_mm"] <= prob.p)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
