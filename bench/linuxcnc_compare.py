"""Our trajectory planner beside LinuxCNC's: cycle time and path deviation, same programs, same limits.

Each program runs through our planner offline (interpreter, `ProgramRunner`: the code the
planner process runs) and through a headless LinuxCNC 2.9 (`linuxcnc_sim.run_linuxcnc`), with
the axis limits of machines/waterjet.toml (X/Y velocity, acceleration, travel, servo period)
and both machines starting at the program's first point. LinuxCNC gets no jerk limit (2.9
has none); ours holds its own. Programs (generated; all within the 1600 x 1200 mm table):

- the paper's test contour, cnc/control/fig10_contour.ngc (tangent lines and arcs, G64 P0.005);
- corner tests: a 100 mm square, and a zigzag whose corners have interior angles of 30, 60,
  90, 120 and 150 degrees (30 = a sharp turn), at F12000 and F30000, G64 P0.05 and P0.005;
- CAM polylines: a circle R100 as 0.5 mm chords at F6000, and a Lissajous curve as 0.2-2 mm
  chords at F12000, G64 P0.05;
- a nest: bench/gcode_speed.py's nesting program, about 2000 lines, with the kerf applied by
  CAM and without jet, pierce-dwell and tool-change lines (LinuxCNC has none of our jet delays).

For each: cycle time, both measured alike (servo periods from the last sample at rest before
the first move to the last change of the commanded position, at LinuxCNC's 1 um sampling
resolution), and their ratio ours/LinuxCNC (target <= 1.0); the largest distance of the
commanded XY from the programmed geometry against the program's G64 P (target <= P); and
per-axis peaks of |v|, |a|, |j| (backward differences of the commanded positions, at rest
before and after). Distances are taken to the programmed elements near each sample's
segment: ours tags every setpoint with it; LinuxCNC's samples carry their program line, which
bounds the segments they may be on (`segment_spans`). A cross-check takes the distance to the
nearest element anywhere in the program (in the JSON; a line is printed where they differ).

From the repository root, with the project installed (LinuxCNC runs in real time: minutes):

    .venv/bin/python bench/linuxcnc_compare.py [--quick] [--only PREFIX] [--json OUT]

For the nest it also gives each planner's time by what the lines do (rapids, lead-ins, contours,
lead-outs: `line_kinds`).

Beside each program, a time no planner holding our jerk limit beats (`jerk_bound_s`: the feeds
and the ramps at rest); on the squares and zigzags the corners counted too (`corner_bound.py`:
the least servo periods of any sampled trajectory within the limits and P, by linear
programming, a few minutes on two CPUs). Where LinuxCNC is below it, <= 1.0x is impossible
while jerk-limited, and the table says BOUND.

Exits 0 when every program ran on both (or LinuxCNC is unavailable here: then only our
figures are shown, with the reason), 1 when a LinuxCNC run failed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import random
import re
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

import corner_bound
import linuxcnc_sim
from gcode_speed import nesting_program

from cnc.config import MachineConfig, load_machine
from cnc.machine_dialect import dialect_for
from cnc.planner.measure import ProgrammedPath, peaks
from cnc.planner.path import elements_from_program
from cnc.planner.runner import ProgramRunner
from gcode.canon import ARC, DWELL
from gcode.interp import interpret
from gcode.program import Program

BENCH = Path(__file__).resolve().parent
MACHINE_FILE = BENCH.parent / "machines" / "waterjet.toml"
FIG10_FILE = BENCH.parent / "cnc" / "control" / "fig10_contour.ngc"
AXES = ("x", "y")
# LinuxCNC has no jet: none of our jet-on, pierce and jet-off pauses may count in our time
NO_JET_DELAYS = {"jet.on_delay_s": 0.0, "jet.pierce_dwell_s": 0.0, "jet.off_delay_s": 0.0}
SAMPLE_RESOLUTION_MM = 1e-6  # halsampler prints "%f": LinuxCNC's positions come rounded to this
REST_SAMPLES = 3  # samples at rest added around a trajectory, so the peaks see it start and stop
TAG_WINDOW = 8  # elements either side of a sample's segment searched for the nearest geometry
LINE_LEAD_RUNS = 2  # how many reported lines LinuxCNC's program line may run ahead of its head
TAG_CHECK_MM = 1e-6  # tagged and nearest-anywhere deviation should agree to this
HEADER = "G21 G90 G17 G40 G94"
CORNER_FEEDS = (12000, 30000)  # mm/min: 200 and 500 mm/s
CORNER_TOLERANCES_MM = (0.05, 0.005)
CORNER_ANGLES_DEG = (30, 60, 90, 120, 150)
SQUARE_MM = 100.0
ZIGZAG_LEG_MM = 50.0
CAM_TOLERANCE_MM = 0.05  # G64 P of the CAM polylines and of the nest
CHORD_CIRCLE_RADIUS_MM, CHORD_CIRCLE_CHORD_MM, CHORD_CIRCLE_FEED = 100.0, 0.5, 6000
LISSAJOUS_AMPLITUDE_MM = (300.0, 200.0)
LISSAJOUS_CHORD_MM = (0.2, 2.0)
LISSAJOUS_FEED = 12000
NEST_LINES = 2000
NEST_DROPPED = re.compile(r"^(M3|M5|G4 P[\d.]+|T\d+ M6)$")  # jet, pierce dwell, tool change
TABLE_CENTRE = (800.0, 600.0)


@dataclass(frozen=True)
class Bench:
    """One program of the comparison."""

    name: str
    text: str
    quick: bool = False  # part of the --quick subset
    polyline: tuple[tuple[float, float], ...] | None = None  # straight moves through these, rest to rest
    feed_mm_min: float = 0.0  # of those moves


@dataclass
class Figures:
    """One planner's result on one program."""

    cycle_time_s: float
    max_deviation_mm: float
    max_deviation_anywhere_mm: float  # to the nearest element of the whole program (cross-check)
    peak_velocity_mm_s: list[float]
    peak_accel_mm_s2: list[float]
    peak_jerk_mm_s3: list[float]
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass
class Comparison:
    """Both planners on one program."""

    bench: Bench
    tolerance_mm: float
    start_mm: tuple[float, float]
    ours: Figures
    linuxcnc: Figures | None = None
    linuxcnc_error: str = ""
    jerk_bound_s: float = 0.0  # no jerk-limited planner is faster: `jerk_bound_s`, or the corner bound where larger
    corner_bound_s: float | None = None  # `corner_bound.polyline_bound_ticks` (the polylines of straight moves)

    @property
    def beyond_jerk(self) -> bool:
        """LinuxCNC's time is below what any planner holding our jerk limit can do."""
        return self.linuxcnc is not None and self.linuxcnc.cycle_time_s < self.jerk_bound_s

    @property
    def ratio(self) -> float | None:
        return self.ours.cycle_time_s / self.linuxcnc.cycle_time_s if self.linuxcnc else None


