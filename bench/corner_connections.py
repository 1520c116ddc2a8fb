"""How fast per-axis time-optimal connections pass the nest's corners between parts: a corner core to try.

`bench/nest_stretches.py` finds the comparison nest's gap to LinuxCNC at the two corners between
parts (a lead-out turned back into a rapid, the rapid into the next lead-in at a right angle):
our planner sums two straight motions there, the jerk-limited optimum plans each axis through the
band. This bench builds such a stretch from per-axis pieces that a planner could make as it goes,
and times it: the lead-out at its feed up to a point before its corner, a time-optimal
connection of both axes (Ruckig, time-synchronised, each axis within its velocity, acceleration
and jerk) to a state on the rapid (a point past the corner, a speed and an acceleration along
the rapid), the rapid's middle as one time-optimal move along its line between those states,
the same kind of connection into the lead-in, and the lead-in at its feed. A connection counts
only where every sample of it (every 0.2 ms) lies within P of the two legs and keeps the lead's
feed where it is nearer the lead than the rapid; the states are searched on a grid. What comes
out is a trajectory that holds every limit, so its time is one such a corner core reaches, not a
bound. Printed beside ours over the same stretch (the planner's run of the nest), and with
`--bound` the optimum (`corner_bound.stretch_ticks`, about 4 min). From the repository root:

    .venv/bin/python bench/corner_connections.py [--bound]
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import corner_bound  # noqa: E402
import linuxcnc_compare as lc  # noqa: E402
import nest_stretches  # noqa: E402

from cnc.config import load_machine  # noqa: E402

CHECK_DT = 2e-4  # s between the samples a connection is checked at
# the grid of states searched: distance before the corner where the lead's cruise ends (mm, up to
# the lead's middle), distance past it on the rapid (mm), speed (mm/s) and share of the rapid's
# acceleration there
LEAD_STEP_MM = 0.02
ON_RAPID_MM = np.arange(0.1, 1.55, 0.1)
ON_RAPID_SPEEDS = np.arange(30.0, 160.0, 10.0)
ACCEL_SHARES = (0.75, 0.875, 1.0)
KEPT = 40  # the fastest connections of each corner tried against each other through the rapid


class Axes:
    """The X and Y axes' limits, and the rapid's along its line (the tightest axis over its direction)."""

    def __init__(self, config, rapid_u: np.ndarray) -> None:  # noqa: ANN001 - MachineConfig
        x, y = config.axis["x"], config.axis["y"]
        self.v = [x.max_velocity_mm_s, y.max_velocity_mm_s]
        self.a = [x.max_accel_mm_s2, y.max_accel_mm_s2]
        self.j = [x.max_jerk_mm_s3, y.max_jerk_mm_s3]
        along = lambda lim: min(lim[i] / abs(rapid_u[i]) for i in (0, 1) if abs(rapid_u[i]) > 1e-12)  # noqa: E731
        self.path = (along(self.v), along(self.a), along(self.j))


def connect(axes_limits: tuple[list, list, list], p0, v0, a0, p1, v1, a1) -> Trajectory | None:  # noqa: ANN001
    """The time-optimal, time-synchronised motion of len(p0) axes from one state to another."""
    n = len(p0)
    inp = InputParameter(n)
    inp.current_position, inp.current_velocity, inp.current_acceleration = list(p0), list(v0), list(a0)
    inp.target_position, inp.target_velocity, inp.target_acceleration = list(p1), list(v1), list(a1)
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = axes_limits
    inp.synchronization = Synchronization.Time
    trajectory = Trajectory(n)
    return trajectory if Ruckig(n).calculate(inp, trajectory) in (Result.Working, Result.Finished) else None


def _to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def keeps_the_band(trajectory: Trajectory, lead: tuple, rapid: tuple, feed: float, tolerance: float) -> bool:
    """Every sample within P of the lead or the rapid, and at most the lead's feed where nearer the lead."""
    ts = np.arange(0.0, trajectory.duration + CHECK_DT / 2, CHECK_DT)
    states = [trajectory.at_time(t) for t in ts]
    pos = np.array([s[0] for s in states])
    vel = np.array([s[1] for s in states])
    to_lead, to_rapid = _to_segment(pos, *lead), _to_segment(pos, *rapid)
    if np.minimum(to_lead, to_rapid).max() > tolerance * (1.0 + 1e-6):
        return False
    return bool((np.linalg.norm(vel[to_lead < to_rapid], axis=1) <= feed * (1.0 + 1e-3)).all())


