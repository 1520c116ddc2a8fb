#!/usr/bin/env python3
"""What holds our planner back on the Fig. 10 contour: its budgets loosened one at a time.

The paper's test contour (cnc/control/fig10_contour.ngc: tangent lines and quarter arcs of R10-R30
at F30000, G64 P0.005) is the one program of `bench/linuxcnc_compare.py` still over LinuxCNC's
time, and `bench/fig10_reach.py` found a trajectory keeping every one of our limits in about half
our time. This bench asks which of the planner's budgets that gap lives in. Each row plans the
contour with one budget changed in memory (nothing in the repository is edited) and runs it through
`ProgramRunner`, the code the planner process runs:

- our planner as it is (the peer of every row);
- the axis average fixed at N samples, no search (`sections._longer_averages` chooses N now);
- the share of a curve's jerk budget its speed takes (`limits.CURVE_SPEED_SHARE`, 0.85);
- the deviation budget of the axis average on arcs doubled (2 P: not allowed, a probe);
- the curves' jerk budget doubled (the section's geometry share of the jerk, x2: a probe);
- the contour with clothoid-like transitions within P at each line-arc junction (each arc drawn
  in by p and joined to its lines by eight arcs of rising curvature, as a CAM could write it),
  run as it is and measured against the contour as programmed.

Per row: cycle time, its ratio to ours, the peaks of |v|, |a|, |j| over both axes against the
machine's limits, and the largest distance from the contour as programmed against P. A row whose
peaks or deviation pass their limit is a probe of what the budget is worth, not a plan the
planner could use. From the repository root (about a minute):

    .venv/bin/python bench/fig10_probes.py [--json OUT]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cnc.config import MachineConfig, load_machine  # noqa: E402
from cnc.machine_dialect import dialect_for  # noqa: E402
from cnc.planner import limits, sections  # noqa: E402
from cnc.planner.path import Element, distance_to, iter_elements  # noqa: E402
from cnc.planner.runner import ProgramRunner  # noqa: E402
from gcode.canon import ARC, LINE  # noqa: E402
from gcode.interp import interpret  # noqa: E402
from gcode.program import Program  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
CONTOUR = REPO / "cnc" / "control" / "fig10_contour.ngc"
TRANSITION_ARCS = 8  # arcs of rising curvature in each clothoid-like transition


def _interpret(text: str, config: MachineConfig) -> Program:
    """The program interpreted with the head at its first point (as the comparison starts it)."""
    dialect = dialect_for(config)
    first = interpret(text, dataclasses.replace(dialect, start_position_mm=(0.0, 0.0, 0.0))).segments[0]["end"]
    return interpret(text, dataclasses.replace(dialect, start_position_mm=(float(first[0]), float(first[1]), 0.0)))


def _run(program: Program, config: MachineConfig) -> np.ndarray:
    """Every commanded XY position of the program's run, from its start point at rest."""
    runner = ProgramRunner(program, config)
    chunks = [np.asarray(program.segments[0]["end"][:2], dtype=float)[None, :]]
    while not runner.finished:
        records, _ = runner.take(1000)
        chunks.append(records["position"][:, :2])
    return np.concatenate(chunks)


@contextlib.contextmanager
def _patched(module, name: str, value) -> Iterator[None]:  # noqa: ANN001 - a module
    old = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, old)


def _fixed_average(n: int):  # noqa: ANN202 - a context manager
    """Every section's axis average at n samples (under G64 P > 0), and no search for another."""
    stack = contextlib.ExitStack()
    stack.enter_context(_patched(limits, "axis_average_samples", lambda config, tolerance: n if tolerance > 0.0 else 1))
    stack.enter_context(_patched(sections, "_longer_averages",
                                 lambda whole, config, cut, elements, path, lim, seconds: (elements, path, lim)))
    return stack


def _curve_budgets(deviation: float = 1.0, jerk: float = 1.0):  # noqa: ANN202 - a context manager
    """The curves' deviation and jerk budgets (`limits._curvature_caps`) times these factors."""
    own = limits._curvature_caps

    def loosened(path, windows, sm, v_feed, j_curv, deviation_mm, *rest):  # noqa: ANN001, ANN202
        return own(path, windows, sm, v_feed, j_curv * jerk, deviation_mm * deviation, *rest)

    return _patched(limits, "_curvature_caps", loosened)