# --------------------------------------------------------------------------------------
# Programs
# --------------------------------------------------------------------------------------


def _program(title: str, tolerance_mm: float, feed: int, points: list[tuple[float, float]]) -> str:
    """A rapid to the first point, then straight moves through the others at `feed` (mm/min)."""
    (x0, y0), rest = points[0], points[1:]
    lines = [f"({title})", HEADER, f"G64 P{tolerance_mm:g}", f"G0 X{x0:.4f} Y{y0:.4f}", f"F{feed}"]
    lines += [f"G1 X{x:.4f} Y{y:.4f}" for x, y in rest]
    return "\n".join([*lines, "M2"]) + "\n"


def _square(origin: tuple[float, float]) -> list[tuple[float, float]]:
    x, y = origin
    s = SQUARE_MM
    return [(x, y), (x + s, y), (x + s, y + s), (x, y + s), (x, y)]


def _zigzag(origin: tuple[float, float]) -> list[tuple[float, float]]:
    """Straight legs meeting at CORNER_ANGLES_DEG (interior angles), turning left and right in turn."""
    heading, points = 0.0, [origin]
    for k, angle in enumerate((*CORNER_ANGLES_DEG, None)):
        x, y = points[-1]
        points.append((x + ZIGZAG_LEG_MM * math.cos(heading), y + ZIGZAG_LEG_MM * math.sin(heading)))
        if angle is not None:
            heading += (-1) ** k * math.radians(180 - angle)
    return points


def corner_benches() -> list[Bench]:
    benches = []
    for shape, points, origin in (("square 100", _square, (200.0, 200.0)), ("zigzag", _zigzag, (600.0, 400.0))):
        for feed in CORNER_FEEDS:
            for p in CORNER_TOLERANCES_MM:
                name = f"{shape} F{feed} P{p:g}"
                quick = (shape, feed, p) in (("square 100", 12000, 0.05), ("zigzag", 30000, 0.005))
                benches.append(Bench(name, _program(name, p, feed, points(origin)), quick, tuple(points(origin)), feed))
    return benches


def chord_circle_bench() -> Bench:
    cx, cy = TABLE_CENTRE
    r = CHORD_CIRCLE_RADIUS_MM
    n = round(2 * math.pi * r / CHORD_CIRCLE_CHORD_MM)
    angles = [2 * math.pi * k / n for k in range(n + 1)]
    points = [(cx + r * math.cos(a), cy + r * math.sin(a)) for a in angles]
    name = f"circle R{r:g} {n} chords F{CHORD_CIRCLE_FEED}"
    return Bench(name, _program(name, CAM_TOLERANCE_MM, CHORD_CIRCLE_FEED, points), quick=True)


