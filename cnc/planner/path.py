"""Planner path: a program's segments as a chain of lines and arcs, corners blended within tolerance.

The planner moves along this path by arc length. Where two straight moves meet at an angle
and the corner tolerance allows (G64 P, or the machine default), the corner is replaced by a
circular arc tangent to both lines, so the head need not stop there. For a turn of phi
between the two directions, an arc of radius R strays from the programmed path (the two
lines, measured to their nearest point) by at most

    d = R * (1 - cos(phi / 2))              (at the arc's middle)

and cuts back each line by R * tan(phi / 2). R is the largest radius with d <= P / 2 (the
other half of P belongs to the planner's smoothing, `limits.py`) whose cut-backs fit in half
of each neighbouring line, so that neighbouring blends never overlap.
A kink where an arc meets a line or another arc (kerf-compensated corners, lead-ins, CAM arcs
fitted a hair off tangent) is blended the same way (`_fillet`): a circle tangent to both on the
inside of the turn, within P / 2 of the corner, trimming at most half of either neighbour.
A corner is an exact stop (no blend) under G61, where the jet or the outputs switch (they
switch exactly at the segment boundary), around dwells, at a reversal, between a rapid and a
feed move, where the height changes, and where the planner finds stopping faster than
crawling through the blend (`sections.py`). Where such a stop may be overlapped (`overlap.py`),
the planner moves the corner outward within P (`sections._move_stop_corners`): the element keeps
the one programmed (`Element.programmed`). A small arc of the kerf's radius between two lines
(kerf compensation's outside corners) may be folded into the corner the lines make
(`sections._fold_small_turns`, `_fold_small_arcs`): the lines keep the arc among their programmed
elements, and a blend of that corner keeps within P of it (`_corner_off_path`). `deviation`
measures how far a path strays from the programmed one, so tests check the bound rather than
trust the formula.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from gcode.arcs import sweep
from gcode.canon import ARC, DWELL, LINE, RAPID

COLLINEAR_RAD = 1e-6  # turns smaller than this are straight on: no blend needed
BLEND_SHARE = 0.5  # share of the tolerance P a blend may use; the planner's smoothing keeps the rest


@dataclass(slots=True)
class Element:
    """One piece of the path: a line or an arc from `start` to `end` (mm), or a dwell."""

    kind: int  # LINE, ARC, RAPID or DWELL
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    center: tuple[float, float] | None
    cw: bool
    turns: int
    feed_mm_s: float  # programmed feed (inf for rapids: the axis limits decide)
    tolerance_mm: float
    jet: bool
    aux: int
    outputs: int
    segment: int  # index of the program segment it comes from
    line: int
    dwell_s: float = 0.0
    blend: bool = False  # a corner blend inserted by the planner
    programmed: "tuple[Element, ...] | None" = None  # where the planner moved an end within P
    # (`sections.py` `_move_stop_corners`, `_fold_small_turns`, `_fold_small_arcs`): the elements
    # as programmed, in path order, which tolerances are measured against (a folded arc on both
    # lines next to it)
    # what the planner asks of an element again and again (its sections, blends and limits each
    # look at it), worked out once: elements never change once made
    _length: float = field(default=-1.0, init=False, repr=False, compare=False)
    _sweep: float | None = field(default=None, init=False, repr=False, compare=False)
    _dir_start: tuple[float, float] | None = field(default=None, init=False, repr=False, compare=False)
    _dir_end: tuple[float, float] | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def length_mm(self) -> float:
        length = self._length
        if length < 0.0:
            if self.kind == DWELL:
                length = 0.0
            elif self.kind == ARC:
                r = math.hypot(self.start[0] - self.center[0], self.start[1] - self.center[1])
                length = math.hypot(r * abs(self.sweep_rad), self.end[2] - self.start[2])
            else:
                length = math.dist(self.start, self.end)
            self._length = length
        return length

    @property
    def sweep_rad(self) -> float:
        """Signed swept angle of an arc (negative clockwise), full circles and extra turns included."""
        swept = self._sweep
        if swept is None:
            swept = self._sweep = sweep(self.start[0], self.start[1], self.end[0], self.end[1], *self.center, self.cw,
                                        self.turns)
        return swept

    def direction_at_start(self) -> tuple[float, float]:
        d = self._dir_start
        if d is None:
            d = self._dir_start = self._direction(self.start)
        return d

    def direction_at_end(self) -> tuple[float, float]:
        d = self._dir_end
        if d is None:
            d = self._dir_end = self._direction(self.end) if self.kind == ARC else self.direction_at_start()
        return d

    def _direction(self, p) -> tuple[float, float]:
        if self.kind == ARC:
            rx, ry = p[0] - self.center[0], p[1] - self.center[1]
            r = math.hypot(rx, ry)
            return (ry / r, -rx / r) if self.cw else (-ry / r, rx / r)
        dx, dy = self.end[0] - self.start[0], self.end[1] - self.start[1]
        n = math.hypot(dx, dy)
        return (dx / n, dy / n) if n > 0 else (0.0, 0.0)


def elements_from_program(segments: np.ndarray) -> list[Element]:
    """The program's segments as path elements (feeds in mm/s)."""
    return list(iter_elements(segments))


