"""A program as the planner runs it: sections of motion and the zero-velocity pauses between them.

A section is a stretch of path the head runs without stopping. It ends wherever the head
must stand still: where the jet or the machine outputs switch (they switch at zero
velocity, exactly at the segment boundary), at a dwell, at a program stop (M0, M1, M60), at
a corner that is neither blended nor tangent, and at the end. Between two sections sits
what happens at the stop: the jet opening (its delay and the pierce dwell), the jet closing
(its delay), a dwell, a program stop waiting for cycle start. Numbered outputs (M62/M63)
switch at their segment boundary without a stop where the path is tangent there.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Iterator

import numpy as np

from gcode.canon import ARC, DWELL, LINE, RAPID
from gcode.program import Program

from ..config import MachineConfig
from ..data.fifo import SetpointFlag
from .geometry import PathArrays
from .limits import (
    GEOMETRY_JERK_SHARE, GEOMETRY_JERK_SHARES, KINK_MAX_RAD, MAX_SMOOTHING_SAMPLES, SectionLimits, arc_pieces_for_caps,
    path_caps, section_limits, section_zones, smoothing_for,
)
from .profile import Zones, rough_duration_s
from .path import Element, blend_corners, blends, distance_to, iter_elements

if TYPE_CHECKING:
    from .overlap import CornerOverlap
    from .quality import CutPlan

Z_RATE_STEP = 1e-9  # two elements whose dz/ds differ by more meet at a stop (rounding alone stays under it)
RUN_PIECE = 64  # a run of elements is made into sections in pieces of at least this many (`iter_steps`)
REST_SAMPLES = 3  # a section ends with this many samples at rest: its end and the next one's start
# then never meet in one third difference (the jerk the drives see)
JERK_RESERVE = 0.03  # share of the axes' jerk a straight move leaves unused at a corner overlap (`_jerk_reserves`)
JERK_RESERVE_SHARED = 0.25  # ... where one of the two moves takes at most this share of the axis they share
FOLD_COARSE_STRIDES = (64, 8)  # a folded corner's candidates ruled out on every 64th, then every 8th sample first
FOLD_CANDIDATES = 8  # points tried for a folded corner (`_fold_small_arcs`), between the arc and where its lines meet
FOLD_SAMPLE_SHARE = 0.25  # a folded corner's lines are sampled every this share of P (`_fold_strays`) ...
FOLD_STRAY_SHARE = 0.85  # ... and keep within this share of P of the programmed path where sampled (between
# samples they may stray half a step more) where the corner is a stop (`_fold_small_arcs`) ...
FOLD_TURN_SHARE = 0.85  # ... and within this share where it may be blended (`_fold_small_turns`)
FOLD_TURN_MAX_RAD = 2.6  # a folded corner turns at most this much (149 degrees; nearer a reversal the lines
# would meet far off the arc): a stop in place of the crawl through the arc even where no overlap passes it
FOLD_TILT_MAX_RAD = KINK_MAX_RAD / 4.0  # a line of a run tilted to a folded corner turns at most this much
SHARP_TURN_RAD = math.radians(120.0)  # a corner overlap turning at least this much eases both moves' ramps ...
SHARP_TURN_ACCEL_SHARE = 0.7  # ... to this share of their acceleration (`_eased_sharp_corners`) ...
RAMP_TRIED_CAPS = 1.5  # ... tried where neither ramp takes longer than this many times the overlap's cap
CORNER_MOVE_SHORTEST = 4.0  # a corner is moved (`_move_stop_corners`) only where both lines are at least
# this many times as long as the move

AXIS_AVERAGE_STEPS = 8  # a section held back by its curves tries axis averages longer by 1/this of its own ...
AXIS_AVERAGE_MOST = 2  # ... in turn, up to this many times its own (`_longer_averages`)
CURVE_BINDS = 1.0 - 1e-9  # a curve's cap under this share of its feed and axis speed holds the section back

MEMO_RUNS = 1024  # runs a program's timing remembers (`RunMemo`): a nest of up to this many different parts
MEMO_DECIMALS = 6  # a remembered run's coordinates, relative to its start, rounded to this many decimals of a mm
MEMO_SHORTEST_MM = 1e-3  # a run with an element shorter than this is never remembered (its direction is rounding)

STOP_KINDS = {"stop": "M0 program stop", "optional_stop": "M1 optional stop", "pallet": "M60 pallet change"}


@dataclass
class Section:
    """One stretch of motion between two stops."""

    elements: list[Element]
    path: PathArrays
    limits: SectionLimits
    offset_mm: float  # program path length before this section
    flags: np.ndarray  # per element: setpoint output bits
    segment: np.ndarray  # per element: program segment index
    line: np.ndarray  # per element: source line
    messages: list[tuple[float, str, int]] = field(default_factory=list)  # (arc length, text, line)
    # the cutting model's cap on the speed through the corner at its end where a corner overlap
    # passes it instead of stopping (`overlap.py`): its jet-lag cap for the turn (inf: none)
    end_cap_mm_s: float = math.inf
    zone_cache: dict = field(default_factory=dict)  # its zones per setting of the controls (`zones`)
    # the share of its acceleration it ramps at next to its start and its end, where a sharp corner
    # overlap joins it to its neighbour (`_eased_sharp_corners`; 1: its own)
    eased_ends: tuple[float, float] = (1.0, 1.0)
    # the elements as the run gave them, before long arcs were cut into pieces for their caps
    # (`arc_pieces_for_caps`), while its limits are still being chosen (`_sections_of`)
    whole: list[Element] | None = None

    def zones(self, holding: bool, override: float, rapid_override: float, over_feed: bool) -> Zones:
        """The whole section's caps and accelerations under these controls, made once per setting
        (`limits.section_zones`; `over_feed`: the motion may run over its feeds, an override above
        100 % since the section began); shared by every stream of the section, from any thread."""
        key = (holding, override, rapid_override, over_feed)
        whole = self.zone_cache.get(key)
        if whole is None:
            whole = section_zones(self.path, self.limits, 0.0, self.length_mm, *key)
            if not holding and self.eased_ends != (1.0, 1.0):  # a hold brakes at the whole acceleration
                whole = _eased_zones(whole, self.eased_ends, self.limits)
            self.zone_cache[key] = whole
        return whole

    @property
    def start(self) -> tuple[float, float, float]:
        return self.elements[0].start

    @property
    def end(self) -> tuple[float, float, float]:
        return self.elements[-1].end

    @property
    def length_mm(self) -> float:
        return self.path.total_mm


@dataclass
class Pause:
    """Time spent standing still between sections."""

    kind: str  # "pierce", "jet_off", "dwell", "program_stop"
    seconds: float
    flags: int  # output bits while it lasts
    position: tuple[float, float, float]
    segment: int
    line: int
    text: str = ""


Step = Section | Pause


class RunMemo:
    """What a program's timing learnt of its runs of elements between two pauses, by their shape.

    A CAM nest cuts the same part again and again at other places: its run of elements (lead-in,
    contour, lead-out between the pierce and the jet going off) has the same shape, feeds and
    tolerances each time, only moved, and so the same sections, profile and servo periods. The
    timing (`steps.ProgramTiming`) makes such a run's sections once: `iter_steps` keys each run
    between two pauses by its elements relative to its first point (`run_key`), and where the key is
    known yields the ticks already timed (`KnownRun`) instead of making the sections again; a run
    is kept under its key in each orientation that times it alike (`run_keys`), so a copy turned or
    mirrored is known too. Only runs
    between pauses are kept: no corner overlap joins them to their neighbours, so their ticks are
    theirs alone. Holds at most `MEMO_RUNS` runs, the oldest dropped first."""

    def __init__(self, size: int = MEMO_RUNS) -> None:
        self.size = size
        self.runs: dict[tuple, tuple[tuple[int, ...], float]] = {}
        self.kept: deque[tuple[tuple, ...]] = deque()  # each run's keys, the oldest first
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple) -> tuple[tuple[int, ...], float] | None:
        known = self.runs.get(key)
        if known is None:
            self.misses += 1
        else:
            self.hits += 1
        return known

    def put(self, keys: tuple[tuple, ...], ticks: tuple[int, ...], length_mm: float) -> None:
        """Remember a run's ticks under its key in each orientation that times it alike (`run_keys`)."""
        if len(self.kept) >= self.size:
            for key in self.kept.popleft():
                self.runs.pop(key, None)
        entry = (ticks, length_mm)
        for key in keys:
            self.runs[key] = entry
        self.kept.append(keys)