def lissajous_bench(seed: int = 1) -> Bench:
    """x = cx + A sin 3t, y = cy + B sin 2t, cut into chords of random length between the limits."""
    (cx, cy), (a, b) = TABLE_CENTRE, LISSAJOUS_AMPLITUDE_MM
    t = np.linspace(0.0, 2 * math.pi, 400_001)
    curve = np.column_stack((cx + a * np.sin(3 * t), cy + b * np.sin(2 * t)))
    s = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(curve, axis=0).T))))
    rng = random.Random(seed)
    stations = [0.0]
    while stations[-1] + 2 * LISSAJOUS_CHORD_MM[1] < s[-1]:
        stations.append(stations[-1] + rng.uniform(*LISSAJOUS_CHORD_MM))
    stations.append(s[-1])
    at = np.interp(stations, s, t)
    points = list(zip(cx + a * np.sin(3 * at), cy + b * np.sin(2 * at)))
    name = f"lissajous {len(points) - 1} chords F{LISSAJOUS_FEED}"
    return Bench(name, _program(name, CAM_TOLERANCE_MM, LISSAJOUS_FEED, points))


def nest_bench() -> Bench:
    """The nesting program's first parts, CAM kerf, no jet: only motion left to compare."""
    text = nesting_program(NEST_LINES).replace("G41 D1 ", "").replace("G40 ", "")
    lines = [ln for ln in text.splitlines() if not NEST_DROPPED.match(ln)]
    return Bench(f"nest {len(lines)} lines F2400", "\n".join(lines) + "\n")


def kerf_nest_bench() -> Bench:
    """The same parts with their kerf compensated by the controller (G41/G42 D1, G40 on the
    lead-out; LinuxCNC's tool table holds the same diameter), no jet: how the paper's CAM writes
    them. Not in the main table (its runs are those of earlier sessions): `--only kerf`."""
    text = nesting_program(NEST_LINES)
    lines = [ln for ln in text.splitlines() if not NEST_DROPPED.match(ln)]
    return Bench(f"kerf nest {len(lines)} lines F2400", "\n".join(lines) + "\n")


def benches(kerf: bool = False) -> list[Bench]:
    """The comparison's programs; `kerf`: the nest compensated by the controller instead."""
    if kerf:
        return [kerf_nest_bench()]
    fig10 = Bench("fig10 contour F30000", FIG10_FILE.read_text(), quick=True)
    return [fig10, *corner_benches(), chord_circle_bench(), lissajous_bench(), nest_bench()]


# --------------------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------------------


def motion_time_s(xy: np.ndarray, dt: float) -> float:
    """Periods from the last sample at rest before the first move to the last change, at 1 um."""
    steps = np.any(np.diff(np.round(xy / SAMPLE_RESOLUTION_MM), axis=0) != 0, axis=1)
    moved = np.nonzero(steps)[0]
    return float(moved[-1] + 1 - moved[0]) * dt if moved.size else 0.0


def peak_figures(xy: np.ndarray, dt: float) -> dict[str, list[float]]:
    """Per-axis peaks of the trajectory with the machine at rest before and after it."""
    padded = np.concatenate((np.repeat(xy[:1], REST_SAMPLES, 0), xy, np.repeat(xy[-1:], REST_SAMPLES, 0)))
    top = peaks(padded, dt)
    return {"peak_velocity_mm_s": top["velocity"].tolist(), "peak_accel_mm_s2": top["acceleration"].tolist(),
            "peak_jerk_mm_s3": top["jerk"].tolist()}