ELEMENT_CHUNK = 4096  # segments converted to Python values at a time: cheap per segment, bounded memory


def iter_elements(segments: np.ndarray, first: int = 0) -> Iterator[Element]:
    """The segments from `first` on as path elements, made as they are asked for (a million-segment
    program is never held as a million elements); zero-length moves are left out."""
    for lo in range(first, len(segments), ELEMENT_CHUNK):
        chunk = segments[lo:lo + ELEMENT_CHUNK]
        columns = [chunk[name].tolist() for name in ("kind", "start", "end", "center", "cw", "turns", "feed", "tolerance",
                                                     "jet", "aux", "outputs", "line", "dwell")]
        for k, (kind, start, end, center, cw, turns, feed, tol, jet, aux, outputs, line, dwell) in enumerate(zip(*columns)):
            e = Element(
                kind=kind, start=tuple(start), end=tuple(end), center=tuple(center) if kind == ARC else None, cw=cw,
                turns=turns, feed_mm_s=math.inf if kind == RAPID or not math.isfinite(feed) else feed / 60.0,
                tolerance_mm=tol, jet=jet, aux=aux, outputs=outputs, segment=lo + k, line=line, dwell_s=dwell,
            )
            if kind == DWELL or e.length_mm > 0.0:
                yield e


def blend_corners(elements: list[Element], stop_before: frozenset[int] = frozenset(), memo: dict | None = None) -> list[Element]:
    """Replace each blendable corner (two straight moves, or a kink at an arc) by a tangent arc within its tolerance,
    except the corners into the elements of the segments in `stop_before` (exact stops there). `memo`: each
    corner's blend by its index, kept between calls on the same elements (the planner blends a run
    again with some corners stopped at; the others' blends are the same)."""
    memo = {} if memo is None else memo
    if len(elements) < 2:
        return list(elements)
    cut_start = [0.0] * len(elements)  # how much each line loses at its start / end to blends
    cut_end = [0.0] * len(elements)
    new_start: dict[int, tuple] = {}  # an arc's new start / end point, where a blend trims it
    new_end: dict[int, tuple] = {}
    blends: dict[int, Element] = {}  # blend arc inserted after element i
    for i in range(len(elements) - 1):
        a, b = elements[i], elements[i + 1]
        if b.segment in stop_before:
            continue
        if a.kind == ARC or b.kind == ARC:  # a kink where an arc meets a line or another arc
            fillet = memo[i] if i in memo else memo.setdefault(i, _fillet(a, b))
            if fillet is None:
                continue
            p0, p1, center, left = fillet
            for k, e, point, lines, arcs in ((i, a, p0, cut_end, new_end), (i + 1, b, p1, cut_start, new_start)):
                if e.kind == ARC:
                    arcs[k] = point
                else:
                    lines[k] = math.dist(point[:2], a.end[:2])
            blends[i] = Element(
                kind=ARC, start=p0, end=p1, center=center, cw=not left, turns=0, feed_mm_s=min(a.feed_mm_s, b.feed_mm_s),
                tolerance_mm=min(a.tolerance_mm, b.tolerance_mm), jet=a.jet, aux=a.aux, outputs=a.outputs,
                segment=b.segment, line=b.line, blend=True,
            )
            continue
        radius, phi = memo[i] if i in memo else memo.setdefault(i, _blend_radius(a, b))
        if radius <= 0.0:
            continue
        t = radius * math.tan(phi / 2.0)
        cut_end[i] = cut_start[i + 1] = t
        u1, u2 = a.direction_at_end(), b.direction_at_start()
        corner = a.end
        p0 = (corner[0] - u1[0] * t, corner[1] - u1[1] * t, corner[2])
        p1 = (corner[0] + u2[0] * t, corner[1] + u2[1] * t, corner[2])
        left = u1[0] * u2[1] - u1[1] * u2[0] > 0.0  # the path turns left: the centre is on the left
        n = (-u1[1], u1[0]) if left else (u1[1], -u1[0])
        center = (p0[0] + n[0] * radius, p0[1] + n[1] * radius)
        # a blended rapid corner stays a rapid: its infinite feed leaves the speed to the axis limits
        blends[i] = Element(
            kind=ARC, start=p0, end=p1, center=center, cw=not left, turns=0,
            feed_mm_s=min(a.feed_mm_s, b.feed_mm_s), tolerance_mm=min(a.tolerance_mm, b.tolerance_mm),
            jet=a.jet, aux=a.aux, outputs=a.outputs, segment=b.segment, line=b.line, blend=True,
        )
    out: list[Element] = []
    for i, e in enumerate(elements):
        if cut_start[i] or cut_end[i]:
            e = _shortened(e, cut_start[i], cut_end[i])
        elif i in new_start or i in new_end:
            e = _trimmed_arc(e, new_start.get(i, e.start), new_end.get(i, e.end))
        out.append(e)
        if i in blends:
            out.append(blends[i])
    return out