@dataclass
class RunStart:
    """Marks the sections that follow, up to the next pause, as a run the memo keeps once timed."""

    keys: tuple[tuple, ...]  # its key in each orientation that times it alike (`run_keys`)
    memo: RunMemo


@dataclass
class KnownRun:
    """A run timed before at another place (`RunMemo`): its sections' servo periods and path length."""

    ticks: tuple[int, ...]
    length_mm: float


# The signed permutations of X and Y a part may be turned or mirrored by without changing its
# timing: (swap, sx, sy): (x, y) -> (sx * x, sy * y), after taking y for x and x for y if `swap`.
# A mirror (one sign change, or a swap with none or two) runs its arcs the other way round.
_SIGNS = ((1, 1), (-1, 1), (1, -1), (-1, -1))
TURNS_SIGNED = tuple((False, sx, sy) for sx, sy in _SIGNS)  # any machine: each axis keeps its limits
TURNS_SWAPPED = TURNS_SIGNED + tuple((True, sx, sy) for sx, sy in _SIGNS)  # X and Y alike


def run_key(run: list[Element], cut: "CutPlan | None" = None, config: MachineConfig | None = None) -> tuple | None:
    """What a run's sections and their ticks depend on, wherever it is: per element its kind, its
    points relative to the run's first (rounded to `MEMO_DECIMALS`), direction and turns, feed,
    tolerance, outputs and the cutting model's quality there. None for a run never remembered: one
    with an element so short that its direction is rounding, or (given the machine `config`) one
    with a point within its tolerance of a travel end, where a corner may be left where it is that
    elsewhere would be moved (`_move_stop_corners`)."""
    parts = _run_parts(run, cut, config)
    return None if parts is None else _turned_key(run, *parts, TURNS_SIGNED[0])


def run_keys(run: list[Element], cut: "CutPlan | None" = None, config: MachineConfig | None = None) -> tuple | None:
    """The run's key (`run_key`) in every orientation that times it alike, its own first. The
    planner's limits are per axis, so a run mirrored in X or Y or turned by half a turn is timed
    alike; on a machine whose X and Y have the same limits (`config`), so is one turned by a quarter
    or mirrored across a diagonal (a nest's left and right parts, parts turned to fit)."""
    parts = _run_parts(run, cut, config)
    return None if parts is None else _keys_of(run, parts, config)


def _keys_of(run: list[Element], parts: tuple[list, list], config: MachineConfig | None) -> tuple[tuple, ...]:
    turns = TURNS_SWAPPED if config is not None and _xy_alike(config) else TURNS_SIGNED
    return tuple(_turned_key(run, *parts, turn) for turn in turns)


def _run_parts(run: list[Element], cut: "CutPlan | None", config: MachineConfig | None) -> tuple[list, list] | None:
    """Per element its points relative to the run's first, rounded, and the rest of its key."""
    ox, oy, oz = run[0].start
    d = MEMO_DECIMALS
    points, rest = [], []
    for e in run:
        if e.length_mm < MEMO_SHORTEST_MM:
            return None
        if config is not None and not all(_inside_travel(config, axis, q, e.tolerance_mm)
                                          for p in (e.start, e.end) for axis, q in zip("xy", p)):
            return None
        (sx, sy, sz), (ex, ey, ez), c = e.start, e.end, e.center
        # rounded once: a sign change or a swap of rounded values is the rounding of the turned ones
        points.append((round(sx - ox, d), round(sy - oy, d), round(ex - ox, d), round(ey - oy, d),
                       None if c is None else (round(c[0] - ox, d), round(c[1] - oy, d))))
        rest.append((round(sz - oz, d), round(ez - oz, d), e.turns, e.feed_mm_s, e.tolerance_mm, e.jet, e.aux,
                     e.outputs, e.blend, cut.quality_of(e.segment) if cut is not None else 0))
    return points, rest


def _turned_key(run: list[Element], points: list, rest: list, turn: tuple[bool, int, int]) -> tuple:
    swap, fx, fy = turn
    mirrored = (fx * fy < 0) != swap
    key = []
    for e, (sx, sy, ex, ey, c), more in zip(run, points, rest):
        if swap:
            sx, sy, ex, ey, c = sy, sx, ey, ex, None if c is None else (c[1], c[0])
        key.append((e.kind, fx * sx, fy * sy, fx * ex, fy * ey, None if c is None else (fx * c[0], fy * c[1]),
                    e.cw != mirrored if e.kind == ARC else e.cw, *more))
    return tuple(key)


def _xy_alike(config: MachineConfig) -> bool:
    """Whether X and Y have the same limits, so that swapping them changes no plan."""
    x, y = config.axis.get("x"), config.axis.get("y")
    return x is not None and y is not None and all(
        getattr(x, k) == getattr(y, k) for k in ("max_velocity_mm_s", "max_accel_mm_s2", "max_jerk_mm_s3"))


def output_flags(jet: bool, aux: int, outputs: int) -> int:
    """Setpoint output bits: the jet, the M-code map's outputs (abrasive, aux1..) and M62-M65 P0..P3."""
    bits = int(SetpointFlag.JET_ON) if jet else 0
    bits |= (int(aux) << 1) & 0x3E
    bits |= (int(outputs) & 0xF) << 2
    return bits


def pierce_dwell_s(config: MachineConfig, cut: "CutPlan | None") -> float:
    """How long the jet stands at a pierce after its on delay: the cutting job's pierce time (its
    material's chart, in either mode: it is the sheet's, not the feed's), else the machine file's
    `[jet] pierce_dwell_s`."""
    return float(cut.model.pierce_s) if cut is not None else float(config.jet.pierce_dwell_s)


def program_steps(program: Program, config: MachineConfig, cut: "CutPlan | None" = None) -> list[Step]:
    """The program's sections and pauses, in order, all of them (`iter_steps` makes them as needed)."""
    return list(iter_steps(program, config, cut))


def iter_steps(program: Program, config: MachineConfig, cut: "CutPlan | None" = None,
               first: int = 0, end: int | None = None,
               memo: RunMemo | None = None) -> Iterator[Step | RunStart | KnownRun]:
    """The program's sections and pauses, in order, each made when it is asked for: only the run of
    elements between two hard stops (jet or outputs switching, a dwell, a program stop) is held
    while its sections are made, so the cost and memory of the next step do not grow with the
    program. A long run is made in pieces of about `RUN_PIECE` elements, each ending at a corner
    that is a section boundary whatever the planner decides (no blend can span it, the head
    stops there: `_boundary`), so the pieces' sections are exactly the whole run's. `cut`: the
    cutting model's speed caps (`quality.py`), taken as the feed wherever they are lower, in its
    "quality" mode. `first`, `end`: only the steps of segments first..end - 1; from a pierce
    (`pierce_boundaries`) to the next, they are exactly the whole program's steps there (the
    program's timing is made in such pieces at once, `steps.ProgramTiming`). `memo`: for the
    timing only, runs between two pauses timed before at another place come as `KnownRun`, and
    those to be timed are announced by a `RunStart` (`RunMemo`)."""
    pierce_s = pierce_dwell_s(config, cut)
    if cut is not None and not cut.applies:
        cut = None
    stops = {m.segment: m for m in program.messages if m.kind in STOP_KINDS}
    notes = {}
    for m in program.messages:
        if m.kind in ("message", "tool"):
            notes.setdefault(m.segment, []).append((m.text, m.line))
    offset = 0.0
    run: list[Element] = []
    jet = config.jet
    made_any = False
    where_last = None  # where the last step made ends

    after_pause = True  # nothing yielded yet, or a pause last: no corner overlap reaches back past it

    def close_run(then_pause: bool) -> Iterator[Step]:
        """The run's sections; `then_pause`: what comes next is a pause or the end."""
        nonlocal offset, run, made_any, where_last, after_pause
        if run:
            parts = _run_parts(run, cut, config) if memo is not None and after_pause and then_pause else None
            key = _turned_key(run, *parts, TURNS_SIGNED[0]) if parts is not None else None
            known = memo.get(key) if key is not None else None
            if known is not None:
                ticks, length_mm = known
                offset += length_mm
                if ticks:
                    made_any, where_last, after_pause = True, run[-1].end, False
                    yield KnownRun(ticks, length_mm)
            else:
                if key is not None:
                    yield RunStart(_keys_of(run, parts, config), memo)
                for section in _sections_of(run, config, offset, notes, cut):
                    offset += section.length_mm
                    made_any, where_last, after_pause = True, section.end, False
                    yield section
        run = []

    def pause(p: Pause) -> Pause:
        nonlocal made_any, where_last, after_pause
        made_any, where_last, after_pause = True, p.position, True
        return p

    last = None
    for e in iter_elements(program.segments if end is None else program.segments[:end], first):
        if e.segment in stops and (run or made_any):
            yield from close_run(True)
            where = where_last if where_last is not None else e.start
            m = stops.pop(e.segment)
            yield pause(Pause("program_stop", 0.0, _flags(last) if last else 0, where, e.segment, m.line, STOP_KINDS[m.kind]))
        # the jet and outputs switch first, a dwell programmed after M3 (the CAM pierce) included:
        # the on delay and pierce dwell always come before what the program adds
        if last is not None and (last.jet, last.aux) != (e.jet, e.aux):
            yield from close_run(last.jet != e.jet)  # the jet switching is a pause; an output alone is not
            where = e.start
            if e.jet and not last.jet:
                yield pause(Pause("pierce", jet.on_delay_s + pierce_s, _flags(e), where, e.segment, e.line, "jet on, pierce"))
            elif last.jet and not e.jet:
                yield pause(Pause("jet_off", jet.off_delay_s, _flags(e), where, e.segment, e.line, "jet off"))
        elif last is None and e.jet:
            yield pause(Pause("pierce", jet.on_delay_s + pierce_s, _flags(e), e.start, e.segment, e.line, "jet on, pierce"))
        elif e.kind != DWELL and len(run) >= RUN_PIECE and _boundary(run[-1], e):
            yield from close_run(False)
        last = e
        if e.kind == DWELL:
            yield from close_run(True)
            yield pause(Pause("dwell", e.dwell_s, _flags(e), e.start, e.segment, e.line, f"G4 P{e.dwell_s:g}"))
            continue
        run.append(e)
    yield from close_run(True)
    if last is not None and last.jet:
        where = where_last if where_last is not None else last.end
        yield Pause("jet_off", jet.off_delay_s, 0, where, last.segment, last.line, "jet off at the end")


