"""Kerf compensation in bulk: whole compensated stretches of a plain run, as numpy arrays.

A stretch is what a nest repeats for every part: `G41 D1 G1 ...` (the entry line), the
contour (lines and partial arcs), `G40 G1 ...` (the straight exit). `KerfCompensator`
(`gcode.kerf`) handles such a stretch move by move; here every stretch of a run is done at
once with the same rules and the same formulas (see that module for what they mean):
corners classified by their bend, convex corners get an arc around the programmed corner,
concave corners are cut back to the meeting point of the offset paths, tangent joins start
the next move where the jet is.

Only the plain case is done here. A stretch with anything else (an entry arc, a rapid or a
pure Z move inside, a full circle, an inside arc too small, offset paths that do not meet,
a move cut back past its start, an arc that collapses) is reported as not plain, and the
caller leaves it to the per-move compensator, which also reports its errors exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .arcs import FULL_TURN_EPS_RAD
from .canon import ARC, LINE
from .kerf import SWEEP_SLACK_INCH_RAD, TANGENT_RAD, LEFT, COLLAPSED_MM

_TWO_PI = 2.0 * math.pi


@dataclass
class Compensated:
    """The compensated path of the stretches, in emission order (corner arcs included)."""

    kind: np.ndarray
    start: np.ndarray  # (n, 3)
    end: np.ndarray  # (n, 3)
    center: np.ndarray  # (n, 2)
    cw: np.ndarray
    source: np.ndarray  # index of the programmed move each piece belongs to
    corner: np.ndarray  # the piece is the arc around a convex corner before its move


def compensate(
    kind: np.ndarray, start: np.ndarray, end: np.ndarray, center: np.ndarray, cw: np.ndarray,
    stretch: np.ndarray, side: np.ndarray, radius: np.ndarray, first: np.ndarray, exit_: np.ndarray,
) -> tuple[Compensated | None, int | None]:
    """Compensate every stretch; moves are in program order.

    `stretch[i]` numbers the stretch move i belongs to (-1: not compensated), `side[i]` and
    `radius[i]` its side (+1 left, -1 right) and kerf radius, `first[i]` marks entry moves and
    `exit_[i]` exit moves (which belong to the stretch they close, and are straight).
    Returns (result, None), or (None, i) where i is the first move of the first stretch that
    is not plain.
    """
    result, bad = compensate_each(kind, start, end, center, cw, stretch, side, radius, first, exit_)
    if bad.any():
        hit = int(np.flatnonzero(bad)[0])
        return None, int(np.flatnonzero(stretch == stretch[hit])[0]) if stretch[hit] >= 0 else hit
    return result, None


def compensate_each(
    kind: np.ndarray, start: np.ndarray, end: np.ndarray, center: np.ndarray, cw: np.ndarray,
    stretch: np.ndarray, side: np.ndarray, radius: np.ndarray, first: np.ndarray, exit_: np.ndarray,
) -> tuple[Compensated, np.ndarray]:
    """`compensate`, answering for each move: (result, bad) with bad[i] set on the moves that
    make their stretch not plain. The pieces of a plain stretch are right whatever the others
    are; the pieces' starts chain across stretches (`Compensated.start`), which a caller
    emitting stretches apart from each other replaces with where each one really starts."""
    n = len(kind)
    comp = (stretch >= 0) & ~exit_
    xy0, xy1 = start[:, :2], end[:, :2]
    r = radius
    bad = np.zeros(n, dtype=bool)
    d = xy1 - xy0
    length = np.hypot(d[:, 0], d[:, 1])
    is_arc = kind == ARC
    with np.errstate(invalid="ignore", divide="ignore"):
        u = d / length[:, None]  # unit direction of lines
        normal = np.stack((-u[:, 1] * side, u[:, 0] * side), axis=1)
        # arcs: the jet is inside when the arc turns toward the jet's side
        inside = (side == LEFT) != cw
        out = np.where(inside, -1.0, 1.0)
        rad_end = np.hypot(xy1[:, 0] - center[:, 0], xy1[:, 1] - center[:, 1])
        rad_start = np.hypot(xy0[:, 0] - center[:, 0], xy0[:, 1] - center[:, 1])
        u_end = (xy1 - center) / rad_end[:, None]
        u_start = (xy0 - center) / rad_start[:, None]
    # what the plain case excludes
    bad |= comp & (kind != LINE) & (kind != ARC)  # rapids inside compensation
    bad |= comp & (length <= 1e-9) & ~is_arc  # pure Z moves
    bad |= comp & is_arc & (first | (np.hypot(*(xy1 - xy0).T) < 1e-9))  # entry arcs, full circles
    bad |= comp & is_arc & inside & (rad_end <= r)  # arc too small for the jet
    bad |= comp & is_arc & inside & (rad_start <= r)
    bad |= first & (length <= r)  # entry not longer than the radius
    bad |= exit_ & is_arc
    # offset ends (the tool position after each move)
    tool = np.where(is_arc[:, None], xy1 + u_end * (out * r)[:, None], xy1 + normal * r[:, None])
    offset_start = np.where(is_arc[:, None], xy0 + u_start * (out * r)[:, None], xy0 + normal * r[:, None])
    # corners: move i (not an entry, not an exit) joins to move i-1 of the same stretch
    corner_at = comp & ~first
    prev = np.arange(n) - 1
    ci = np.flatnonzero(corner_at)
    pi_ = prev[ci]
    bad_corner = np.zeros(n, dtype=bool)
    anchor = np.where(first[:, None], xy0, np.nan)  # where each compensated move starts
    piece_end = tool.copy()  # where each compensated move ends (cut back at concave corners)
    held_start = np.full((n, 2), np.nan)  # anchor of the incoming move, for the reversal check
    corner_arc = np.zeros(n, dtype=bool)
    if len(ci):
        corner = xy0[ci]
        t_prev = tool[pi_]
        s = side[ci]
        rr = r[ci]
        off = t_prev - corner
        a_in = np.arctan2(off[:, 1], off[:, 0]) - s * (math.pi / 2)
        a_out = np.where(
            is_arc[ci],
            np.arctan2(corner[:, 1] - center[ci, 1], corner[:, 0] - center[ci, 0]) + np.where(cw[ci], -math.pi / 2, math.pi / 2),
            np.arctan2(d[ci, 1], d[ci, 0]),
        )
        bend = np.mod(s * (a_in - a_out) + math.pi / 2, _TWO_PI) - math.pi / 2
        in_arc = is_arc[pi_]
        concave = (bend < -TANGENT_RAD) | (bend > math.pi + TANGENT_RAD)
        concave |= ~is_arc[ci] & (bend > math.pi - TANGENT_RAD) & in_arc & ~inside[pi_]
        concave |= is_arc[ci] & (np.abs(bend - math.pi) < TANGENT_RAD) & ~inside[ci]
        convex = ~concave & (bend > TANGENT_RAD)
        dir_in = np.stack((np.cos(a_in), np.sin(a_in)), axis=1)
        meet = np.full((len(ci), 2), np.nan)
        # line after line: the offset lines meet short of the jet by r*tan(bend/2)
        ll = concave & ~in_arc & ~is_arc[ci]
        back = -rr * np.tan(bend / 2.0)
        meet[ll] = t_prev[ll] - dir_in[ll] * back[ll, None]
        la = concave & ~in_arc & is_arc[ci]
        if la.any():
            meet[la] = _line_meets_arc(ci[la], corner[la], t_prev[la], dir_in[la], center, rad_end, inside, rr[la])
        al = concave & in_arc & ~is_arc[ci]
        if al.any():
            meet[al] = _arc_meets_line(pi_[al], corner[al], u[ci[al]], s[al], center, rad_end, inside, rr[al])
        aa = concave & in_arc & is_arc[ci]
        if aa.any():
            meet[aa] = _arcs_meet(pi_[aa], ci[aa], center, rad_end, inside, cw, rr[aa])
        bad_corner[ci[concave & np.isnan(meet).any(axis=1)]] = True
        anchor[ci] = np.where(concave[:, None], meet, np.where(convex[:, None], offset_start[ci], t_prev))
        piece_end[pi_] = np.where(concave[:, None], meet, t_prev)
        corner_arc[ci] = convex
        # the reversal check when the incoming move is released at a point (concave, or convex before a line)
        checked = concave | (convex & ~is_arc[ci])
        held_start[ci] = anchor[pi_]  # anchors are filled in order: pi_ < ci
        bad_corner[ci[checked]] |= _reverses(
            pi_[checked], piece_end[pi_[checked]], anchor, xy0, xy1, center, d, cw, is_arc, first
        )
    # the anchor of a move must be known before the next corner's check: fill in order once more
    # (anchors of entries are their programmed start; of the rest, set above at their corner)
    last_of_stretch = comp & np.concatenate((exit_[1:], [False]))
    bad_corner[last_of_stretch] |= _reverses(
        np.flatnonzero(last_of_stretch), tool[last_of_stretch], anchor, xy0, xy1, center, d, cw, is_arc, first
    )
    # collapsed offset arcs (start meets end) are not plain
    collapsed = comp & is_arc & (np.hypot(*(piece_end - anchor).T) < COLLAPSED_MM)
    bad |= bad_corner | collapsed
    return _assemble(kind, start, end, center, cw, comp, exit_, anchor, piece_end, tool, offset_start, corner_arc, side), bad


def _reverses(idx, point, anchor, xy0, xy1, center, d, cw, is_arc, first) -> np.ndarray:
    """Would ending move idx at `point` cut it back past its start (a gouge)? Entries are never checked."""
    if not len(idx):
        return np.zeros(0, dtype=bool)
    start = anchor[idx]
    line_rev = (d[idx, 0] * (point[:, 0] - start[:, 0]) + d[idx, 1] * (point[:, 1] - start[:, 1])) < 0.0
    arc = is_arc[idx]
    rev = np.where(arc, False, line_rev)
    if arc.any():
        c = center[idx]
        prog = _sweep(xy0[idx], c, cw[idx], xy1[idx])
        now = _sweep(start, c, cw[idx], point)
        # the tighter (G20) slack: an arc between the two goes to the per-move compensator,
        # which knows the program's units
        rev = np.where(arc, np.abs(now) > np.abs(prog) + SWEEP_SLACK_INCH_RAD, rev)
    return rev & ~first[idx]


def _sweep(p0, c, cw, p1) -> np.ndarray:
    """Signed angle from p0 to p1 about c, one turn, p0 == p1 a full turn (kerf._sweep_rad for turn = +-1)."""
    delta = np.arctan2(p1[:, 1] - c[:, 1], p1[:, 0] - c[:, 0]) - np.arctan2(p0[:, 1] - c[:, 1], p0[:, 0] - c[:, 0])
    ccw = np.where(delta <= FULL_TURN_EPS_RAD, delta + _TWO_PI, delta)
    cwv = np.where(delta >= -FULL_TURN_EPS_RAD, delta - _TWO_PI, delta)
    return np.where(cw, cwv, ccw)


def _line_circle(point, unit, center, radius):
    rel = point - center
    b = (unit * rel).sum(axis=1)
    disc = b * b - ((rel * rel).sum(axis=1) - radius * radius)
    root = np.sqrt(np.where(disc < 0.0, np.nan, disc))
    return -b - root, -b + root


def _on_circle(center, radius, point):
    v = point - center
    return center + v / np.hypot(v[:, 0], v[:, 1])[:, None] * radius[:, None]


def _line_meets_arc(arc_i, corner, tool_prev, direction, center, rad_end, inside, rr):
    """kerf.KerfCompensator._line_meets_arc."""
    c = center[arc_i]
    nominal = rad_end[arc_i]
    radius = nominal + np.where(inside[arc_i], -rr, rr)
    line_point = _on_circle(c, nominal, corner) + (tool_prev - corner)
    t0, t1 = _line_circle(line_point, direction, c, radius)
    t = np.where(inside[arc_i], t1, t0)
    return line_point + direction * t[:, None]


def _arc_meets_line(arc_i, corner, unit, s, center, rad_end, inside, rr):
    """kerf.KerfCompensator._arc_meets_line: the held arc's radius is its offset radius."""
    c = center[arc_i]
    nominal = rad_end[arc_i]
    radius = nominal + np.where(inside[arc_i], -rr, rr)
    offset = np.stack((-unit[:, 1] * s, unit[:, 0] * s), axis=1) * rr[:, None]
    line_point = _on_circle(c, nominal, corner) + offset
    t0, t1 = _line_circle(line_point, unit, c, radius)
    t = np.where(inside[arc_i], t0, t1)
    return line_point + unit * t[:, None]