def blends(a: Element, b: Element) -> bool:
    """Whether `blend_corners` may blend the corner a -> b (the planner may still stop there)."""
    if a.kind == ARC or b.kind == ARC:
        return _fillet(a, b) is not None
    return _blend_radius(a, b)[0] > 0.0


def _blend_radius(a: Element, b: Element) -> tuple[float, float]:
    """(radius, turn) of the blend at the corner a->b, radius 0 when the corner must be an exact stop."""
    if a.kind not in (LINE, RAPID) or b.kind not in (LINE, RAPID) or (a.kind == RAPID) != (b.kind == RAPID):
        return 0.0, 0.0
    tol = min(a.tolerance_mm, b.tolerance_mm) * BLEND_SHARE - _corner_off_path(a, b)
    if tol <= 0.0 or (a.jet, a.aux, a.outputs) != (b.jet, b.aux, b.outputs):
        return 0.0, 0.0
    if a.start[2] != a.end[2] or b.start[2] != b.end[2]:
        return 0.0, 0.0
    u1, u2 = a.direction_at_end(), b.direction_at_start()
    phi = math.acos(max(-1.0, min(1.0, u1[0] * u2[0] + u1[1] * u2[1])))
    if phi < COLLINEAR_RAD or phi > math.pi - 1e-3:
        return 0.0, phi  # straight on (nothing to blend) or a reversal (stop)
    by_tolerance = tol / (1.0 - math.cos(phi / 2.0))
    by_length = 0.5 * min(a.length_mm, b.length_mm) / math.tan(phi / 2.0)
    return min(by_tolerance, by_length), phi


def _corner_off_path(a: Element, b: Element) -> float:
    """How far the corner a -> b lies off the programmed path: 0, but where the planner folded a
    small arc into it (`sections._fold_small_turns`): a blend there keeps the rest of its share of
    P, so that blend and smoothing still keep within P of the arc and the lines as programmed."""
    if a.programmed is None or b.programmed is None:
        return 0.0
    return float(distance_to(np.array([a.end[:2]]), [*a.programmed, *b.programmed])[0])