def pierce_boundaries(program: Program) -> np.ndarray:
    """Segments at which the program may be cut into pieces whose steps (`iter_steps` with `first`
    and `end`) are exactly the whole program's: each opens the jet after a segment that had it
    closed, both of them elements of the path (not zero-length moves, which make none), and no
    program stop there. The whole program's steps change there anyway: the run before ends, and
    the pierce's pause begins the next piece."""
    seg = program.segments
    if len(seg) < 2:
        return np.zeros(0, dtype=np.int64)
    moves = np.any(seg["start"] != seg["end"], axis=1) | (seg["kind"] == ARC) | (seg["kind"] == DWELL)
    jet = seg["jet"]
    at = np.flatnonzero(jet[1:] & ~jet[:-1] & moves[1:] & moves[:-1]) + 1
    stops = np.array(sorted(m.segment for m in program.messages if m.kind in STOP_KINDS), dtype=np.int64)
    return at[~np.isin(at, stops)] if len(stops) else at


def _boundary(a: Element, b: Element) -> bool:
    """The corner a -> b ends a section in any case: no blend there, and the head stops."""
    return not blends(a, b) and _stops_between(a, b)


def move_steps(
    start: tuple[float, float, float], end: tuple[float, float, float], feed_mm_s: float, config: MachineConfig
) -> list[Step]:
    """A single straight move at rest at both ends (jog, go-to): feed_mm_s, or the axis limits when inf."""
    kind = RAPID if feed_mm_s == math.inf else LINE
    e = Element(kind, tuple(start), tuple(end), None, False, 0, feed_mm_s, 0.0, False, 0, 0, 0, 0)
    return [_section([e], config, 0.0, {})] if e.length_mm > 0.0 else []


def _flags(e: Element) -> int:
    return output_flags(e.jet, e.aux, e.outputs)


def _sections_of(run: list[Element], config: MachineConfig, offset: float, notes: dict, cut=None) -> list[Section]:  # noqa: ANN001
    """Sections of a run of elements between hard stops, each corner blended or stopped at,
    whichever is faster."""
    corners: dict = {}  # each corner's blend, made once for both passes
    folds: dict = {}  # each stop corner's fold (`_fold_small_arcs`), made once for every pass
    run = _fold_small_turns(run, config)
    first = _split(blend_corners(run, memo=corners), config, offset, notes, choose_jerk=False, cut=cut, folds=folds)
    stops, kept = _corners_to_stop(first, config)
    if stops:
        out = _split(blend_corners(run, frozenset(stops), corners), config, offset, notes, cut=cut, folds=folds)
        # the gentle corners kept beside sharp ones, weighed again with those a stop: a stop after all
        # where their own caps say so
        again = _corners_to_stop(out, config, only=kept)[0] if kept else set()
        if again:
            stops |= again
            out = _split(blend_corners(run, frozenset(stops), corners), config, offset, notes, cut=cut, folds=folds)
    else:
        out = []
        for section in first:  # the same sections: only the share of jerk (and the axis average) still to choose
            limits, seconds = _fastest_limits(
                section.path, section.limits.v_feed, section.limits.rapid, min(e.tolerance_mm for e in section.elements),
                any(e.blend for e in section.elements), config, known=section.limits,
            )
            elements, path, limits = _longer_averages(section.whole, config, cut, section.elements, section.path, limits,
                                                      seconds)
            if path is section.path:
                section.limits = limits
            else:
                ends = section.end_cap_mm_s
                section = _assembled(elements, path, limits, section.offset_mm, notes)
                section.end_cap_mm_s = ends
            out.append(section)
    for section in out:  # chosen: what the limits were made from is not kept in the window ahead
        section.whole = None
        if section.limits.caps is not None:
            section.limits = dataclasses.replace(section.limits, caps=None)
    _eased_sharp_corners(out, config)  # with the limits the sections run with
    return out


def _corners_to_stop(sections: list[Section], config: MachineConfig,
                     only: set[int] | None = None) -> tuple[set[int], set[int]]:
    """Segments whose corner is faster to stop at than to blend, and the gentle ones kept (below);
    `only`: weigh only these corners, each by itself.

    A blend's speed cap v_b holds for the averages' span T_ext on either side of it, so the
    head crawls through the corner for about 2 T_ext; a stop costs the averages' settling of
    a straight section instead. Against passing at v (the neighbours' speed, or what their
    length allows from a stop), with r = v_b / v:

        blend ~ 2 T_ext (1 - r) + v (1 - r)^2 / A        stop ~ T_settle + v / A

    each with the acceleration (and so the path average's span in T_ext and T_settle) the
    sections get at that speed (`limits.smoothing_for`).

    The averages spread a sharp blend's cap over the blends within their span: a gentle corner
    next to a sharp one (a lead-in's corner, then the first chords of a round part) got the sharp
    one's crawl and was made a stop as well. A blend whose own curvature allows the neighbours'
    speed (`_blend_own_cap`) is kept when a sharp corner to be stopped at lies within that span,
    and weighed again once that corner is a stop (`_sections_of`, `only`): what else was near it
    (a kerf compensation's arc, another corner) may still make it a stop.
    """
    straight = smoothing_for(config, 0.0, False, False, False)
    dt, accel, jerk = straight.dt, straight.accel_cap, straight.jerk_path
    out: set[int] = set()
    kept: set[int] = set()
    j_geometry = jerk * GEOMETRY_JERK_SHARE
    a_normal = config.planner.arc_normal_share * accel
    for section in sections:
        lim = section.limits
        # the neighbours' speed without the blend: a programmed arc's cap already carries the
        # blend's curvature (its window reaches it), which is the cost weighed here, not a given;
        # its feed stands for it
        cap = np.minimum(lim.v_hard, lim.v_feed)
        programmed_arc = section.path.arc & ~np.array([e.blend for e in section.elements])
        near = np.minimum(np.where(programmed_arc, np.inf, lim.v_hard), lim.v_feed)
        # the averages' span and acceleration as the path average alone would make them: a section
        # whose axis average holds its jerk (`smoothing_for`) may still be made so once its share
        # of jerk is chosen (`_fastest_limits`), and its blends then crawl that long
        a_blend = lim.smoothing.alone[1]
        span_s = 2.0 * lim.smoothing.alone_extension_s
        elements = section.elements
        chosen = []  # (where along the section, the neighbours' speed, gentle by itself, the blend's segment)
        for k in range(1, len(elements) - 1):
            if not elements[k].blend or (only is not None and elements[k].segment not in only):
                continue
            shortest = min(_whole_length(elements, k, -1), _whole_length(elements, k, 1)) + elements[k].length_mm / 2.0
            v = min(near[k - 1], near[k + 1], math.sqrt(accel * shortest))
            r = min(cap[k] / v, 1.0) if v > 0.0 else 1.0
            blend_s = span_s * (1.0 - r) + v * (1.0 - r) ** 2 / a_blend
            # the two straight sections a stop makes, as `smoothing_for` would make them at that speed
            a_stop = min(accel, math.sqrt(2.0 * v * jerk)) if v > 0.0 else accel
            settle_s = (max(1, math.ceil(a_stop / (jerk * dt) - 1e-9)) + straight.n_axis + REST_SAMPLES) * dt
            if settle_s + (v / a_stop if v > 0.0 else 0.0) < blend_s:
                gentle = only is None and _blend_own_cap(elements[k], a_normal, j_geometry, span_s) >= v
                chosen.append((float(section.path.s0[k]) + elements[k].length_mm / 2.0, v, gentle, elements[k].segment))
        # a gentle blend whose cap is a sharp one's nearby, spread by the windows: with the sharp
        # corner a stop, the gentle one runs at its own speed (a lead-in's corner and the next chord's)
        sharp = [s for s, _, gentle, _ in chosen if not gentle]
        for s, v, gentle, segment in chosen:
            (kept if gentle and any(abs(s - t) <= v * span_s for t in sharp) else out).add(segment)
    return out, kept


