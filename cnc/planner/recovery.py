"""Starting a program elsewhere than at its beginning: continuing a cut where the jet stopped,
starting at part N of a nest, running from a line.

All three work on the interpreted program's segments. Those are in machine coordinates with every
modal state already applied (units, work offsets, G92, kerf compensation, feed, corner tolerance,
the outputs in force), so starting inside them needs no modal state rebuilt: interpreting the
whole program first is what gives that (LinuxCNC's run-from-line re-executes the program's
preamble for it, and loses what a loop computed). What starts is a new program: a rapid from
where the head stands, jet closed, to where the restart begins, then the rest of the program from
there, the first segment cut short when the restart begins inside it. Where the jet is to be
open there, the planner pierces (the machine file's on delay and pierce dwell) before the head
moves on, as at any jet-on transition.

Continuing backs up along the cut by an overlap so that the joined cut has no gap (the jet was
closing while the head stopped), but never past the pierce of that cut: the overlap ends at the
cut's start. A line inside an O-word loop or subroutine ran several times; its segments are
those of every pass, and `run_from_line` takes the first pass and says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from gcode.arcs import arc_length, sweep, sweeps
from gcode.canon import ARC, DWELL, RAPID
from gcode.program import Message, Program, Statistics

from .preflight import segment_bounds

_TWO_PI = 2.0 * math.pi


class RecoveryError(ValueError):
    """Where a program cannot be restarted, and why (with what to do instead)."""


@dataclass(frozen=True)
class Restart:
    """A program that starts where asked: `program`'s first segment is the rapid to `at`."""

    program: Program
    segment: int  # the original program's segment the restart begins in
    into_mm: float  # how far into it
    line: int
    at: tuple[float, float, float]
    description: str
    offset: int = 0  # the restart's segment j >= 1 is the original program's j + offset (0 is the rapid)

    def original_segment(self, j: np.ndarray) -> np.ndarray:
        """The original program's segment indices of the restart's `j` (the rapid counts as the first)."""
        return np.where(j >= 1, j + self.offset, self.segment)


# -- geometry of one segment ------------------------------------------------------------------
def segment_length(s: np.void) -> float:
    """Path length of one segment (0 for a dwell)."""
    kind = int(s["kind"])
    if kind == DWELL:
        return 0.0
    (x0, y0, z0), (x1, y1, z1) = s["start"], s["end"]
    if kind == ARC:
        cx, cy = s["center"]
        swept = sweep(x0, y0, x1, y1, cx, cy, bool(s["cw"]), int(s["turns"]))
        return arc_length(math.hypot(x0 - cx, y0 - cy), swept, z1 - z0)
    return math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2 + (z1 - z0) ** 2)


def point_at(s: np.void, into_mm: float) -> tuple[float, float, float]:
    """The point `into_mm` along one segment from its start."""
    length = segment_length(s)
    f = 0.0 if length <= 0.0 else min(max(into_mm / length, 0.0), 1.0)
    (x0, y0, z0), (x1, y1, z1) = s["start"], s["end"]
    if int(s["kind"]) == ARC:
        cx, cy = s["center"]
        swept = sweep(x0, y0, x1, y1, cx, cy, bool(s["cw"]), int(s["turns"]))
        r = math.hypot(x0 - cx, y0 - cy)
        a = math.atan2(y0 - cy, x0 - cx) + swept * f
        return (float(cx + r * math.cos(a)), float(cy + r * math.sin(a)), float(z0 + (z1 - z0) * f))
    return (float(x0 + (x1 - x0) * f), float(y0 + (y1 - y0) * f), float(z0 + (z1 - z0) * f))