def distance_anywhere(path: ProgrammedPath, xy: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest element of the whole program (slow: every element)."""
    n, span = len(path.elements), 2 * TAG_WINDOW + 1
    best = np.full(len(xy), np.inf)
    for centre in range(TAG_WINDOW, n + span - 1, span):
        tag = path.elements[min(centre, n - 1)].segment
        best = np.minimum(best, path.distance(xy, np.full(len(xy), tag), TAG_WINDOW))
    return best


def deviation_anywhere(path: ProgrammedPath, xy: np.ndarray, deviation: np.ndarray) -> float:
    """Largest distance to the nearest element anywhere in the program: a cross-check of the
    tagged `deviation` (it is never larger). Taken where `deviation` is at least half its peak
    only, which gives the exact figure whenever that is at least half the peak."""
    far = deviation >= 0.5 * deviation.max()
    return float(distance_anywhere(path, xy[far]).max())


def segment_spans(segment_lines: np.ndarray, lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each LinuxCNC sample, the first and last program segment it may be on: from the last
    segment of the line reported LINE_LEAD_RUNS changes of line before its own to the last
    segment of its own line. LinuxCNC reports lines in program order, but ahead of the head:
    a run of short moves it merged into one (its naive-CAM detector, G64 Q, which defaults to P)
    is reported by the run's last line, and a blend by the line it blends into."""
    if np.any(np.diff(segment_lines) < 0):
        raise ValueError("program segments are not in line order: cannot map LinuxCNC's lines to them")
    last = np.clip(np.searchsorted(segment_lines, lines, side="right") - 1, 0, len(segment_lines) - 1)
    run_starts = np.concatenate(([0], np.flatnonzero(np.diff(lines)) + 1))
    run = np.searchsorted(run_starts, np.arange(len(lines)), side="right") - 1
    before = last[run_starts[np.maximum(run - LINE_LEAD_RUNS, 0)]]
    return np.minimum(before, last), np.maximum(before, last)


def deviation_by_line(path: ProgrammedPath, program: Program, xy: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Distance of each sample to the nearest element its program line allows (`segment_spans`,
    widened by TAG_WINDOW elements either side for the corner blends)."""
    first, last = segment_spans(program.segments["line"], lines)
    span = 2 * TAG_WINDOW + 1
    best = np.full(len(xy), np.inf)
    for offset in range(0, int((last - first).max()) + span, span):  # the last tag is `last` itself
        best = np.minimum(best, path.distance(xy, np.minimum(first + offset, last), TAG_WINDOW))
    return best


def figures(path: ProgrammedPath, xy: np.ndarray, deviation: np.ndarray, dt: float, **extra: Any) -> Figures:
    """A planner's figures from its commanded XY (from rest) and the tagged deviation of each sample."""
    return Figures(motion_time_s(xy, dt), float(deviation.max()), deviation_anywhere(path, xy, deviation),
                   **peak_figures(xy, dt), extra=extra)


LINE_KINDS = ("rapids", "lead-ins", "contours", "lead-outs")


def line_kinds(text: str) -> dict[int, str]:
    """Each motion line of a nest by what it does: a rapid; the first feed move after a rapid (the
    lead-in); the last one before the next rapid (the lead-out); the contour between them."""
    kinds: dict[int, str] = {}
    feeds: list[int] = []

    def close() -> None:
        for k, line in enumerate(feeds):
            kinds[line] = "lead-ins" if k == 0 else "lead-outs" if k == len(feeds) - 1 else "contours"
        feeds.clear()
    for number, rapid in _motion_lines(text):
        if rapid:
            close()
            kinds[number] = "rapids"
        else:
            feeds.append(number)
    close()
    return kinds


def line_parts(text: str) -> dict[int, int]:
    """Each motion line's part of a nest: a part starts at each rapid (part 0 is what comes before
    the first)."""
    parts: dict[int, int] = {}
    part = 0
    for number, rapid in _motion_lines(text):
        part += rapid
        parts[number] = part
    return parts


def _motion_lines(text: str) -> Iterator[tuple[int, bool]]:
    """(line number, whether it is a rapid) of each line that starts with G0 to G3."""
    for number, raw in enumerate(text.splitlines(), 1):
        words = raw.split()
        if words and re.fullmatch(r"G0?[0-3]", words[0]):
            yield number, words[0] in ("G0", "G00")


def seconds_by(sample_lines: np.ndarray, groups: dict[int, Any], dt: float) -> dict[Any, float]:
    """Servo periods counted to the program line each sample carries, summed by the group each
    line is in (`line_kinds`, `line_parts`; a corner's time may go to either of its lines)."""
    out: dict[Any, float] = {}
    lines, counts = np.unique(np.asarray(sample_lines, dtype=np.int64), return_counts=True)
    for line, n in zip(lines.tolist(), counts.tolist()):
        if line in groups:
            out[groups[line]] = out.get(groups[line], 0.0) + n * dt
    return out


def time_split(sample_lines: np.ndarray, kinds: dict[int, str], parts: dict[int, int], dt: float) -> dict[str, Any]:
    """A run's time by line kind (every kind, 0 where none) and by part (a list, part 0 first)."""
    by_kind, by_part = seconds_by(sample_lines, kinds, dt), seconds_by(sample_lines, parts, dt)
    return {"by_line_kind_s": {k: by_kind.get(k, 0.0) for k in LINE_KINDS},
            "by_part_s": [by_part.get(p, 0.0) for p in range(max(parts.values(), default=0) + 1)]}


# --------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------


def interpret_from_start(text: str, config: MachineConfig) -> tuple[Program, tuple[float, float]]:
    """The program interpreted with the head at its first programmed point (where both machines start)."""
    dialect = dialect_for(config)
    first = interpret(text, dataclasses.replace(dialect, start_position_mm=(0.0, 0.0, 0.0))).segments[0]["end"]
    start = (float(first[0]), float(first[1]))
    return interpret(text, dataclasses.replace(dialect, start_position_mm=(*start, 0.0))), start


def feed_bound_s(program: Program, config: MachineConfig) -> float:
    """A time no planner beats: every element at its feed, or at the speed its axes allow (a line:
    the tightest axis over its direction; an arc: the axes' combined top speed), with no
    acceleration at all; dwells as programmed."""
    caps = [config.axis[a].max_velocity_mm_s for a in ("x", "y")]
    total = 0.0
    for e in elements_from_program(program.segments):
        if e.kind == DWELL:
            total += e.dwell_s
            continue
        if e.kind == ARC:
            v_axes = math.hypot(*caps)
        else:
            d = [abs(e.end[i] - e.start[i]) for i in range(2)]
            v_axes = min((c * e.length_mm / di for c, di in zip(caps, d) if di > 0.0), default=math.inf)
        total += e.length_mm / min(e.feed_mm_s, v_axes)
    return total


def _ramp(v: float, a: float, j: float) -> tuple[float, float]:
    """Time and distance of the fastest jerk-limited speed-up from rest to v (no acceleration at
    either end): a triangle of acceleration below a^2/j, a trapezoid above."""
    t = 2.0 * math.sqrt(v / j) if v <= a * a / j else v / a + a / j
    return t, v * t / 2.0


def _element_speeds(elements: list, caps: list[float]) -> list[float]:
    """Each element's top speed: its feed, or what its axes allow (as `feed_bound_s`)."""
    out = []
    for e in elements:
        if e.kind == ARC:
            v_axes = math.hypot(*caps)
        else:
            d = [abs(e.end[i] - e.start[i]) for i in range(2)]
            v_axes = min((c * e.length_mm / di for c, di in zip(caps, d) if di > 0.0), default=math.inf)
        out.append(min(e.feed_mm_s, v_axes))
    return out


def jerk_bound_s(program: Program, config: MachineConfig) -> float:
    """A time no planner that holds the axes' acceleration and jerk limits beats: `feed_bound_s`,
    plus the least a speed-up from rest and a slow-down to rest cost wherever every planner
    stands still (the program's start and end, and around dwells). Near such a rest the path
    runs along the directions of the elements within the ramp's distance; along a unit
    direction u the axes allow a path acceleration of A / max(|ux|, |uy|) (A sqrt 2 on a
    diagonal), and so for jerk: the most generous of those directions counts (any direction
    for an arc there), and the lowest top speed of those elements. A stretch too short to reach
    that speed counts as the fastest rest-to-rest move over its length. Corners are not
    counted: a planner may pass them within G64 P at any speed its limits allow, so this bound
    is below what any planner achieves on programs with sharp corners."""
    caps = [config.axis[a].max_velocity_mm_s for a in ("x", "y")]
    a_axis = min(config.axis[a].max_accel_mm_s2 for a in ("x", "y"))
    j_axis = min(config.axis[a].max_jerk_mm_s3 for a in ("x", "y"))
    total, stretch = 0.0, []
    for e in [*elements_from_program(program.segments), None]:
        if e is not None and e.kind != DWELL:
            stretch.append(e)
            continue
        if stretch:
            total += _stretch_bound_s(stretch, _element_speeds(stretch, caps), a_axis, j_axis)
            stretch = []
        if e is not None:
            total += e.dwell_s
    return total


def corner_limits(config: MachineConfig, feed_mm_min: float, tolerance_mm: float) -> corner_bound.Limits:
    """The corner bound's problem for this machine's X and Y axes, a feed and a G64 P."""
    axes = [config.axis[a] for a in AXES]
    return corner_bound.Limits(config.timing.period_s, tuple(a.max_velocity_mm_s for a in axes),
                               tuple(a.max_accel_mm_s2 for a in axes), tuple(a.max_jerk_mm_s3 for a in axes),
                               feed_mm_min / 60.0, tolerance_mm)


def corner_bound_s(bench: Bench, tolerance_mm: float, config: MachineConfig) -> float:
    """The bound that counts the corners too, for a polyline of straight moves from rest to rest
    (`corner_bound.py`: the least servo periods of any sampled trajectory holding the axes'
    velocity, acceleration and jerk, the feed, and G64 P)."""
    limits = corner_limits(config, bench.feed_mm_min, tolerance_mm)
    workers = len(os.sched_getaffinity(0))
    return corner_bound.polyline_bound_ticks(list(bench.polyline), limits, workers) * config.timing.period_s


def _axis_factor(e) -> float:
    """How much faster than one axis's limit the path may accelerate along element e."""
    if e.kind == ARC:
        return math.sqrt(2.0)  # an arc may turn through the diagonal
    d = e.direction_at_start()
    return 1.0 / max(abs(d[0]), abs(d[1]), 1.0 / math.sqrt(2.0))


def _stretch_bound_s(elements: list, speeds: list[float], a_axis: float, j_axis: float) -> float:
    lengths = [e.length_mm for e in elements]
    cruise = sum(length / v for length, v in zip(lengths, speeds))
    total_mm = sum(lengths)

    def near(order: list[int]) -> tuple[float, float, float]:
        """(speed, acceleration, jerk) for the ramp at one end: the lowest top speed and the most
        generous direction among the elements within the ramp's distance."""
        v, factor, done = math.inf, 0.0, 0.0
        for k in order:
            v, factor = min(v, speeds[k]), max(factor, _axis_factor(elements[k]))
            if done >= _ramp(v, factor * a_axis, factor * j_axis)[1]:
                break
            done += lengths[k]
        return v, factor * a_axis, factor * j_axis

    (v_in, a_in, j_in), (v_out, a_out, j_out) = near(list(range(len(elements)))), near(list(range(len(elements) - 1, -1, -1)))
    (t_in, d_in), (t_out, d_out) = _ramp(v_in, a_in, j_in), _ramp(v_out, a_out, j_out)
    if d_in + d_out <= total_mm:
        return cruise + (t_in - d_in / v_in) + (t_out - d_out / v_out)
    a, j = max(a_in, a_out), max(j_in, j_out)  # too short: the fastest rest-to-rest move over its length
    lo, hi = 0.0, min(v_in, v_out)
    for _ in range(60):
        mid = (lo + hi) / 2.0
        lo, hi = (mid, hi) if 2.0 * _ramp(mid, a, j)[1] <= total_mm else (lo, mid)
    return max(cruise, 2.0 * _ramp(lo, a, j)[0])


def every_record(runner: ProgramRunner) -> np.ndarray:
    """The runner's setpoint records from where it stands to the program's end, in one array."""
    chunks = []
    while not runner.finished:
        records, _ = runner.take(1000)
        chunks.append(records)
    return np.concatenate(chunks)


def run_ours(program: Program, start: tuple[float, float], config: MachineConfig, kinds: dict[int, str],
             parts: dict[int, int]) -> Figures:
    dt = config.timing.period_s
    runner = ProgramRunner(program, config)
    planned = runner.planned_ticks()
    wall = time.monotonic()
    records = every_record(runner)
    wall = time.monotonic() - wall
    xy = np.concatenate(([start], records["position"]))
    tags = np.concatenate((records["segment"][:1], records["segment"]))
    path = ProgrammedPath(program.segments)
    deviation = path.distance(xy, tags, TAG_WINDOW)
    return figures(path, xy, deviation, dt,
                   records_s=len(records) * dt, planned_s=planned * dt, planning_wall_s=wall,
                   **time_split(program.segments["line"][records["segment"]], kinds, parts, dt))


def run_linuxcnc_like_ours(program_file: Path, start: tuple[float, float], config: MachineConfig) -> dict:
    """LinuxCNC's run of the program (`linuxcnc_sim.run_linuxcnc`) with this machine's X and Y
    limits, travel, servo period and nozzle table, from the program's first point."""
    return linuxcnc_sim.run_linuxcnc(
        program_file,
        max_velocity_mm_s={ax: config.axis[ax].max_velocity_mm_s for ax in AXES},
        max_accel_mm_s2={ax: config.axis[ax].max_accel_mm_s2 for ax in AXES},
        travel_mm={ax: (config.axis[ax].travel_min_mm, config.axis[ax].travel_max_mm) for ax in AXES},
        period_s=config.timing.period_s, home_mm=dict(zip(AXES, start)),
        tools_mm=dict(dialect_for(config).tool_diameters_mm))


def run_theirs(program_file: Path, program: Program, start: tuple[float, float],
               config: MachineConfig, kinds: dict[int, str], parts: dict[int, int]) -> Figures:
    dt = config.timing.period_s
    wall = time.monotonic()
    res = run_linuxcnc_like_ours(program_file, start, config)
    wall = time.monotonic() - wall
    xy = res["xy_mm"]
    path = ProgrammedPath(program.segments)
    return figures(path, xy, deviation_by_line(path, program, xy, res["line"]), dt,
                   linuxcnc_cycle_time_s=res["cycle_time_s"], in_position_time_s=res["in_position_time_s"],
                   version=res["version"], how=res["how"], run_wall_s=wall,
                   **time_split(res["line"], kinds, parts, dt))


def compare(bench: Bench, config: MachineConfig, workdir: Path, with_linuxcnc: bool) -> Comparison:
    program, start = interpret_from_start(bench.text, config)
    tolerance_mm = float(program.segments["tolerance"].max())
    kinds, parts = line_kinds(bench.text), line_parts(bench.text)
    result = Comparison(bench, tolerance_mm, start, run_ours(program, start, config, kinds, parts),
                        jerk_bound_s=jerk_bound_s(program, config))
    if bench.polyline is not None:
        result.corner_bound_s = corner_bound_s(bench, tolerance_mm, config)
        result.jerk_bound_s = max(result.jerk_bound_s, result.corner_bound_s)
    if with_linuxcnc:
        program_file = workdir / (re.sub(r"[^\w.]+", "_", bench.name) + ".ngc")
        program_file.write_text(bench.text)
        try:
            result.linuxcnc = run_theirs(program_file, program, start, config, kinds, parts)
        except linuxcnc_sim.LinuxCNCRunError as exc:
            result.linuxcnc_error = str(exc)
    return result


# --------------------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------------------


def _pair(values: list[float], fmt: str) -> str:
    return " / ".join(format(v, fmt) for v in values)


def _verdict(ok: bool) -> str:
    return "met" if ok else "MISSED"


def render_targets(rows: list[Comparison]) -> list[str]:
    out = [f"{'program':34} {'P mm':>6} {'ours s':>8} {'LCNC s':>8} {'ratio':>6} {'<=1.0':>6} {'j-bound s':>9} "
           f"{'/bound':>6}  {'ours dev mm':>11} {'/P':>5} {'<=P':>6}  {'LCNC dev mm':>11} {'/P':>5} {'<=P':>6}"]
    for c in rows:
        ours, theirs, p = c.ours, c.linuxcnc, c.tolerance_mm
        dev = ours.max_deviation_mm
        bound = f"{c.jerk_bound_s:9.3f} {ours.cycle_time_s / c.jerk_bound_s:6.3f}"
        mine = f"{dev:11.5f} {dev / p:5.2f} {_verdict(dev <= p):>6}"
        if theirs is None:
            peer = f"{'-':>8} {'-':>6} {'-':>6} {bound}  {mine}  {'-':>11} {'-':>5} {'-':>6}"
        else:
            # below the jerk-limited bound LinuxCNC cannot be matched while jerk-limited: the
            # figure that counts there is ours against the bound
            verdict = "met" if c.ratio <= 1.0 else "BOUND" if c.beyond_jerk else "MISSED"
            peer = (f"{theirs.cycle_time_s:8.3f} {c.ratio:6.2f} {verdict:>6} {bound}  {mine}  "
                    f"{theirs.max_deviation_mm:11.5f} {theirs.max_deviation_mm / p:5.2f} "
                    f"{_verdict(theirs.max_deviation_mm <= p):>6}")
        out.append(f"{c.bench.name:34} {p:6.3f} {ours.cycle_time_s:8.3f} {peer}")
    out.append("<=1.0: BOUND where LinuxCNC is faster than any planner holding our jerk limit can be "
               "(its time is below j-bound: `jerk_bound_s`, on the squares and zigzags the corners counted too, "
               "`corner_bound.py`); /bound: ours over that bound")
    return out


def render_peaks(rows: list[Comparison]) -> list[str]:
    out = [f"{'peaks per axis, X / Y':34} {'planner':9} {'|v| mm/s':>15} {'|a| mm/s^2':>17} {'|j| mm/s^3':>21}"]
    for c in rows:
        for label, f in (("ours", c.ours), ("LinuxCNC", c.linuxcnc)):
            if f is not None:
                name = c.bench.name if label == "ours" else ""
                out.append(f"{name:34} {label:9} {_pair(f.peak_velocity_mm_s, '6.1f'):>15} "
                           f"{_pair(f.peak_accel_mm_s2, '7.1f'):>17} {_pair(f.peak_jerk_mm_s3, '9.3g'):>21}")
    return out


def render_summary(rows: list[Comparison], config: MachineConfig) -> list[str]:
    both = [c for c in rows if c.linuxcnc is not None]
    x = config.axis["x"]
    ours_ok = f"deviation <= P: ours {sum(c.ours.max_deviation_mm <= c.tolerance_mm for c in rows)} of {len(rows)}"
    if both:
        faster = sum(c.ratio <= 1.0 for c in both)
        bounded = sum(c.ratio > 1.0 and c.beyond_jerk for c in both)
        theirs_ok = sum(c.linuxcnc.max_deviation_mm <= c.tolerance_mm for c in both)
        targets = (f"targets: cycle time ratio <= 1.0 met on {faster} of {len(both)}, beyond the jerk-limited bound on "
                   f"{bounded} more; "
                   f"{ours_ok}, LinuxCNC {theirs_ok} of {len(both)}")
    else:
        targets = f"targets: cycle time ratio not measured (LinuxCNC did not run); {ours_ok}"
    out = [targets,
           f"note: LinuxCNC 2.9 limits velocity ({x.max_velocity_mm_s:g} mm/s) and acceleration "
           f"({x.max_accel_mm_s2:g} mm/s^2) per axis but not jerk: its |a| steps within one servo period "
           f"(|j| up to 2 A / dt = {2 * x.max_accel_mm_s2 / config.timing.period_s:.3g} mm/s^3); "
           f"ours holds |j| <= {x.max_jerk_mm_s3:g} mm/s^3."]
    for c in both:
        if c.linuxcnc.max_deviation_mm - c.linuxcnc.max_deviation_anywhere_mm > TAG_CHECK_MM:
            out.append(f"check: {c.bench.name}: LinuxCNC deviation by program line "
                       f"{c.linuxcnc.max_deviation_mm:.5f} mm, to the nearest geometry anywhere "
                       f"{c.linuxcnc.max_deviation_anywhere_mm:.5f} mm")
    out += [f"LinuxCNC failed on {c.bench.name}: {c.linuxcnc_error}" for c in rows if c.linuxcnc_error]
    return out


def render_by_line(rows: list[Comparison]) -> list[str]:
    """Where each planner spends the nest's time, by what its lines do (`line_kinds`; a sample
    counts to the program line it carries, so time near a corner may go to either neighbour)."""
    out = []
    for c in rows:
        if c.linuxcnc is None or not c.bench.name.startswith("nest"):
            continue
        ours, theirs = c.ours.extra["by_line_kind_s"], c.linuxcnc.extra["by_line_kind_s"]
        out += [f"{c.bench.name}: time by line kind", f"{'lines':<12}{'ours s':>10}{'LCNC s':>10}{'ours - LCNC':>13}"]
        for kind in LINE_KINDS:
            out.append(f"{kind:<12}{ours[kind]:10.2f}{theirs[kind]:10.2f}{ours[kind] - theirs[kind]:+13.2f}")
        delta_ms = 1000.0 * (np.array(c.ours.extra["by_part_s"]) - np.array(c.linuxcnc.extra["by_part_s"]))[1:]
        if len(delta_ms):
            worst = np.argsort(delta_ms)[::-1][:3] + 1
            out.append(f"by part (from one rapid to the next, {len(delta_ms)} parts): ours - LCNC min {delta_ms.min():+.0f} ms, "
                       f"median {np.median(delta_ms):+.0f} ms, max {delta_ms.max():+.0f} ms; ours slower on "
                       f"{int((delta_ms > 0).sum())}; the most: parts {', '.join(str(int(k)) for k in worst)}")
    return out


def to_json(rows: list[Comparison], config: MachineConfig, linuxcnc: str, wall_s: float) -> dict[str, Any]:
    keys = ("max_velocity_mm_s", "max_accel_mm_s2", "max_jerk_mm_s3", "travel_min_mm", "travel_max_mm")
    limits = {ax: {k: getattr(config.axis[ax], k) for k in keys} for ax in AXES}
    programs = [{"name": c.bench.name, "tolerance_mm": c.tolerance_mm, "start_mm": c.start_mm, "ratio": c.ratio,
                 "jerk_bound_s": c.jerk_bound_s, "corner_bound_s": c.corner_bound_s,
                 "linuxcnc_beyond_jerk_bound": c.beyond_jerk,
                 "ours": dataclasses.asdict(c.ours),
                 "linuxcnc": dataclasses.asdict(c.linuxcnc) if c.linuxcnc else None,
                 "linuxcnc_error": c.linuxcnc_error or None, "gcode": c.bench.text} for c in rows]
    return {"machine_file": str(MACHINE_FILE), "period_s": config.timing.period_s, "limits": limits,
            "linuxcnc": linuxcnc, "wall_time_s": wall_s, "programs": programs}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="run a few programs only")
    ap.add_argument("--json", type=Path, metavar="OUT", help="write every figure here")
    ap.add_argument("--only", metavar="PREFIX", default="",
                    help="run only the programs whose name starts so ('kerf': the nest compensated by the controller)")
    ap.add_argument("--bounds", action="store_true",
                    help="print only each program's feed and jerk-limited bounds (`feed_bound_s`, `jerk_bound_s`) and exit")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    config = load_machine(MACHINE_FILE, NO_JET_DELAYS)
    if args.bounds:
        for bench in benches():
            program, _ = interpret_from_start(bench.text, config)
            corners = "" if bench.polyline is None else \
                f"   with its corners {corner_bound_s(bench, float(program.segments['tolerance'].max()), config):9.3f} s"
            print(f"{bench.name:<34} feed bound {feed_bound_s(program, config):9.3f} s   "
                  f"jerk-limited bound {jerk_bound_s(program, config):9.3f} s{corners}")
        return 0
    available, reason = linuxcnc_sim.available()
    rows: list[Comparison] = []
    with tempfile.TemporaryDirectory(prefix="linuxcnc_compare-") as tmp:
        chosen = benches(kerf=args.only.startswith("kerf"))
        for bench in (b for b in chosen if (b.quick or not args.quick) and b.name.startswith(args.only)):
            try:
                rows.append(compare(bench, config, Path(tmp), available))
            except linuxcnc_sim.LinuxCNCUnavailable as exc:
                available, reason = False, str(exc)
                rows.append(compare(bench, config, Path(tmp), available))
            print(f"  {bench.name}: done ({time.monotonic() - t0:.0f} s)", file=sys.stderr)
    wall_s = time.monotonic() - t0
    peer = reason if available else f"LinuxCNC (unavailable: {reason})"
    print(f"ours vs {peer}; same limits: {MACHINE_FILE.name}, period {config.timing.period_s * 1e3:g} ms, "
          "start at each program's first point")
    print("\n".join([*render_targets(rows), "", *render_peaks(rows), "", *render_summary(rows, config), "",
                     *render_by_line(rows)]))
    print(f"ran in {wall_s:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(to_json(rows, config, reason, wall_s), indent=1))
        print(f"wrote {args.json}")
    return 1 if any(c.linuxcnc_error for c in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