def _blend_own_cap(blend: Element, a_normal: float, j_geometry: float, span_s: float) -> float:
    """The speed a corner blend's own curvature allows (radius R: its normal acceleration, the
    curvature's jerk v^3/R^2, and the step of normal acceleration v^2/R taken within the averages'
    span), however slow the corners near it are."""
    radius = math.hypot(blend.start[0] - blend.center[0], blend.start[1] - blend.center[1])
    return min(math.sqrt(a_normal * radius), (j_geometry * radius * radius) ** (1.0 / 3.0),
               math.sqrt(j_geometry * span_s * radius))


def _whole_length(elements: list[Element], k: int, step: int) -> float:
    """Length of the element beside a blend at k (step -1: before it, +1: after it), all of it
    where it is an arc cut into pieces (`arc_pieces_for_caps`: the same segment, side by side)."""
    i = k + step
    segment, total = elements[i].segment, 0.0
    while 0 <= i < len(elements) and not elements[i].blend and elements[i].segment == segment:
        total += elements[i].length_mm
        i += step
    return total


def _fastest_limits(
    path: PathArrays, feed, rapid, tolerance: float, blended: bool, config: MachineConfig, choose: bool = True,
    known: SectionLimits | None = None, jerk_reserve: float = 0.0, n_axis: int | None = None,
) -> tuple[SectionLimits, float]:
    """The section's limits under the share of jerk for curvature that runs it soonest: curves
    want more of it (higher speeds on arcs), speed changes want less (shorter ramps). The
    estimate ranks the candidates by the profile over the elements' own caps (unwidened); it is
    returned with them (inf where no share was chosen).
    `known`: the limits under the default share, already made (a straight section's answer);
    `jerk_reserve`: the share of the jerk the section leaves unused (`_jerk_reserves`); `n_axis`:
    its axis average's samples (`smoothing_for`)."""
    if known is not None:
        if known.smoothing.geometry_share == 0.0:
            return known, math.inf  # straight: no share to choose
        jerk_reserve = known.smoothing.jerk_reserve
    best, best_s = None, math.inf
    caps = known.caps if known is not None else None
    for share in GEOMETRY_JERK_SHARES if choose else (GEOMETRY_JERK_SHARE,):
        if known is not None and share == GEOMETRY_JERK_SHARE:
            lim = known
        else:
            caps = caps or path_caps(path, config)
            lim = section_limits(path, feed, rapid, tolerance, blended, config, share, caps, jerk_reserve, n_axis)
        if not choose or lim.smoothing.geometry_share == 0.0:  # straight: no share to choose
            return lim, math.inf
        sm = lim.smoothing
        zones = Zones(path.s0, lim.v_hard, lim.v_feed, lim.accel_for(False))  # as timed: at 100 %
        seconds = rough_duration_s(zones) + (sm.n_path + sm.n_axis) * sm.dt
        if seconds < best_s:
            best, best_s = lim, seconds
    return best, best_s


def _split(path: list[Element], config: MachineConfig, offset: float, notes: dict, choose_jerk: bool = True,
           cut=None, folds: dict | None = None) -> list[Section]:  # noqa: ANN001 - a CutPlan
    """Cut a blended run of elements at every corner that is neither tangent nor a small kink."""
    motion = [e for e in path if e.kind != DWELL and e.length_mm > 1e-9]  # blends may leave a line of length 0
    groups: list[list[Element]] = []
    start = 0
    for i in range(1, len(motion) + 1):
        if i == len(motion) or _stops_between(motion[i - 1], motion[i]):
            groups.append(motion[start:i])
            start = i
    groups = _fold_small_arcs(groups, config, {} if folds is None else folds)
    _move_stop_corners(groups, config)
    out: list[Section] = []
    for elements, reserve in zip(groups, _jerk_reserves(groups, config)):
        out.append(_section(elements, config, offset, notes, choose_jerk, cut, reserve))
        offset += out[-1].length_mm
    if cut is not None:
        for a, b in zip(out[:-1], out[1:]):
            a.end_cap_mm_s = _overlap_cap(a.elements[-1], b.elements[0], cut)
    return out


def _eased_sharp_corners(sections: list[Section], config: MachineConfig) -> None:
    """Ease both moves' ramps at a sharp corner that a corner overlap may pass (`overlap.py`), where
    that passes it sooner.

    Where the path turns back sharply the two moves run largely against each other on an axis:
    the last one's braking jerk (-J along u_a as it starts to slow down) and the next one's first
    (+J along u_b, against u_a there) add on it, so at their own jerk the next move may only start
    once the last one has braked about halfway; the overlap is held by that sum, not by P (a
    contour's end into a lead-out turned back at 45 degrees, at F2400: 21 samples). Ramping both at
    `SHARP_TURN_ACCEL_SHARE` of their acceleration (the jerk through the averages follows it) lets
    them overlap until P holds them instead (33 samples there), for ramps about a fifth longer
    (3 samples each). Whether that pays depends on what holds the overlap and on what the
    section does near its end (at F4800 the overlap nears its cap, `[planner] corner_overlap_ms`,
    at its own jerk, and a circle's kinks near the end slow down and speed up again at the eased
    acceleration): so the corner is tried both ways, on the stretches of the two sections next
    to it (`_stretch_near`: long enough that their own ends far from the corner do not reach it),
    and eased only where the sum of their samples less the overlap is smaller. Only turns of at
    least `SHARP_TURN_RAD` are tried (at a turn a little over a right angle P holds the overlap
    anyway), only between feed moves (a rapid's ramps are long), and only where neither move's
    ramp takes longer than `RAMP_TRIED_CAPS` times the overlap's cap (the overlap can grow by less
    than its cap; a zigzag at 30 m/min, 110 ms ramps, is not tried, one at 12 m/min is and is
    left as it was). A hold brakes at the whole acceleration (`Section.zones`). The choice is made
    here, once per run, from the sections alone, so the timing and the streamed run share it; the
    overlap's own check decides, as everywhere, how far the eased moves are added."""
    from .overlap import CornerOverlap  # it checks sections' sums

    cap_s = config.planner.corner_overlap_ms / 1000.0
    if cap_s <= 0.0:
        return
    corners = CornerOverlap.of(config)
    for a, b in zip(sections[:-1], sections[1:]):
        ea, eb = a.elements[-1], b.elements[0]
        if ea.kind == RAPID or eb.kind == RAPID or not overlap_may_apply(ea, eb):
            continue
        if abs(_turn_rad(ea.direction_at_end(), eb.direction_at_start())) < SHARP_TURN_RAD:
            continue
        if _ramp_s(a, -1) > RAMP_TRIED_CAPS * cap_s or _ramp_s(b, 0) > RAMP_TRIED_CAPS * cap_s:
            continue
        if _eased_corner_samples(a, b, corners, SHARP_TURN_ACCEL_SHARE) < _eased_corner_samples(a, b, corners, 1.0):
            a.eased_ends = (a.eased_ends[0], SHARP_TURN_ACCEL_SHARE)
            b.eased_ends = (SHARP_TURN_ACCEL_SHARE, b.eased_ends[1])


def _speed_at(limits: SectionLimits, k: int) -> float:
    """The fastest element k of a section runs at 100 % (its feed, or its caps where lower)."""
    return float(min(limits.v_feed[k], limits.v_hard[k]))


def _ramp_s(section: Section, k: int) -> float:
    """How long the section's ramp between rest and its speed at element k takes (its acceleration
    there, through the average that holds its jerk)."""
    lim = section.limits
    return _speed_at(lim, k) / float(lim.accel_for(False)[k]) + lim.smoothing.turn_samples * lim.smoothing.dt