def locate(s: np.void, point: tuple[float, ...], hint_mm: float = -1.0) -> float:
    """How far along one segment the point nearest `point` (x, y) lies, in mm. An arc of several
    turns passes every point once a turn: the pass nearest `hint_mm` (how far into the segment the
    head was known to be, roughly; a few mm off picks the right turn), its first when negative."""
    (x0, y0, z0), (x1, y1, z1) = s["start"], s["end"]
    px, py = float(point[0]), float(point[1])
    length = segment_length(s)
    if length <= 0.0:
        return 0.0
    if int(s["kind"]) == ARC:
        cx, cy = s["center"]
        swept = abs(sweep(x0, y0, x1, y1, cx, cy, bool(s["cw"]), int(s["turns"])))
        rel = math.atan2(py - cy, px - cx) - math.atan2(y0 - cy, x0 - cx)
        rel = (-rel if s["cw"] else rel) % _TWO_PI
        if rel > swept:  # beyond the arc's end: the nearer of its two ends
            return length if rel - swept < _TWO_PI - rel else 0.0
        passes = int((swept - rel) // _TWO_PI)  # the turns after the first pass that pass it again
        if hint_mm >= 0.0 and passes:
            rel += _TWO_PI * min(max(round((hint_mm / length * swept - rel) / _TWO_PI), 0), passes)
        return rel / swept * length
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    planar = dx * dx + dy * dy
    if planar <= 0.0:
        return 0.0
    t = ((px - x0) * dx + (py - y0) * dy) / planar
    return min(max(t, 0.0), 1.0) * length


def into_segments(segment: np.ndarray, done_mm: np.ndarray, carry: tuple[int, float],
                  restart_into_mm: float | None = None) -> tuple[np.ndarray, tuple[int, float]]:
    """How far into its segment each of a run's setpoints lies, mm, from the program position
    `done_mm` of each and its `segment` (the run's own numbering), roughly: from where the
    segment's first setpoint was (a blend's share and a sample's step off). `carry`: (segment,
    base) of the last setpoint before these ((-1, 0) at a run's start), returned for the next.
    `restart_into_mm`: a restart's, how far into the program's segment its segment 1 begins; its
    segment 0, the rapid there (and the pierce at its end), is at that point too.
    Kept with the cut point: which turn of an arc of several the jet stopped on."""
    if not len(segment):
        return np.zeros(0), carry
    before = np.concatenate(([carry[0]], segment[:-1]))
    starts = np.where(segment != before, np.arange(len(segment)), -1)
    first = np.maximum.accumulate(starts)
    base_at = done_mm if restart_into_mm is None else done_mm - np.where(segment == 1, restart_into_mm, 0.0)
    base = np.where(first >= 0, base_at[np.maximum(first, 0)], carry[1])
    into = done_mm - base
    if restart_into_mm is not None:
        into = np.where(segment == 0, restart_into_mm, into)
    return into, (int(segment[-1]), float(base[-1]))


def _cut_short(s: np.void, into_mm: float) -> np.void:
    """The segment from `into_mm` to its end (the same segment when `into_mm` is 0)."""
    out = s.copy()
    if into_mm <= 0.0:
        return out
    start = point_at(s, into_mm)
    if int(s["kind"]) == ARC:
        (x0, y0, _), (x1, y1, _) = s["start"], s["end"]
        cx, cy = s["center"]
        swept = sweep(x0, y0, x1, y1, cx, cy, bool(s["cw"]), int(s["turns"]))
        remaining = abs(swept) * (1.0 - into_mm / segment_length(s))
        # the whole turns beyond the sweep from the new start to the end: counted against that sweep
        # itself, so that a start a hair past a turn's boundary (where it meets the end) keeps the
        # turn left instead of becoming a zero-length arc, a turn never cut
        base = abs(sweep(float(start[0]), float(start[1]), x1, y1, cx, cy, bool(s["cw"]), 0))
        out["turns"] = max(int(round((remaining - base) / _TWO_PI)), 0)
    out["start"] = start
    return out


# -- the restarts -----------------------------------------------------------------------------
def _cuts(s: np.void) -> bool:
    """Whether the segment is a cutting move: the jet open on a feed move (not a rapid or a dwell)."""
    return bool(s["jet"]) and int(s["kind"]) not in (RAPID, DWELL)


def continue_at(program: Program, segment: int, point: tuple[float, ...], overlap_mm: float,
                head: tuple[float, float, float], segment_mm: float = -1.0) -> Restart:
    """Continue a cut stopped at `point` on `segment` (where the jet was last open), backed up by
    `overlap_mm` along the cut (not past its pierce); the head now at `head`. `segment_mm`: roughly
    how far into the segment the jet stopped (-1 unknown), which turn of an arc of several.

    The jet may also stop while the head stands with it open, in a dwell: while piercing (the
    dwell opens the cut) the restart pierces there again and cuts the part from its start; in a
    dwell inside a cut, the cut stopped at the end of the move before it, and continues from there."""
    seg = program.segments
    if not 0 <= segment < len(seg):
        raise RecoveryError(f"segment {segment} is not in {_name(program)} (it has {len(seg)})")
    if not (math.isfinite(overlap_mm) and overlap_mm >= 0.0):
        raise RecoveryError(f"overlap {overlap_mm!r} mm must be 0 or more")
    s = seg[segment]
    if s["jet"] and int(s["kind"]) == DWELL:  # the jet stopped while the head stood with it open
        cut = segment
        while cut > 0 and seg[cut - 1]["jet"] and int(seg[cut - 1]["kind"]) == DWELL:
            cut -= 1
        if cut == 0 or not _cuts(seg[cut - 1]):  # piercing: pierce again, and cut the part from its start
            line = int(seg[cut]["line"])
            return _from(program, cut, 0.0, head, f"pierce again at line {line} (the jet stopped while piercing) "
                                                  "and cut from there")
        segment, point, segment_mm = cut - 1, tuple(seg[cut - 1]["end"]), segment_length(seg[cut - 1])
        s = seg[segment]  # a dwell inside a cut: the cut stopped where the head stood, at the move's end
    if not _cuts(s):
        raise RecoveryError(f"{_name(program)}:{int(s['line'])}: the jet was not cutting there; start at the next part instead")
    k, into = segment, locate(s, point, segment_mm)
    if into >= segment_length(s) - COMPLETE_MM and _ends_its_cut(seg, segment):
        return _after_complete_cut(program, segment, head)
    back = overlap_mm
    while back > 1e-12:
        if into >= back:
            into -= back
            break
        back -= into
        prev = seg[k - 1] if k > 0 else None
        if prev is None or not _cuts(prev):
            into = 0.0  # the cut's pierce: the overlap ends here
            break
        k -= 1
        into = segment_length(seg[k])
    if into >= segment_length(seg[k]) - 1e-9 and k + 1 < len(seg):  # at a segment's very end: the next one
        k, into = k + 1, 0.0
    line = int(seg[k]["line"])
    return _from(program, k, into, head, f"continue the cut of line {line}, {overlap_mm:g} mm back from where it stopped")


COMPLETE_MM = 1e-6  # a cut stopped this close to its end was complete (the program closed the jet there)


def _ends_its_cut(seg: np.ndarray, k: int) -> bool:
    """Whether no cutting move follows segment k while the jet stays open: k is its cut's last."""
    for j in range(k + 1, len(seg)):
        if not seg[j]["jet"] or int(seg[j]["kind"]) == RAPID:
            return True
        if _cuts(seg[j]):
            return False
    return True


def _after_complete_cut(program: Program, k: int, head: tuple[float, float, float]) -> Restart:
    """The jet last cut at the very end of a cut: the program had closed it there, and the stop
    came after (in the rapid to the next part, say). That cut is whole: the next one starts with its
    own pierce, where the CAM placed it, rather than a pierce at the finished part's edge."""
    line = int(program.segments[k]["line"])
    later = [n for n, start in enumerate(cut_starts(program), 1) if start > k]
    if not later:
        raise RecoveryError(f"{_name(program)}:{line}: the cut that stopped was complete and no cut follows it: "
                            "nothing is left to cut (run from a line to move the head on)")
    restart = start_at_part(program, later[0], head)
    return replace(restart, description=f"the cut of line {line} was complete: {restart.description}")


def start_at_part(program: Program, n: int, head: tuple[float, float, float]) -> Restart:
    """Start at part `n` (1-based): at the beginning of its cut, the `n`-th pierce of the program
    (its own pierce dwell, if it has one, included)."""
    starts = cut_starts(program)
    if not 1 <= n <= len(starts):
        raise RecoveryError(f"{_name(program)} has {len(starts)} part{'s' if len(starts) != 1 else ''} (pierces): "
                            f"there is no part {n}")
    k = starts[n - 1]
    return _from(program, k, 0.0, head, f"start at part {n} of {len(starts)} (line {int(program.segments[k]['line'])})")


def run_from_line(program: Program, line: int, head: tuple[float, float, float]) -> Restart:
    """Run from the first segment of source line `line` (or the first after it, for a line that
    moves nothing); a line inside a loop or subroutine: its first pass."""
    seg = program.segments
    lines = seg["line"]
    at = np.flatnonzero(lines >= line) if len(seg) else np.zeros(0, dtype=np.int64)
    if not len(at):
        raise RecoveryError(f"{_name(program)}: nothing moves at or after line {line}")
    k = int(at[0])
    passes = int(np.count_nonzero(lines == int(lines[k])))
    note = f" (line {int(lines[k])} runs {passes} times in a loop or subroutine: from its first pass)" if passes > 1 else ""
    return _from(program, k, 0.0, head, f"run from line {int(lines[k])}{note}")


def cut_starts(program: Program) -> list[int]:
    """The segment where each cut begins: the first of a run of jet-on segments (a pierce dwell
    included) that contains a cutting move. Whole-array: a million segments in milliseconds."""
    seg = program.segments
    kind = seg["kind"]
    on = seg["jet"] & (kind != RAPID)
    if not on.any():
        return []
    edges = np.diff(np.concatenate(([0], on.view(np.int8), [0])))
    first, end = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # each run of jet-on: [first, end)
    cutting = np.concatenate(([0], np.cumsum(on & (kind != DWELL))))
    return first[cutting[end] > cutting[first]].tolist()


def _name(program: Program) -> str:
    """The program's file name, as an operator knows it."""
    return program.name.replace("\\", "/").rsplit("/", 1)[-1]


def _from(program: Program, k: int, into: float, head: tuple[float, float, float], description: str) -> Restart:
    """The program from `into` mm into segment `k`, after a rapid from `head` to there."""
    seg = program.segments
    first = _cut_short(seg[k], into)
    at = tuple(float(v) for v in first["start"])
    rapid = np.zeros(1, dtype=seg.dtype)
    rapid["kind"], rapid["start"], rapid["end"] = RAPID, head, at
    rapid["feed"], rapid["dwell"], rapid["line"] = math.nan, 0.0, int(first["line"])
    rapid["tolerance"] = first["tolerance"]
    body = [first[None]] if into <= 0.0 or segment_length(first) > 1e-9 else []
    segments = np.concatenate([rapid, *body, seg[k + 1:]])
    shift = 1 + len(body) - (k + 1)  # old segment j > k is new j + shift
    # a message shown before segment k still shows when the restart begins at k's start
    messages = [Message(m.line, m.segment + shift, m.kind, m.text, m.data) for m in program.messages
                if m.segment > k or (m.segment == k and into <= 0.0)]
    restarted = Program(program.name, segments, messages, _statistics(segments, program.stats.lines), program.units_final)
    return Restart(restarted, k, float(into), int(first["line"]), at, description, offset=-shift)


def _statistics(segments: np.ndarray, lines: int) -> Statistics:
    """The figures of a restarted program (its path lengths, pierces and dwell), counted as the
    interpreter counts them: a cutting move pierces when the jet was closed before it (a rapid or
    dwell with the jet closed closes it; a feed move leaves it as that move had it)."""
    st = Statistics(lines=lines, segments=len(segments))
    if not len(segments):
        return st
    kind, jet = segments["kind"], segments["jet"]
    length = segment_lengths(segments)
    rapid, dwell = kind == RAPID, kind == DWELL
    feed = ~(rapid | dwell)
    st.dwell_s = float(segments["dwell"][dwell].sum())
    st.rapid_length_mm = float(length[rapid].sum())
    st.feed_length_mm = float(length[feed].sum())
    st.cut_length_mm = float(length[feed & jet].sum())
    # the jet's state before each segment: set by the last segment before it that sets it
    sets = feed | ((rapid | dwell) & ~jet)
    last = np.maximum.accumulate(np.where(sets, np.arange(len(segments)), -1))
    before = np.concatenate(([-1], last[:-1]))
    was_on = np.where(before >= 0, jet[np.maximum(before, 0)] & feed[np.maximum(before, 0)], False)
    st.pierces = int(np.count_nonzero(feed & jet & ~was_on))
    lo, hi = segment_bounds(segments)  # an arc's bulge included, as the interpreter counts it
    st.bounds_min, st.bounds_max = tuple(lo.min(axis=0)), tuple(hi.max(axis=0))
    return st


def segment_lengths(segments: np.ndarray) -> np.ndarray:
    """`segment_length` of every segment at once (whole-array: the restart of a million-line nest)."""
    kind = segments["kind"]
    start, end = segments["start"], segments["end"]
    d = end - start
    out = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + d[:, 2] ** 2)
    arc = np.flatnonzero(kind == ARC)
    if len(arc):
        a = segments[arc]
        (x0, y0), (x1, y1), (cx, cy) = a["start"][:, :2].T, a["end"][:, :2].T, a["center"].T
        swept, _ = sweeps(x0, y0, x1, y1, cx, cy, a["cw"], a["turns"])
        out[arc] = np.hypot(np.hypot(x0 - cx, y0 - cy) * swept, d[arc, 2])
    out[kind == DWELL] = 0.0
    return out