def _fillet(a: Element, b: Element) -> tuple[tuple, tuple, tuple[float, float], bool] | None:
    """The blend of a kink where an arc meets a line or another arc: (point on a, point on b,
    centre, turns left) of the circle tangent to both, on the inside of the turn, whose distance
    from the corner is at most half the tolerance (as for two lines) and which trims at most half
    of either neighbour; None where the corner must be an exact stop.

    The centre lies at the blend's radius R from both curves: on the line offset by R, on the
    circle of radius r -+ R about an arc's centre (minus where the turn's inside is the arc's
    own centre side). R starts at the two lines' value, tol / (1 - cos(phi/2)), and shrinks
    until the corner's distance |C - centre| - R is within the tolerance and both trims fit."""
    if RAPID in (a.kind, b.kind) or a.kind == DWELL or b.kind == DWELL:
        return None
    if (a.kind == ARC and a.turns) or (b.kind == ARC and b.turns):
        return None
    tol = min(a.tolerance_mm, b.tolerance_mm) * BLEND_SHARE - _corner_off_path(a, b)
    if tol <= 0.0 or (a.jet, a.aux, a.outputs) != (b.jet, b.aux, b.outputs):
        return None
    if a.start[2] != a.end[2] or b.start[2] != b.end[2]:
        return None
    u1, u2 = a.direction_at_end(), b.direction_at_start()
    phi = math.acos(max(-1.0, min(1.0, u1[0] * u2[0] + u1[1] * u2[1])))
    if phi < COLLINEAR_RAD or phi > math.pi - 1e-3:
        return None
    left = u1[0] * u2[1] - u1[1] * u2[0] > 0.0
    corner = a.end
    # as for two lines: within the tolerance, and trimming at most half of the shorter neighbour
    radius = min(tol / (1.0 - math.cos(phi / 2.0)), 0.5 * min(a.length_mm, b.length_mm) / math.tan(phi / 2.0))
    for _ in range(40):
        centre = _fillet_centre(a, b, radius, left, corner)
        if centre is not None:
            p0, p1 = _touch(a, centre, radius), _touch(b, centre, radius)
            dev = math.hypot(corner[0] - centre[0], corner[1] - centre[1]) - radius
            turn = abs(sweep(p0[0], p0[1], p1[0], p1[1], centre[0], centre[1], not left, 0))
            if (dev <= tol * (1.0 + 1e-9) and math.dist(p0, p1) > 1e-9 and turn < math.pi
                    and _trim_fits(a, p0, at_end=True) and _trim_fits(b, p1, at_end=False)):
                z = corner[2]
                return (p0[0], p0[1], z), (p1[0], p1[1], z), centre, left
        radius *= 0.7
        if radius < 1e-4:  # a blend this tight is slower than a stop: the corner is one
            return None
    return None


def _fillet_centre(a: Element, b: Element, radius: float, left: bool, corner) -> tuple[float, float] | None:
    """The centre of the circle of `radius` tangent to a and b on the inside of the turn, the
    solution nearest the corner (None when the offset curves do not meet)."""
    curves = [_offset(e, radius, left, at_end) for e, at_end in ((a, True), (b, False))]
    if any(c is None for c in curves):
        return None
    (ka, pa, qa), (kb, pb, qb) = curves
    if ka == "line" and kb == "line":
        return None
    if ka == "line":
        candidates = _line_circle(pa, qa, pb, qb)
    elif kb == "line":
        candidates = _line_circle(pb, qb, pa, qa)
    else:
        candidates = _circle_circle(pa, qa, pb, qb)
    if not candidates:
        return None
    return min(candidates, key=lambda c: math.hypot(c[0] - corner[0], c[1] - corner[1]))


def _offset(e: Element, radius: float, left: bool, at_end: bool):
    """e's offset by `radius` to the inside of the turn: ("line", point, direction) or ("circle", centre, radius)."""
    if e.kind == ARC:
        r = math.hypot(e.start[0] - e.center[0], e.start[1] - e.center[1])
        towards_centre = (not e.cw) == left  # a CCW arc's centre is on its left
        rho = r - radius if towards_centre else r + radius
        return ("circle", e.center, rho) if rho > 1e-9 else None
    u = e.direction_at_end() if at_end else e.direction_at_start()
    n = (-u[1], u[0]) if left else (u[1], -u[0])
    p = e.end if at_end else e.start
    return "line", (p[0] + n[0] * radius, p[1] + n[1] * radius), u


def _line_circle(p, u, c, rho) -> list[tuple[float, float]]:
    fx, fy = p[0] - c[0], p[1] - c[1]
    b = u[0] * fx + u[1] * fy
    disc = b * b - (fx * fx + fy * fy - rho * rho)
    if disc < 0.0:
        return []
    root = math.sqrt(disc)
    return [(p[0] + u[0] * t, p[1] + u[1] * t) for t in (-b - root, -b + root)]


def _circle_circle(c1, r1, c2, r2) -> list[tuple[float, float]]:
    dx, dy = c2[0] - c1[0], c2[1] - c1[1]
    d = math.hypot(dx, dy)
    if d < 1e-12 or d > r1 + r2 or d < abs(r1 - r2):
        return []
    along = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d)
    h = math.sqrt(max(r1 * r1 - along * along, 0.0))
    mx, my = c1[0] + dx * along / d, c1[1] + dy * along / d
    return [(mx - dy * h / d, my + dx * h / d), (mx + dy * h / d, my - dx * h / d)]