def _eased_corner_samples(a: Section, b: Section, corners: "CornerOverlap", share: float) -> int:
    """Servo periods of the stretches of a and b next to their corner (`_stretch_near`) with both
    ramps there at `share` of their acceleration, less the samples the corner overlap adds."""
    from .stream import SectionStream  # it plans sections

    tail = dataclasses.replace(_stretch_near(a, at_end=True), eased_ends=(1.0, share), zone_cache={})
    head = dataclasses.replace(_stretch_near(b, at_end=False), eased_ends=(share, 1.0), zone_cache={})
    ta, tb = SectionStream(tail), SectionStream(head)
    n = ta.planned_samples() + tb.planned_samples()
    return n - corners.samples(ta, tb)


def _stretch_near(section: Section, at_end: bool) -> Section:
    """The section's elements near its end (or start) as a section of their own, with their own
    limits: as long as two ramps from rest and the averages' reach, so that the stretch's other
    end, from rest, leaves the motion near the corner as the whole section's (where it cruises
    there); the whole section where it is not much longer."""
    lim = section.limits
    k = -1 if at_end else 0
    v = _speed_at(lim, k)
    need = 2.0 * (v * v / float(lim.accel_for(False)[k]) + 2.0 * v * lim.smoothing.extension_s)
    s0 = section.path.s0
    if s0[-1] <= 2.0 * need:
        return section
    if at_end:
        first = int(np.searchsorted(s0, s0[-1] - need, side="right")) - 1
        keep = slice(max(first, 0), len(section.elements))
    else:
        last = int(np.searchsorted(s0, need, side="left"))
        keep = slice(0, max(last, 1))
    junctions = slice(keep.start, max(keep.stop - 1, keep.start))
    elements = section.elements[keep]
    limits = dataclasses.replace(
        lim, v_hard=lim.v_hard[keep], v_feed=lim.v_feed[keep], rapid=lim.rapid[keep], accel=lim.accel[keep],
        v_kink=lim.v_kink[junctions], caps=None,
        accel_feed=None if lim.accel_feed is None else lim.accel_feed[keep])
    return Section(elements, PathArrays.of(elements), limits, 0.0, section.flags[keep], section.segment[keep],
                   section.line[keep], [], section.end_cap_mm_s)


def _eased_zones(zones: Zones, shares: tuple[float, float], limits: SectionLimits) -> Zones:
    """The zones with the acceleration scaled by shares[0] over the stretch a ramp from rest at the
    start takes (its braking distance at the eased acceleration from the fastest the section may
    run at any override, and the averages' reach at that speed), and by shares[1] over the same at
    the end; the two stretches meet halfway on a short section. The stretches depend on the
    section alone, not on the controls: a motion planned under one override and planned again
    under another from where it is (`SectionStream.set_override`) finds the same accelerations
    where it brakes."""
    v, a = limits.v_max_any, float(limits.accel.max())
    lo_mm, hi_mm = float(zones.edges[0]), float(zones.edges[-1])
    half = (lo_mm + hi_mm) / 2.0

    def reach(share: float) -> float:
        return v * v / (2.0 * a * share) + v * limits.smoothing.extension_s if share < 1.0 else 0.0

    head = min(lo_mm + reach(shares[0]), half)
    tail = max(hi_mm - reach(shares[1]), half)
    inner = [x for x in (head, tail) if lo_mm < x < hi_mm]
    edges = np.unique(np.concatenate((zones.edges, inner)))
    mid = (edges[:-1] + edges[1:]) / 2.0
    k = np.clip(np.searchsorted(zones.edges, mid, side="right") - 1, 0, len(zones.accel) - 1)
    accel = zones.accel[k] * np.where(mid < head, shares[0], 1.0) * np.where(mid > tail, shares[1], 1.0)
    return Zones(edges, zones.hard[k], zones.soft[k], accel)


def _overlap_cap(a: Element, b: Element, cut) -> float:  # noqa: ANN001 - a CutPlan
    """The cutting model's cap on passing the corner a -> b in an overlap: the jet-lag cap of its turn
    at the finer quality of the two, and never above that quality's straight speed (the sum of the
    two moves may otherwise pass a hair over it, where one still arrives as the other has left); inf
    where either is not cut under the model. Stopped at, a corner needs none: the bottom of the jet
    catches up while the head stands; passed in an overlap, the head turns at speed, as at a corner
    of that angle."""
    if not overlap_may_apply(a, b):
        return math.inf
    qa, qb = (cut.quality_of(e.segment) if e.jet and e.kind in (LINE, ARC) else 0 for e in (a, b))
    if not (qa and qb):
        return math.inf
    u, w = own_line(a).direction_at_end(), own_line(b).direction_at_start()
    finer = max(qa, qb)
    return min(float(cut.model.turn_cap(finer, abs(_turn_rad(u, w)))), float(cut.model.speed_mm_s[finer]))


def _move_stop_corners(groups: list[list[Element]], config: MachineConfig) -> None:
    """Move each corner between two sections that a corner overlap may join (`overlap.py`) outward,
    by `[planner] corner_move_share` of its tolerance P, where a straight section alone ends or
    starts there.

    An overlap passes the corner on its inside: the two motions added cut it, by as much as the
    tolerance allows. With the corner moved outward by d, the sum may cut the moved corner by up
    to P + d and still keep within P of the programmed one, so the overlap may be longer and the
    head passes faster (a trajectory that turns within the band of 2 P around the legs, as the
    fastest jerk-limited one does: docs/benchmarks.md, "Where the corners lose"). Only a line
    that is a section by itself (a lead-in, a lead-out, a leg of a polyline stopped at at both
    ends) is tilted to the moved corner; a line in a longer section is only lengthened along its
    own direction (its other end may be blended, and a tilt would kink it there): between two such
    lines the corner moves along the bisector, outward; after a lone line into a longer section
    back along the next section's first line; before one, on along the last line: there by
    `[planner] lead_move_share` of P (0.7), as the move along the longer section's line puts the
    corner only sin(turn) of it outside the lone line, where a move along the bisector puts it
    outside both (0.7 instead of 0.5 there: the comparison nest 0.09 s sooner at F2400, 0.08 s
    over its five feeds; between two lone lines it left a zigzag a sample slower). Arcs are not
    moved, nor corners whose moved point leaves the travel. Each moved element keeps the one
    programmed (`Element.programmed`), against which the overlap measures its tolerance."""
    share, lead_share = config.planner.corner_move_share, config.planner.lead_move_share
    if config.planner.corner_overlap_ms <= 0.0 or share <= 0.0:
        return
    for i in range(len(groups) - 1):
        a, b = groups[i][-1], groups[i + 1][0]
        alone_a, alone_b = len(groups[i]) == 1, len(groups[i + 1]) == 1
        if a.kind == ARC or b.kind == ARC or not (alone_a or alone_b) or not overlap_may_apply(a, b):
            continue
        if a.end != own_line(a).end or b.start != own_line(b).start:  # a small arc folded into this corner
            continue
        u, w = a.direction_at_end(), b.direction_at_start()
        if u[0] * w[0] + u[1] * w[1] < -1e-9:  # a turn of more than 90 degrees: its overlap is held by
            continue  # the jerk two motions add, not by P, and the longer legs would only cost time
        if alone_a and alone_b:
            d = (u[0] - w[0], u[1] - w[1])
            norm = math.hypot(*d)
            if norm < 1e-3:  # straight on: no corner to move
                continue
            d = (d[0] / norm, d[1] / norm)
        else:
            d = (-w[0], -w[1]) if alone_a else u
        move = (share if alone_a and alone_b else lead_share) * min(a.tolerance_mm, b.tolerance_mm)
        if any(e.length_mm < CORNER_MOVE_SHORTEST * move for e in (a, b)):
            continue
        corner = a.end
        moved = (corner[0] + move * d[0], corner[1] + move * d[1], corner[2])
        if not all(_inside_travel(config, axis, q) for axis, q in zip("xy", moved)):
            continue
        groups[i][-1] = dataclasses.replace(a, end=moved, programmed=programmed_of(a))
        groups[i + 1][0] = dataclasses.replace(b, start=moved, programmed=programmed_of(b))


def programmed_of(e: Element) -> tuple[Element, ...]:
    """The programmed elements `e` stands for, in path order: itself, or where the planner moved a
    corner within P (`_move_stop_corners`, `_fold_small_arcs`, `_fold_small_turns`) the elements
    as programmed."""
    return e.programmed or (e,)