# ----------------------------------------------------------------------------------------------
# the contour with clothoid-like transitions


def _integrate(pieces: list[tuple[float, float]]) -> tuple[float, float, float]:
    """End point and heading of arcs (curvature, length) laid end to end from the origin along +x."""
    x = y = heading = 0.0
    for k, length in pieces:
        turn = k * length
        x += (math.sin(heading + turn) - math.sin(heading)) / k
        y += (math.cos(heading) - math.cos(heading + turn)) / k
        heading += turn
    return x, y, heading


def _transition(radius: float, shift: float) -> tuple[float, list[tuple[float, float]]]:
    """A transition from a line (y = 0, along +x) into the circle of centre (0, radius) drawn in to
    radius - shift: where it leaves the line (x) and its arcs (curvature rising in equal steps to
    the circle's), whose length makes it end on that circle, tangent to it."""
    inner = radius - shift

    def pieces(length: float) -> list[tuple[float, float]]:
        return [((i - 0.5) / TRANSITION_ARCS / inner, length / TRANSITION_ARCS) for i in range(1, TRANSITION_ARCS + 1)]

    lo, hi = 1e-6, math.pi * inner / 2.0
    for _ in range(100):  # the centre's distance from the line grows with the length
        mid = 0.5 * (lo + hi)
        x, y, heading = _integrate(pieces(mid))
        lo, hi = (mid, hi) if y + inner * math.cos(heading) < radius else (lo, mid)
    found = pieces(0.5 * (lo + hi))
    x, _, heading = _integrate(found)
    return inner * math.sin(heading) - x, found


def _laid(junction, along, inward, x0: float, found: list) -> tuple[tuple, list]:  # noqa: ANN001
    """The transition's arcs in the plane: (start point, [(end, centre), ...])."""
    ox, oy = junction[0] + x0 * along[0], junction[1] + x0 * along[1]
    out, x, y, heading = [], 0.0, 0.0, 0.0
    for k, length in found:
        cx, cy = x - math.sin(heading) / k, y + math.cos(heading) / k
        turn = k * length
        x += (math.sin(heading + turn) - math.sin(heading)) / k
        y += (math.cos(heading) - math.cos(heading + turn)) / k
        heading += turn
        point = (ox + x * along[0] + y * inward[0], oy + x * along[1] + y * inward[1])
        centre = (ox + cx * along[0] + cy * inward[0], oy + cx * along[1] + cy * inward[1])
        out.append((point, centre))
    return (ox, oy), out


def clothoid_contour(elements: list[Element], shift_mm: float) -> str:
    """The program of these lines and arcs (the contour as interpreted) with each arc between two
    lines drawn in by `shift_mm` and joined to them by clothoid-like transitions; an arc that meets
    another arc is kept as it is."""
    moves = [e for e in elements if e.kind in (LINE, ARC)]
    out: list[tuple] = []  # ("L", end) or ("A", end, centre, counter-clockwise)
    for k, e in enumerate(moves):
        lonely = e.kind == ARC and 0 < k < len(moves) - 1 and moves[k - 1].kind == LINE and moves[k + 1].kind == LINE
        if not lonely:
            out.append(("L", e.end[:2]) if e.kind == LINE else ("A", e.end[:2], e.center, not e.cw))
            continue
        centre, ccw = e.center, not e.cw
        radius = math.dist(e.start[:2], centre)
        x0, found = _transition(radius, shift_mm)
        pieces = []
        for junction, forward in ((e.start[:2], True), (e.end[:2], False)):
            ux, uy = (junction[0] - centre[0]) / radius, (junction[1] - centre[1]) / radius
            along = (-uy, ux) if ccw == forward else (uy, -ux)  # the way along the line towards the arc
            pieces.append(_laid(junction, along, (-ux, -uy), x0, found))
        (entry_start, entry), (exit_end, exit_back) = pieces
        out[-1] = ("L", entry_start)  # the line before ends where the transition leaves it
        out += [("A", point, c, ccw) for point, c in entry]
        back_points = [exit_end] + [p for p, _ in exit_back]
        out.append(("A", back_points[-1], centre, ccw))
        out += [("A", back_points[j], exit_back[j][1], ccw) for j in range(len(exit_back) - 1, -1, -1)]
    here = moves[0].start[:2]
    lines = [f"G21 G90 G17 G91.1 G64 P{min(e.tolerance_mm for e in moves):g}", f"G0 X{here[0]:.6f} Y{here[1]:.6f}",
             f"F{moves[0].feed_mm_s * 60.0:g}"]
    for move in out:
        if move[0] == "L":
            lines.append(f"G1 X{move[1][0]:.6f} Y{move[1][1]:.6f}")
        else:
            lines.append(f"{'G3' if move[3] else 'G2'} X{move[1][0]:.6f} Y{move[1][1]:.6f} "
                         f"I{move[2][0] - here[0]:.6f} J{move[2][1] - here[1]:.6f}")
        here = move[1]
    return "\n".join([*lines, "M2"]) + "\n"


# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Row:
    name: str
    cycle_s: float
    v: float
    a: float
    j: float
    deviation_mm: float


def measure(name: str, text: str, config: MachineConfig, programmed: list, change: Callable[[], contextlib.AbstractContextManager]) -> Row:  # noqa: E501
    dt = config.timing.period_s
    with change():
        xy = _run(_interpret(text, config), config)
    v = np.diff(xy, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    j = np.diff(a, axis=0) / dt
    return Row(name, (len(xy) - 1) * dt, float(np.abs(v).max()), float(np.abs(a).max()), float(np.abs(j).max()),
               float(distance_to(xy, programmed).max()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--json", metavar="OUT", help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    config = load_machine(args.machine)
    text = CONTOUR.read_text()
    programmed = list(iter_elements(_interpret(text, config).segments))
    tolerance = min(e.tolerance_mm for e in programmed)
    same = contextlib.nullcontext
    probes: list[tuple[str, str, Callable]] = [("our planner", text, same)]
    probes += [(f"axis average fixed at {n}", text, lambda n=n: _fixed_average(n)) for n in (4, 8, 11, 14)]
    probes += [(f"curve speed share {s}", text, lambda s=s: _patched(limits, "CURVE_SPEED_SHARE", s)) for s in (0.9, 0.95)]
    probes += [("deviation budget x2 (2 P)", text, lambda: _curve_budgets(deviation=2.0)),
               ("curves' jerk budget x2", text, lambda: _curve_budgets(jerk=2.0))]
    probes += [(f"clothoid transitions, p {p * 1000:g} um", clothoid_contour(programmed, p), same) for p in (0.001, 0.0025)]
    rows = [measure(name, program, config, programmed, change) for name, program, change in probes]
    axes = [config.axis[a] for a in "xy"]
    lim_v, lim_a, lim_j = (min(getattr(x, key) for x in axes) for key in ("max_velocity_mm_s", "max_accel_mm_s2", "max_jerk_mm_s3"))
    ours = rows[0].cycle_s
    print(f"the Fig. 10 contour (F30000, G64 P{tolerance:g}) with one budget changed at a time ({Path(args.machine).name})")
    print(f"{'probe':<32}{'cycle s':>9}{'/ ours':>8}{'|v| mm/s':>10}{'|a| mm/s2':>11}{'|j| mm/s3':>11}{'dev um':>8}  within")
    for r in rows:
        within = r.v <= lim_v * 1.001 and r.a <= lim_a * 1.001 and r.j <= lim_j * 1.001 and r.deviation_mm <= tolerance + 1e-9
        print(f"{r.name:<32}{r.cycle_s:>9.3f}{r.cycle_s / ours:>8.3f}{r.v:>10.1f}{r.a:>11.0f}{r.j:>11.3g}"
              f"{r.deviation_mm * 1000:>8.2f}  {'yes' if within else 'NO'}")
    print(f"limits: |v| {lim_v:g}, |a| {lim_a:g}, |j| {lim_j:g}, deviation {tolerance * 1000:g} um (from the contour as programmed)")
    if args.json:
        Path(args.json).write_text(json.dumps([dataclasses.asdict(r) for r in rows], indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