def _touch(e: Element, centre: tuple[float, float], radius: float) -> tuple[float, float]:
    """Where the blend circle about `centre` touches e."""
    if e.kind == ARC:
        cx, cy = e.center
        r = math.hypot(e.start[0] - cx, e.start[1] - cy)
        d = math.hypot(centre[0] - cx, centre[1] - cy)
        return cx + (centre[0] - cx) * r / d, cy + (centre[1] - cy) * r / d
    u = e.direction_at_start()
    t = (centre[0] - e.start[0]) * u[0] + (centre[1] - e.start[1]) * u[1]
    return e.start[0] + u[0] * t, e.start[1] + u[1] * t


def _trim_fits(e: Element, point: tuple[float, float], at_end: bool) -> bool:
    """`point` lies on e, on its half next to the corner (neighbouring blends never overlap)."""
    if e.kind == ARC:
        cx, cy = e.center
        whole = abs(e.sweep_rad)
        a_pt = math.atan2(point[1] - cy, point[0] - cx)
        a_corner = math.atan2((e.end if at_end else e.start)[1] - cy, (e.end if at_end else e.start)[0] - cx)
        turn = (a_corner - a_pt) if at_end else (a_pt - a_corner)
        trimmed = turn % (2.0 * math.pi) if not e.cw else (-turn) % (2.0 * math.pi)
        return 0.0 < trimmed <= 0.5 * whole
    u = e.direction_at_start()
    corner = e.end if at_end else e.start
    t = (corner[0] - point[0]) * u[0] + (corner[1] - point[1]) * u[1]
    t = t if at_end else -t
    return 0.0 < t <= 0.5 * e.length_mm


def arc_pieces(e: Element, fractions: list[float]) -> list[Element]:
    """An arc cut at these fractions of its sweep (rising, each strictly between 0 and 1): the
    same circle, line, segment and controls in each piece. A piece's sweep is set, not worked
    back from its ends, so the pieces add up to the arc whatever its size (a piece's ends could
    read as the other way round a nearly full circle)."""
    cx, cy = e.center
    r0 = math.hypot(e.start[0] - cx, e.start[1] - cy)
    dr = math.hypot(e.end[0] - cx, e.end[1] - cy) - r0  # a programmed end a hair off the circle: the radius
    # changes along the arc (`PathArrays.points`), and along its pieces alike
    a0, whole = math.atan2(e.start[1] - cy, e.start[0] - cx), e.sweep_rad
    z0, dz = e.start[2], e.end[2] - e.start[2]
    cuts = [((r0 + dr * f) * math.cos(a0 + whole * f) + cx, (r0 + dr * f) * math.sin(a0 + whole * f) + cy, z0 + dz * f)
            for f in fractions]
    ends = [e.start, *cuts, e.end]
    bounds = [0.0, *fractions, 1.0]
    pieces = []
    for k in range(len(ends) - 1):
        piece = _trimmed_arc(e, ends[k], ends[k + 1])
        piece._sweep = whole * (bounds[k + 1] - bounds[k])
        pieces.append(piece)
    return pieces


def _trimmed_arc(e: Element, start: tuple, end: tuple) -> Element:
    return Element(
        e.kind, tuple(start), tuple(end), e.center, e.cw, 0, e.feed_mm_s, e.tolerance_mm, e.jet, e.aux, e.outputs,
        e.segment, e.line, e.dwell_s, e.blend,
    )


def _shortened(e: Element, at_start: float, at_end: float) -> Element:
    u = e.direction_at_start()
    s = (e.start[0] + u[0] * at_start, e.start[1] + u[1] * at_start, e.start[2])
    t = (e.end[0] - u[0] * at_end, e.end[1] - u[1] * at_end, e.end[2])
    return Element(
        e.kind, s, t, e.center, e.cw, e.turns, e.feed_mm_s, e.tolerance_mm, e.jet, e.aux, e.outputs,
        e.segment, e.line, e.dwell_s, e.blend,
    )