def own_line(e: Element) -> Element:
    """The programmed element `e` is made from (without the arcs folded into its ends)."""
    return next((p for p in programmed_of(e) if p.kind != ARC), e) if e.kind == LINE else e


def _fold_small_arcs(groups: list[list[Element]], config: MachineConfig, memo: dict) -> list[list[Element]]:
    """Fold a small arc that starts a section after a stop into the corner it rounds.

    Kerf compensation enters a part with a lead-in ending at the compensated point, a kink of a
    few degrees, and an arc of the kerf's radius around the contour's first point: a corner of
    the part rounded by a quarter of a millimetre. The planner stops at the kink and crawls
    through the arc at its centripetal jerk (about 10 mm/s at r = 0.125 mm). Within G64 P the
    three elements are one corner: where the arc holds the head below its feed anyway, the line
    before it is led to a point M and the line after it starts there. M lies between the arc and
    where the two lines meet, on the lines where they must keep their direction (a line in a
    longer section is only lengthened, a line that is a section by itself may be tilted), where
    the lines stray least from the programmed ones and the arc; never over P. The corner at M
    is a stop that a corner overlap (`overlap.py`) may pass, measured against the programmed
    elements (`Element.programmed` holds the arc on both sides). Nothing is folded where
    overlaps are off or corners are not to be moved (`[planner] corner_move_share` 0). `memo`:
    the folds made in an earlier pass over the same run, by the elements' identity."""
    if config.planner.corner_overlap_ms <= 0.0 or config.planner.corner_move_share <= 0.0 or len(groups) < 2:
        return groups
    gs = [list(g) for g in groups]
    for j in range(1, len(gs)):
        i = j - 1
        while i >= 0 and not gs[i]:
            i -= 1
        if i < 0 or not gs[j] or gs[j][0].kind != ARC:
            continue
        c = gs[j][0]
        if len(gs[j]) > 1:
            b_at, tilt_b = (j, 1), len(gs[j]) == 2
        elif j + 1 < len(gs) and gs[j + 1]:
            b_at, tilt_b = (j + 1, 0), len(gs[j + 1]) == 1
        else:
            continue
        b = gs[b_at[0]][b_at[1]]
        a, tilt_a = gs[i][-1], len(gs[i]) == 1
        key = (id(a), id(c), id(b), tilt_a, tilt_b)  # the same elements in every pass of a run (`memo`)
        folded = memo[key] if key in memo else memo.setdefault(key, _folded_corner(a, c, b, tilt_a, tilt_b, config))
        if folded is None:
            continue
        gs[i][-1] = folded[0]
        gs[b_at[0]][b_at[1]] = folded[1]
        del gs[j][0]
    return [g for g in gs if g]


def _fold_small_turns(run: list[Element], config: MachineConfig) -> list[Element]:
    """Fold each small arc between two lines of a run into the corner where the lines meet, where
    that corner lies within `FOLD_TURN_SHARE` of P of the arc, before corners are blended.

    Kerf compensation rounds every outside corner of a contour with an arc of the kerf's radius,
    also the few degrees between two chords of a curve: the head, held to that radius's
    centripetal jerk (about 10 mm/s at r = 0.125 mm), would crawl through each; a chord circle
    compensated on the outside took 2.5 times as long as compensated on the inside, a polygon's
    every corner 50-80 ms more. Folded, the corner is blended or stopped at and overlapped, as
    the CAM's own corner would be, whichever is faster: a blend there keeps only the rest of its
    share of P (`path._corner_off_path`), an overlap measures P against the programmed elements
    (`Element.programmed` keeps the arc), and where the corner is a kink passed unblended the
    lines give up what they stray from their tolerance. The lines are lengthened to their corner
    where it lies that near; where it does not (a right angle under a 0.25 mm kerf: 0.052 mm off
    its arc), a line whose far end is still where programmed may be tilted about it, by at most
    `FOLD_TILT_MAX_RAD` (a hair's kink at that end), to a corner between the arc and that point,
    where the lines stray least; a line is tilted at one end only, so no edge is shifted whole.
    Nothing is folded where corners are not to be moved (`[planner] corner_move_share` 0)."""
    if config.planner.corner_move_share <= 0.0 or len(run) < 3:
        return run
    out: list[Element] = []
    k = 0
    while k < len(run):
        c = run[k]
        if c.kind == ARC and out and out[-1].kind == LINE and k + 1 < len(run) and run[k + 1].kind == LINE:
            a, b = out[-1], run[k + 1]
            folded = _folded_corner(a, c, b, False, False, config, FOLD_TURN_SHARE, to_blend=True)
            tangent = not (_stops_between(a, c) or _stops_between(c, b))  # else a stop: `_fold_small_arcs` may tilt more
            if folded is None and tangent:  # tilted a hair about a far end still where programmed
                tilt = (a.start == own_line(a).start, b.end == own_line(b).end)
                if any(tilt):
                    folded = _folded_corner(a, c, b, *tilt, config, FOLD_TURN_SHARE, to_blend=True)
            if folded is not None:
                out[-1] = folded[0]
                out.append(folded[1])
                k += 2
                continue
        out.append(c)
        k += 1
    return out


def _folded_corner(a: Element, c: Element, b: Element, tilt_a: bool, tilt_b: bool, config: MachineConfig,
                   share: float = FOLD_STRAY_SHARE, to_blend: bool = False) -> tuple[Element, Element] | None:
    """Lines a and b meeting at one point M instead of through the small arc c between them
    (`_fold_small_arcs`, `_fold_small_turns`), or None where the arc is not small, the lines would
    stray over `share` of P from the programmed path or the three cannot be one corner. A line
    may already be folded at its other end (its programmed elements are kept, in path order).
    `to_blend`: the corner may be blended (the blend keeps the rest of its share of P,
    `path._corner_off_path`); where it is a kink, passed unblended and smoothed within all of P
    from the lines as made, their tolerance gives up what they stray (at most, between samples
    too)."""
    if a.kind != LINE or c.kind != ARC or b.kind != LINE or c.turns or a.end != c.start or c.end != b.start:
        return None
    cx, cy = c.center
    r = math.hypot(c.start[0] - cx, c.start[1] - cy)
    if _arc_speed_mm_s(r, config) >= c.feed_mm_s:  # the arc does not slow the head: a curve, not a corner
        return None
    if not (overlap_may_apply(a, c) and overlap_may_apply(c, b)) or a.end != own_line(a).end or \
            b.start != own_line(b).start:
        return None  # a line moved at this end already
    u, w = a.direction_at_end(), b.direction_at_start()
    cross = u[0] * w[1] - u[1] * w[0]
    if abs(cross) < 1e-6 or abs(_turn_rad(u, w)) > FOLD_TURN_MAX_RAD:
        return None  # parallel lines, or nearly a reversal
    side = math.copysign(1.0, cross)
    if min(_turn_rad(u, c.direction_at_start()) * side, c.sweep_rad * side, _turn_rad(c.direction_at_end(), w) * side) \
            < -KINK_MAX_RAD:
        return None  # an S (tangent joins count either way: their turn is rounding): no corner
    # Q, where the two lines meet: a.end + s u = b.start - t w
    dx, dy = b.start[0] - a.end[0], b.start[1] - a.end[1]
    s_q, t_q = (dx * w[1] - dy * w[0]) / cross, (u[0] * dy - u[1] * dx) / cross
    if s_q < -1e-9 or t_q < -1e-9:
        return None
    tolerance = min(e.tolerance_mm for e in (a, c, b))
    q = (a.end[0] + s_q * u[0], a.end[1] + s_q * u[1])
    if not (tilt_a or tilt_b) and min(abs(math.hypot(q[0] - cx, q[1] - cy) - r), s_q, t_q) > tolerance * share:
        return None  # Q, the only corner untilted lines have, lies farther off the arc (or the lines' ends)
    if tilt_a and tilt_b:  # anywhere between the arc and Q, on the ray from the arc's centre through Q
        reach_q = math.hypot(q[0] - cx, q[1] - cy)
        points = [(cx + (q[0] - cx) * f, cy + (q[1] - cy) * f) for f in np.linspace(r / reach_q, 1.0, FOLD_CANDIDATES + 1)[1:]]
    elif tilt_a:  # on b's line, from its start back to Q
        points = [(b.start[0] - t * w[0], b.start[1] - t * w[1]) for t in np.linspace(0.0, t_q, FOLD_CANDIDATES + 1)[1:]]
    elif tilt_b:  # on a's line, from its end on to Q
        points = [(a.end[0] + t * u[0], a.end[1] + t * u[1]) for t in np.linspace(0.0, s_q, FOLD_CANDIDATES + 1)[1:]]
    else:
        points = [q]
    points = np.array(points)
    inside = np.minimum(np.hypot(*(points - a.start[:2]).T), np.hypot(*(points - b.end[:2]).T)) > tolerance  # lines longer than P
    for col, axis in enumerate("xy"):
        limits = config.axis.get(axis)
        if limits is not None:
            inside &= (points[:, col] >= limits.travel_min_mm) & (points[:, col] <= limits.travel_max_mm)
    if to_blend:  # a tilt kinks a line's far end, where it may meet the next element tangent: a hair only
        for tilt, far, d, sense in ((tilt_a, a.start, u, 1.0), (tilt_b, b.end, w, -1.0)):
            if tilt:  # the line as made, in its direction of travel, against the line's own
                v = sense * (points - np.asarray(far[:2]))
                inside &= np.abs(np.arctan2(v[:, 0] * d[1] - v[:, 1] * d[0], v[:, 0] * d[0] + v[:, 1] * d[1])) \
                    <= FOLD_TILT_MAX_RAD
    points = points[inside]
    if not len(points):
        return None
    size, limit = r + max(s_q, t_q), tolerance * share
    for stride in FOLD_COARSE_STRIDES:  # a coarser sampling strays no more: a candidate it puts over P is out
        points = points[_fold_strays(points, a, c, b, (tilt_a, tilt_b), size, tolerance, stride=stride) <= limit]
        if not len(points):
            return None
    strays = _fold_strays(points, a, c, b, (tilt_a, tilt_b), size, tolerance)
    best = int(np.argmin(strays))
    if strays[best] > limit:
        return None
    moved = (float(points[best, 0]), float(points[best, 1]), a.end[2])
    # a kink is passed unblended, its smoothing taking all of P: the lines give up what they stray
    kink = to_blend and abs(_turn_rad(u, w)) <= KINK_MAX_RAD
    given_up = float(strays[best]) + FOLD_SAMPLE_SHARE * tolerance / 2.0 if kink else 0.0
    return (dataclasses.replace(a, end=moved, programmed=(*programmed_of(a), c), tolerance_mm=a.tolerance_mm - given_up),
            dataclasses.replace(b, start=moved, programmed=(c, *programmed_of(b)), tolerance_mm=b.tolerance_mm - given_up))


