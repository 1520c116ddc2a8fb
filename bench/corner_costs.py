"""What one corner costs our planner, beside what it costs the best jerk-limited trajectory.

Issue 19, point 4 asks for cycle times at or under LinuxCNC's on the corner programs of
`bench/linuxcnc_compare.py`; `bench/corner_bound.py` shows that at G64 P0.05 the remaining gap is
within a jerk-limited planner's reach. This bench says where: for each interior angle of the
zigzag (30 to 150 degrees) and each feed and tolerance of the comparison, a corner between two
legs of the zigzag's length, as

    cost = time(two legs meeting at the angle) - time(one straight move of both legs' length)

for our planner (`ProgramRunner`, the servo periods from the first moving sample to the last)
and for the optimum (`corner_bound.polyline_bound_ticks` of both polylines: the least periods of
any sampled trajectory within the axes' v, a, j, the feed and P). The same definition on both
sides, so the ramps at rest cancel and only the corner remains. The last column says what our
planner does there: stops (the corner is a section boundary with no overlap), or the least
path speed it passes at (a blend, or two sections overlapped: `overlap.py`).

From the repository root (about four minutes on two CPUs, the linear programmes in parallel;
`--feeds`, `--tolerances` and `--angles` choose other corners, e.g. the nest's feed):

    .venv/bin/python bench/corner_costs.py
    .venv/bin/python bench/corner_costs.py --feeds 2400 --tolerances 0.05 --angles 45 90 135
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))
sys.path.insert(0, str(BENCH))

import corner_bound  # noqa: E402 - bench/ is put on the path above
import linuxcnc_compare as lc  # noqa: E402
from cnc.config import MachineConfig, load_machine  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402

STILL_MM_S = 1e-3  # a path speed under this at the corner counts as a stop
ORIGIN = (300.0, 300.0)


def legs(interior_deg: float | None) -> list[tuple[float, float]]:
    """Two zigzag legs meeting at `interior_deg`, or (None) one straight move as long as both."""
    x, y = ORIGIN
    length = lc.ZIGZAG_LEG_MM
    if interior_deg is None:
        return [(x, y), (x + 2 * length, y)]
    heading = math.radians(180.0 - interior_deg)
    return [(x, y), (x + length, y), (x + length + length * math.cos(heading), y + length * math.sin(heading))]


def ours(points: list[tuple[float, float]], feed: int, tolerance: float, config: MachineConfig) -> tuple[int, float]:
    """Our planner's servo periods from the first moving sample to the last, and the least path
    speed within a leg's length of the corner (mm/s)."""
    program, start = lc.interpret_from_start(lc._program("corner", tolerance, feed, points), config)
    xy = np.concatenate(([start], lc.every_record(ProgramRunner(program, config))["position"][:, :2]))
    speed = np.linalg.norm(np.diff(xy, axis=0), axis=1) / config.timing.period_s
    moving = np.flatnonzero(speed > STILL_MM_S)
    corner = np.asarray(points[1])
    near = np.linalg.norm(xy[1:] - corner, axis=1) < 1.0  # within a mm of the corner
    return int(moving[-1] - moving[0] + 1), float(speed[near].min()) if near.any() else math.nan


def optimum(points: list[tuple[float, float]], feed: int, tolerance: float, config: MachineConfig) -> int:
    """The least periods of any jerk-limited trajectory along `points` within P (`corner_bound.py`)."""
    return corner_bound.polyline_bound_ticks(points, lc.corner_limits(config, feed, tolerance))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--feeds", type=int, nargs="+", default=list(lc.CORNER_FEEDS), metavar="MM_MIN",
                    help="feeds (mm/min; default: the comparison's corner feeds)")
    ap.add_argument("--tolerances", type=float, nargs="+", default=list(lc.CORNER_TOLERANCES_MM), metavar="P",
                    help="G64 P values (mm; default: the comparison's)")
    ap.add_argument("--angles", type=float, nargs="+", default=list(lc.CORNER_ANGLES_DEG), metavar="DEG",
                    help="interior angles (degrees, between 0 and 180; default: the zigzag's)")
    args = ap.parse_args(argv)
    bad = [a for a in args.angles if not 0.0 < a < 180.0] + [f for f in args.feeds if f <= 0] + \
        [p for p in args.tolerances if p <= 0.0]
    if bad:
        ap.error(f"out of range: {', '.join(f'{b:g}' for b in bad)} (angles between 0 and 180, feeds and P above 0)")
    config = load_machine(lc.MACHINE_FILE, lc.NO_JET_DELAYS)
    dt_ms = config.timing.period_s * 1000.0
    began = time.monotonic()
    print(f"{'feed':>6} {'P mm':>6} {'interior':>9} {'optimum ms':>11} {'ours ms':>8} {'ratio':>6}  ours at the corner")
    for feed in args.feeds:
        for tolerance in args.tolerances:
            corner_bound.presolve([legs(a) for a in (None, *args.angles)], lc.corner_limits(config, feed, tolerance),
                                  len(os.sched_getaffinity(0)))
            straight_ours, _ = ours(legs(None), feed, tolerance, config)
            straight_best = optimum(legs(None), feed, tolerance, config)
            for interior in args.angles:
                ticks, slowest = ours(legs(interior), feed, tolerance, config)
                best = optimum(legs(interior), feed, tolerance, config) - straight_best
                cost = ticks - straight_ours
                at = "stops" if slowest <= STILL_MM_S else f"passes at {slowest:.1f} mm/s"
                ratio = f"{cost / best:6.2f}" if best > 0 else f"{'-':>6}"  # a corner cut within P may save time
                print(f"{feed:>6} {tolerance:>6g} {interior:>8g}° {best * dt_ms:>11.0f} {cost * dt_ms:>8.0f} "
                      f"{ratio}  {at}", flush=True)
    print(f"(cost: two {lc.ZIGZAG_LEG_MM:g} mm legs at the angle less one straight move of their length, from rest "
          f"to rest; optimum: corner_bound.py's least periods for both; {time.monotonic() - began:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