def sample(elements: list[Element], step_mm: float = 0.01) -> np.ndarray:
    """Points along the path (XY), every `step_mm` or closer, ends included."""
    pts = []
    for e in elements:
        if e.kind == DWELL:
            continue
        n = max(2, int(math.ceil(e.length_mm / step_mm)) + 1)
        t = np.linspace(0.0, 1.0, n)
        if e.kind == ARC:
            cx, cy = e.center
            r = math.hypot(e.start[0] - cx, e.start[1] - cy)
            a0 = math.atan2(e.start[1] - cy, e.start[0] - cx)
            ang = a0 + t * e.sweep_rad
            pts.append(np.stack((cx + r * np.cos(ang), cy + r * np.sin(ang)), axis=1))
        else:
            p0, p1 = np.array(e.start[:2]), np.array(e.end[:2])
            pts.append(p0 + t[:, None] * (p1 - p0))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def deviation(path: list[Element], programmed: list[Element], step_mm: float = 0.01) -> np.ndarray:
    """Distance of each sample of `path` to the nearest point of the `programmed` geometry (mm)."""
    return distance_to(sample(path, step_mm), programmed)


def distance_to(pts: np.ndarray, programmed: list[Element]) -> np.ndarray:
    """Distance of each XY point (m, 2) to the nearest point of the elements (mm)."""
    best = np.full(len(pts), np.inf)
    for e in programmed:
        if e.kind == DWELL:
            continue
        if e.kind == ARC:
            best = np.minimum(best, _distance_to_arc(pts, e))
        else:
            best = np.minimum(best, _distance_to_segment(pts, e.start[:2], e.end[:2]))
    return best


def distance_to_programmed(pts: np.ndarray, near: list[Element]) -> np.ndarray:
    """How far each XY point (m, 2) may be from the path as programmed near a corner: its distance
    to the nearest of the elements `near` (`overlap._near_corner`), where that is a blend (an arc the
    planner put into a corner, `blend_corners`) plus the most the blend strays from the
    corner's own elements (its share of P, `BLEND_SHARE`). A point within P of a blend may
    lie half as far again from the programmed lines: a connection through a corner next to a
    blended one passed P so (by 0.011 mm at P 0.2, a random CAM part)."""
    plain = [e for e in near if not e.blend]
    best = distance_to(pts, plain) if plain else np.full(len(pts), np.inf)
    for e in near:
        if e.blend:
            best = np.minimum(best, distance_to(pts, [e]) + e.tolerance_mm * BLEND_SHARE)
    return best


def _distance_to_segment(pts: np.ndarray, a, b) -> np.ndarray:
    a, b = np.asarray(a), np.asarray(b)
    ab = b - a
    denom = float(ab @ ab)
    t = np.clip(((pts - a) @ ab) / denom, 0.0, 1.0) if denom > 0 else np.zeros(len(pts))
    proj = a + t[:, None] * ab
    return np.hypot(pts[:, 0] - proj[:, 0], pts[:, 1] - proj[:, 1])


def _distance_to_arc(pts: np.ndarray, e: Element) -> np.ndarray:
    """Distance to an arc as it is run: an end a hair off the start's circle makes it a spiral
    between the two radii (`PathArrays.points`), and the overlap's and blends' checks within P
    must measure against that, not against the start's circle (a CAM arc's end off by 30 nm let
    an overlap pass P by 12 nm). Arcs of several turns: the nearest turn counts."""
    cx, cy = e.center
    r0 = math.hypot(e.start[0] - cx, e.start[1] - cy)
    dr = math.hypot(e.end[0] - cx, e.end[1] - cy) - r0
    a0 = math.atan2(e.start[1] - cy, e.start[0] - cx)
    sweep = abs(e.sweep_rad)
    ang = np.arctan2(pts[:, 1] - cy, pts[:, 0] - cx)
    along = np.mod((ang - a0) * (1.0 if e.sweep_rad >= 0 else -1.0), 2.0 * math.pi)
    dist = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy)
    radial = np.full(len(pts), np.inf)
    for turn in range(int(sweep // (2.0 * math.pi)) + 1):
        angle = along + 2.0 * math.pi * turn
        frac = np.minimum(angle / sweep, 1.0) if sweep > 0.0 else np.zeros(len(pts))
        radial = np.where((angle <= sweep) | (turn == 0), np.minimum(radial, np.abs(dist - (r0 + frac * dr))), radial)
    if sweep >= 2.0 * math.pi - 1e-9:
        return radial
    ends = np.minimum(
        np.hypot(pts[:, 0] - e.start[0], pts[:, 1] - e.start[1]), np.hypot(pts[:, 0] - e.end[0], pts[:, 1] - e.end[1])
    )
    return np.where(along <= sweep, radial, ends)