def _fold_strays(points: np.ndarray, a: Element, c: Element, b: Element, tilted: tuple[bool, bool], size: float,
                 tolerance: float, stride: int = 1) -> np.ndarray:
    """For each candidate corner M (rows of `points`) of a folded corner (`_folded_corner`): how far
    the lines a.start -> M -> b.end stray from the programmed elements (a's, c and b's) at most.

    Sampled every P / 4: between samples the distance can be at most P / 8 more, inside the
    margin `FOLD_STRAY_SHARE` leaves. A line only lengthened (`tilted` False) is as before but
    for the stretch from its end to M: that is sampled. A tilted line is sampled within reach of M
    (`size`: the arc's radius and how far the lines run on to meet), where the nearest programmed
    element may change; farther along, its distance to its own programmed line, whose far end it
    keeps, is convex and 0 there, so it is largest where the samples stop: that is taken too. A
    tilted line whose far end was moved as well is sampled whole.

    `stride` > 1: every stride-th of those samples only (and not the far end's), a lower bound of
    the whole sampling's figure for each point: cheap to rule points out with (`_folded_corner`)."""
    programmed = _unique([*programmed_of(a), c, *programmed_of(b)])
    step = tolerance * FOLD_SAMPLE_SHARE
    reach = size + tolerance + math.dist(c.start[:2], c.end[:2])
    pieces, beyond = [], []
    for end, far, line, tilt in ((a.end, a.start, own_line(a), tilted[0]), (b.start, b.end, own_line(b), tilted[1])):
        if not tilt:  # from the line's end on to M
            start = np.broadcast_to(np.asarray(end[:2]), points.shape)
            span = float(np.hypot(*(points - start).T).max())
        else:  # from M back along the line
            start = points
            far_kept = far in (line.start, line.end)
            span = reach if far_kept else float(np.hypot(*(np.asarray(far[:2]) - points).T).max())
        target = points if not tilt else np.asarray(far[:2])
        toward = target - start
        length = np.hypot(*toward.T)
        unit = np.divide(toward, length[:, None], out=np.zeros_like(toward), where=length[:, None] > 0.0)
        t = np.minimum(np.arange(0.0, span + step, step)[None, ::stride], length[:, None])
        pieces.append(start[:, None, :] + t[:, :, None] * unit[:, None, :])
        if tilt and far_kept and stride == 1:
            beyond.append(distance_to(pieces[-1][:, -1, :], [line]))
    samples = np.concatenate(pieces, axis=1)
    near = distance_to(samples.reshape(-1, 2), programmed).reshape(len(points), -1).max(axis=1)
    return np.maximum.reduce([near, *beyond]) if beyond else near


def _unique(elements: list[Element]) -> list[Element]:
    """The elements, each once (the same object may stand for both sides of a folded corner)."""
    out: list[Element] = []
    for e in elements:
        if not any(e is o for o in out):
            out.append(e)
    return out


def _arc_speed_mm_s(radius_mm: float, config: MachineConfig) -> float:
    """The most an arc of this radius lets the head run with the axes' whole acceleration and jerk
    (centripetal a = v^2 / r, its jerk v^3 / r^2): a bound above what the planner gives it."""
    accel, jerk = config.axis["x"].max_accel_mm_s2, config.axis["x"].max_jerk_mm_s3
    if "y" in config.axis:
        accel, jerk = min(accel, config.axis["y"].max_accel_mm_s2), min(jerk, config.axis["y"].max_jerk_mm_s3)
    return min(math.sqrt(accel * radius_mm), (jerk * radius_mm * radius_mm) ** (1.0 / 3.0))


def _inside_travel(config: MachineConfig, axis: str, position: float, margin: float = 0.0) -> bool:
    """Whether `position` on `axis` lies within the machine's travel, at least `margin` from its ends."""
    limits = config.axis.get(axis)
    return limits is None or limits.travel_min_mm + margin <= position <= limits.travel_max_mm - margin


def overlap_may_apply(last: Element, first: Element) -> bool:
    """Whether a corner overlap (`overlap.py`) may join a section ending with element `last` to the
    next one, starting with `first`: a tolerance on both, the same outputs, both flat (the check
    measures the deviation in XY) and meeting."""
    if min(last.tolerance_mm, first.tolerance_mm) <= 0.0 or _flags(last) != _flags(first):
        return False
    return flat(last) and flat(first) and max(abs(p - q) for p, q in zip(last.end, first.start)) <= 1e-9


def flat(e: Element) -> bool:
    """The element keeps its height (no Z motion along it)."""
    return e.start[2] == e.end[2]


def _jerk_reserves(groups: list[list[Element]], config: MachineConfig) -> list[float]:
    """Per section (its elements): the share of the axes' jerk it leaves unused (`JERK_RESERVE` or 0).

    Where two sections meet at a stop that a corner overlap may join (`overlap.py`), the last one's
    final jerk (its deceleration easing off: +J along its direction u_a) and the next one's first
    (+J along u_b) add on an axis both move along in the same sense. When the sum is over the axis's
    jerk the overlap is refused for that alone, even where one of them barely moves along that axis:
    a lead-in along Y into a contour whose first chord runs 3 degrees off X overlapped 2 ms instead
    of 40, for 1 % of jerk too much. So a single straight move (a lead-in, a lead-out, a rapid) at
    such a corner, where the smaller of the two directions' shares of the common axis is at most
    `JERK_RESERVE_SHARED`, leaves `JERK_RESERVE` of the jerk unused: its ramps take about that share
    longer, and the corner overlaps as far as the tolerance allows. Where both move along the axis
    (a zigzag's corners), a few per cent would not make room: no reserve there. The comparison nest
    of `bench/linuxcnc_compare.py` runs 0.6 s (0.3 %) sooner; no other comparison program changes.
    Curved sections never reserve: their share of the jerk is chosen by the time it takes
    (`_fastest_limits`). The corners weighed are those between the sections of one piece of a run
    (`iter_steps`); one where a long run is cut into pieces gets no reserve. Where a line runs a
    hair off its axis because a corner was moved (`_move_stop_corners`), the share the other move
    adds on that axis is left unused by whichever of the two moves most along it
    (`_jerk_shares_needed`), a few ten-thousandths, so that the exact right angle it was keeps its
    overlap."""
    reserves = [0.0] * len(groups)
    if config.planner.corner_overlap_ms <= 0.0:
        return reserves
    straight = [len(g) == 1 and g[0].kind != ARC for g in groups]
    for i in range(len(groups) - 1):
        a, b = groups[i][-1], groups[i + 1][0]
        if not (straight[i] or straight[i + 1]) or not overlap_may_apply(a, b):
            continue
        u_a, u_b = a.direction_at_end(), b.direction_at_start()
        shared = [min(abs(p), abs(q)) for p, q in zip(u_a, u_b) if p * q > 0.0]
        if shared and max(shared) <= JERK_RESERVE_SHARED:
            for k in (i, i + 1):
                if straight[k]:
                    reserves[k] = JERK_RESERVE
        # a line a moved corner tilted (at this end or its other) runs a hair off its axis
        if a.programmed is not None or b.programmed is not None:
            for k, need in zip((i, i + 1), _jerk_shares_needed(u_a, u_b)):
                if need <= JERK_RESERVE_SHARED:  # more: the overlap's check keeps the sum within the limits
                    reserves[k] = max(reserves[k], need)
    return reserves