def _arcs_meet(before, after, center, rad_end, inside, cw, rr):
    """kerf.KerfCompensator._arcs_meet: both circles are the offset circles."""
    c0 = center[before]
    r0 = rad_end[before] + np.where(inside[before], -rr, rr)
    r1 = rad_end[after] + np.where(inside[after], -rr, rr)
    between = np.hypot(*(center[after] - c0).T)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_a = (r0**2 + between**2 - r1**2) / (2.0 * r0 * between)
        ok = (r0 != 0.0) & (between != 0.0) & (np.abs(cos_a) <= 1.0)
        left = inside[before] == ~cw[after]
        acs = np.arccos(np.clip(cos_a, -1.0, 1.0))
        a = np.arctan2(center[after, 1] - c0[:, 1], center[after, 0] - c0[:, 0]) + np.where(left, acs, -acs)
    pts = np.stack((c0[:, 0] + r0 * np.cos(a), c0[:, 1] + r0 * np.sin(a)), axis=1)
    pts[~ok] = np.nan
    return pts


def _assemble(kind, start, end, center, cw, comp, exit_, anchor, piece_end, tool, offset_start, corner_arc, side) -> Compensated:
    """Pieces in emission order: [corner arc before move i], move i; each starts where the last ended."""
    n = len(kind)
    count = 1 + corner_arc.astype(np.int64)
    pos = np.concatenate(([0], np.cumsum(count)[:-1]))
    total = int(count.sum())
    out_kind = np.empty(total, dtype=np.uint8)
    out_end = np.empty((total, 3))
    out_center = np.zeros((total, 2))
    out_cw = np.zeros(total, dtype=bool)
    source = np.empty(total, dtype=np.int64)
    move_at = pos + corner_arc
    # corner arcs: around the programmed corner, at the Z where the jet is (the previous end's Z)
    ca = np.flatnonzero(corner_arc)
    at = pos[ca]
    out_kind[at] = ARC
    out_end[at, :2] = offset_start[ca]
    out_end[at, 2] = end[ca - 1, 2]
    out_center[at] = start[ca, :2]
    out_cw[at] = side[ca] == LEFT
    source[at] = ca
    # the moves themselves
    out_kind[move_at] = kind
    xy_end = np.where(comp[:, None], piece_end, end[:, :2])
    out_end[move_at, :2] = xy_end
    out_end[move_at, 2] = end[:, 2]
    out_center[move_at] = center
    out_cw[move_at] = cw
    source[move_at] = np.arange(n)
    out_start = np.empty((total, 3))
    out_start[0] = start[0]
    out_start[1:] = out_end[:-1]
    corner = np.zeros(total, dtype=bool)
    corner[at] = True
    return Compensated(out_kind, out_start, out_end, out_center, out_cw, source, corner)