def corner_options(axes: Axes, lead: tuple, corner: np.ndarray, rapid_u: np.ndarray, feed: float,
                   tolerance: float, into_rapid: bool) -> list[tuple[float, float, float, float]]:
    """(seconds, distance on the rapid, speed, acceleration) of every connection that keeps the
    band, between the lead's cruise (from its middle) and a state on the rapid; `into_rapid`: the
    lead comes first (a lead-out), else the rapid does (into a lead-in)."""
    lead_u = (lead[1] - lead[0]) / np.linalg.norm(lead[1] - lead[0])
    half = np.linalg.norm(lead[1] - lead[0]) / 2.0
    limits = (axes.v, axes.a, axes.j)
    out = []
    for s, d, v, share in itertools.product(np.arange(LEAD_STEP_MM, half + 1e-9, LEAD_STEP_MM), ON_RAPID_MM,
                                            ON_RAPID_SPEEDS, ACCEL_SHARES):
        a = share * axes.path[1]
        if into_rapid:
            t = connect(limits, corner - s * lead_u, feed * lead_u, (0, 0), corner + d * rapid_u, v * rapid_u, a * rapid_u)
        else:
            t = connect(limits, corner - d * rapid_u, v * rapid_u, -a * rapid_u, corner + s * lead_u, feed * lead_u, (0, 0))
        rapid = (corner, corner + 10.0 * rapid_u) if into_rapid else (corner - 10.0 * rapid_u, corner)
        if t is not None and keeps_the_band(t, lead, rapid, feed, tolerance):
            out.append(((half - s) / feed + t.duration, d, v, a))
    return sorted(out)[:KEPT]


def fastest(config, stretch: nest_stretches.Stretch, tolerance: float) -> tuple[float, tuple, tuple]:  # noqa: ANN001
    """The stretch's time through the fastest pair of connections found, and those two."""
    mid_out, b, c, mid_in = (np.array(p, dtype=float) for p in stretch.points)
    rapid_u = (c - b) / np.linalg.norm(c - b)
    axes = Axes(config, rapid_u)
    feed_out, _, feed_in = stretch.feeds
    first = corner_options(axes, (2 * mid_out - b, b), b, rapid_u, feed_out, tolerance, into_rapid=True)
    last = corner_options(axes, (c, 2 * mid_in - c), c, rapid_u, feed_in, tolerance, into_rapid=False)
    path_limits = ([axes.path[0]], [axes.path[1]], [axes.path[2]])
    best = (math.inf, None, None)
    for f, g in itertools.product(first, last):
        rest = np.linalg.norm(c - b) - f[1] - g[1]
        middle = connect(path_limits, [0.0], [f[2]], [f[3]], [rest], [g[2]], [-g[3]]) if rest > 0.0 else None
        if middle is not None and f[0] + middle.duration + g[0] < best[0]:
            best = (f[0] + middle.duration + g[0], f, g)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bound", action="store_true", help="also the jerk-limited optimum of the stretch (about 4 min)")
    args = ap.parse_args()
    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    program, start = lc.interpret_from_start(lc.nest_bench().text, config)
    stretch = nest_stretches.stretches(program)[0]
    tolerance = float(program.segments["tolerance"].max())
    wall = time.monotonic()
    seconds, first, last = fastest(config, stretch, tolerance)
    wall = time.monotonic() - wall
    ours_ms = nest_stretches.periods_over(*nest_stretches.ours(program, start, config), stretch) * config.timing.period_s * 1e3
    print(f"the nest's first stretch (corners at {stretch.points[1]} and {stretch.points[2]}), searched in {wall:.0f} s")
    if first is None:
        print("no pair of connections keeps the band")
        return 1
    print(f"  into the rapid {first[1]:.2f} mm past the turn back at {first[2]:.0f} mm/s, {first[3]:.0f} mm/s^2; "
          f"out of it {last[1]:.2f} mm before the right angle at {last[2]:.0f} mm/s, braking {last[3]:.0f} mm/s^2")
    print(f"{'':28} {'ms':>7} {'/ ours':>7}")
    print(f"{'per-axis connections':28} {seconds * 1e3:7.1f} {seconds * 1e3 / ours_ms:7.3f}")
    print(f"{'ours (two motions summed)':28} {ours_ms:7.1f} {1.0:7.3f}")
    if args.bound:
        limits = nest_stretches.stretch_limits(program, config)
        bound_ms = corner_bound.stretch_ticks(list(stretch.points), list(stretch.feeds), limits) * config.timing.period_s * 1e3
        print(f"{'the optimum (a bound)':28} {bound_ms:7.1f} {bound_ms / ours_ms:7.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