def _jerk_shares_needed(u_a: tuple[float, float], u_b: tuple[float, float]) -> tuple[float, float]:
    """The shares of their jerk two moves meeting at a corner, along u_a and u_b there, leave unused
    so that no axis sees more than its limit where their ramps are added in an overlap, whichever of
    them meet (each move's path jerk takes its largest axis to the limit). On an axis where the two
    add up to more than the limit, the move with the larger part of it gives the excess up: a line
    tilted by a moved corner (`_move_stop_corners`) asks a few thousandths of the move along that
    axis, not all of its own small part."""
    top_a, top_b = max(map(abs, u_a)), max(map(abs, u_b))
    need = [0.0, 0.0]
    for p, q in zip(u_a, u_b):
        mine, theirs = abs(p) / top_a, abs(q) / top_b
        excess = mine + theirs - 1.0
        if excess > 0.0 and mine and theirs:
            k = 0 if mine >= theirs else 1
            need[k] = max(need[k], excess / max(mine, theirs) * (1.0 + 1e-3) + 1e-6)
    return need[0], need[1]


def _stops_between(a: Element, b: Element) -> bool:
    """A stop between two elements: at a corner in XY sharper than a kink, where Z starts or
    stops moving or changes its rate along the path (dz/ds: a plunge after a lift, a ramp after
    a helix; the corner blends and kink caps work in XY, so a Z rate stepped at speed would be a
    step of the Z velocity), or where the jet or the outputs switch."""
    u, w = a.direction_at_end(), b.direction_at_start()
    turn = _turn_rad(u, w)
    z_turn = (a.start[2] != a.end[2]) != (b.start[2] != b.end[2]) or abs(_z_rate(a) - _z_rate(b)) > Z_RATE_STEP
    return abs(turn) > KINK_MAX_RAD or z_turn or (a.jet, a.aux) != (b.jet, b.aux)


def _turn_rad(u: tuple[float, float], w: tuple[float, float]) -> float:
    """The signed turn in XY from direction u to direction w (counter-clockwise positive)."""
    return math.atan2(u[0] * w[1] - u[1] * w[0], u[0] * w[0] + u[1] * w[1])


def _z_rate(e: Element) -> float:
    """dz/ds of an element (constant along a line or a helix), s the path length."""
    dz = e.end[2] - e.start[2]
    return dz / e.length_mm if dz else 0.0


def _section(elements: list[Element], config: MachineConfig, offset: float, notes: dict, choose_jerk: bool = True,
             cut=None, jerk_reserve: float = 0.0) -> Section:  # noqa: ANN001 - a CutPlan
    whole = elements
    elements, path, feed, rapid, tolerance, blended = _capped_path(whole, config, cut)
    limits, seconds = _fastest_limits(path, feed, rapid, tolerance, blended, config, choose_jerk, jerk_reserve=jerk_reserve)
    if choose_jerk:
        elements, path, limits = _longer_averages(whole, config, cut, elements, path, limits, seconds)
    section = _assembled(elements, path, limits, offset, notes)
    section.whole = whole
    return section


def _capped_path(whole: list[Element], config: MachineConfig, cut, n_axis: int | None = None) -> tuple:  # noqa: ANN001
    """A section's elements as its caps are counted (long arcs in pieces for an axis average of
    `n_axis` samples, `arc_pieces_for_caps`), their path, feeds (the cutting model's where lower),
    rapids, tightest tolerance and whether any is a blend."""
    elements, origin = arc_pieces_for_caps(whole, config, n_axis)
    path = PathArrays.of(elements)
    feed = np.array([e.feed_mm_s for e in elements])
    if cut is not None:  # the cutting model: F is only an upper bound, set by the whole elements
        feed = np.minimum(feed, cut.caps(whole, path if elements is whole else PathArrays.of(whole))[origin])
    rapid = np.array([e.kind == RAPID for e in elements])
    tolerance = min(e.tolerance_mm for e in elements)
    blended = any(e.blend for e in elements)
    return elements, path, feed, rapid, tolerance, blended


def _longer_averages(whole: list[Element], config: MachineConfig, cut, elements: list[Element], path: PathArrays,
                     limits: SectionLimits, seconds: float) -> tuple[list[Element], PathArrays, SectionLimits]:  # noqa: ANN001
    """A section whose curves hold it back (a curve capped under its feed and the axes' speed)
    with the axis average its tolerance gives (`limits.axis_average_samples`: the balance of a
    curvature step's jerk and an arc's deviation) tries longer ones in turn, while the longer
    runs it sooner. A longer average spreads the curvature steps where arcs meet lines over more
    samples, so an arc's head may run faster, at the cost of a smaller deviation budget over the
    arc's middle and a longer settling at the section's ends; which wins depends on the arcs'
    lengths and radii (the Fig. 10 contour at P 0.005: 8 samples of its own, 2.96 s; 12 samples,
    2.69 s). The rough estimate that ranks the shares of jerk (`_fastest_limits`) misses both (it
    counts no cap widened by the averages' span), so the candidates are ranked by their planned
    samples (`SectionStream.planned_samples`, what the runner makes of them). The search ends
    where a longer average would hold the path's jerk another way than the section's own
    (`smoothing_for`: with the axis average alone, or no longer so): with the axis average alone
    and a longer one, the acceleration grows with it, and a window mixing a blend's short arc
    with the faster line before it passed P (by 0.01 mm at P 0.05, a random CAM part). `seconds`:
    the estimate of the limits given (inf: a section with no share to choose, kept as it is)."""
    from .stream import SectionStream  # (stream.py imports this module)

    sm = limits.smoothing
    if sm.n_axis <= 1 or not math.isfinite(seconds) or not _curves_bind(path, limits):
        return elements, path, limits
    step, most = max(1, round(sm.n_axis / AXIS_AVERAGE_STEPS)), min(MAX_SMOOTHING_SAMPLES, AXIS_AVERAGE_MOST * sm.n_axis)
    best = SectionStream(_assembled(elements, path, limits, 0.0, {})).planned_samples()
    n = sm.n_axis + step
    while n <= most:
        tried, tried_path, *rest = _capped_path(whole, config, cut, n)
        lim = _fastest_limits(tried_path, *rest, config, jerk_reserve=sm.jerk_reserve, n_axis=n)[0]
        if (lim.smoothing.n_path == 1) != (sm.n_path == 1):
            break  # the path's jerk held another way (`smoothing_for`): not a longer average of the same motion
        samples = SectionStream(_assembled(tried, tried_path, lim, 0.0, {})).planned_samples()
        if samples >= best:
            break
        elements, path, limits, best = tried, tried_path, lim, samples
        n += step
    return elements, path, limits


def _curves_bind(path: PathArrays, limits: SectionLimits) -> bool:
    """Whether a curve of the section is capped under its feed (at 100 %) and the axes' speed."""
    v_run = limits.v_feed if limits.caps is None else np.minimum(limits.v_feed, limits.caps.v_axis)
    return bool(np.any(path.arc & (limits.v_hard < CURVE_BINDS * v_run)))


def _assembled(elements: list[Element], path: PathArrays, limits: SectionLimits, offset: float, notes: dict) -> Section:
    """The section of these elements, path and limits, with its messages (`notes`: per segment)."""
    messages = []
    seen = set()
    for k, e in enumerate(elements):
        if e.segment in notes and e.segment not in seen:
            seen.add(e.segment)
            messages += [(float(path.s0[k]), text, line) for text, line in notes[e.segment]]
    return Section(
        elements, path, limits, offset,
        np.array([_flags(e) for e in elements], dtype=np.uint32),
        np.array([e.segment for e in elements], dtype=np.int64),
        np.array([e.line for e in elements], dtype=np.int64),
        messages,
    )
