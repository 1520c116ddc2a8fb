"""What overlapping the planner's stops would still save: an estimate for issue 19, point 4.

The planner overlaps the sections at a corner where nothing switches (`cnc/planner/overlap.py`):
the next one starts up to `[planner] corner_overlap_ms` before the last one comes to rest. This
bench asks what is left. It streams `bench/linuxcnc_compare.py`'s programs through the planner
(`ProgramRunner`, as the comparison does), then at every stop still between two moves finds the
largest overlap of the recorded samples (the second move shifted earlier by k servo periods and
added to the first's last ones) whose backward differences keep the axis limits and whose
samples stay within P of the programmed elements near the corner, with no cap on k. The rest
periods between the moves go as well. The sum is what overlapping every remaining stop, however
long, would save with the same profiles. (Before the planner overlapped, this bench found 7.7 s
in the nest's 205.3 s; the planner, capped at 40 ms, now saves 7.6 s of it.)

Nothing here changes the motion. It prints each program's cycle time, the estimate, and the
jerk-limited lower bound computed in the same run (`linuxcnc_compare.jerk_bound_s`) with both
ratios to it; LinuxCNC's times are in docs/benchmarks.md (the comparison itself takes minutes
of LinuxCNC in real time).

    .venv/bin/python bench/overlap_estimate.py [PREFIX ...]     # programs whose name starts so
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import linuxcnc_compare as compare  # noqa: E402

from cnc.config import load_machine  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402

NEAR_CORNER_MM = 5.0  # programmed elements this close to a stop are the corner's geometry
CONTEXT = 4  # samples either side of an overlap whose differences are checked too
GIVE_UP_AFTER = 40  # overlaps tried past the last one that kept the limits and P


def stream_xy(program, start: tuple[float, float], config) -> np.ndarray:
    runner = ProgramRunner(program, config)
    chunks = []
    while not runner.finished:
        records, _ = runner.take(1000)
        chunks.append(records)
    return np.concatenate(([start], np.concatenate(chunks)["position"][:, :2]))


def _distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((points - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.hypot(*(points - (a + np.outer(t, ab))).T)


class Limits:
    def __init__(self, config) -> None:
        self.dt = config.timing.period_s
        margin = 1.0 + 1e-6  # rounding of the differences, as the comparison's peaks allow
        self.v = np.array([config.axis[a].max_velocity_mm_s for a in "xy"]) * margin
        self.a = np.array([config.axis[a].max_accel_mm_s2 for a in "xy"]) * margin
        self.j = np.array([config.axis[a].max_jerk_mm_s3 for a in "xy"]) * margin

    def kept(self, xy: np.ndarray) -> bool:
        v = np.diff(xy, axis=0) / self.dt
        a = np.diff(v, axis=0) / self.dt
        j = np.diff(a, axis=0) / self.dt
        return not ((np.abs(v) > self.v).any() or (np.abs(a) > self.a).any() or (np.abs(j) > self.j).any())


def overlap_saving(xy: np.ndarray, program, limits: Limits) -> tuple[int, int]:
    """(servo periods saved, stops between moves) over the whole run."""
    tolerance = float(program.segments["tolerance"].max())
    seg = program.segments
    starts, ends = seg["start"][:, :2].astype(float), seg["end"][:, :2].astype(float)
    real = np.any(starts != ends, axis=1)
    moving = np.any(np.abs(np.diff(xy, axis=0)) > 1e-9, axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], moving.astype(int), [0]))))
    moves = list(zip(edges[::2], edges[1::2]))  # [first step, last step + 1) of each motion
    saved = 0
    for (s0, e0), (s1, e1) in zip(moves[:-1], moves[1:]):
        first, second = xy[s0 : e0 + 1], xy[s1 : e1 + 1]
        corner = second[0]
        near = [k for k in np.flatnonzero(real) if _distance(corner[None], starts[k], ends[k])[0] < NEAR_CORNER_MM]
        n, m = len(first) - 1, len(second) - 1
        best = 0
        for k in range(1, min(n, m)):
            joined = first[n - k :] + (second[: k + 1] - corner)
            around = np.concatenate((first[max(0, n - k - CONTEXT) : n - k], joined, second[k + 1 : k + 1 + CONTEXT]))
            deviation = np.min([_distance(joined, starts[i], ends[i]) for i in near], axis=0).max()
            if limits.kept(around) and deviation <= tolerance:
                best = k
            elif k > best + GIVE_UP_AFTER:
                break
        saved += (s1 - e0) + best  # the rest between the moves, and the overlap
    return saved, len(moves) - 1


def main(argv: list[str]) -> int:
    config = load_machine(compare.MACHINE_FILE, compare.NO_JET_DELAYS)
    limits = Limits(config)
    print(f"{'program':34s} {'ours s':>9s} {'stops':>6s} {'overlap s':>10s} {'estimate s':>11s} "
          f"{'j-bound s':>10s} {'ours/bound':>11s} {'estimate/bound':>15s}")
    for bench in compare.benches():
        if argv and not any(bench.name.startswith(p) for p in argv):
            continue
        program, start = compare.interpret_from_start(bench.text, config)
        xy = stream_xy(program, start, config)
        total = compare.motion_time_s(xy, limits.dt)
        saved, stops = overlap_saving(xy, program, limits)
        estimate = total - saved * limits.dt
        bound = compare.jerk_bound_s(program, config)
        print(f"{bench.name:34s} {total:9.3f} {stops:6d} {saved * limits.dt:10.3f} {estimate:11.3f} "
              f"{bound:10.3f} {total / bound:11.3f} {estimate / bound:15.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
