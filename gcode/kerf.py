"""Kerf compensation (G41/G42/G41.1/G42.1/G40): offsets the programmed XY path by the jet radius, as LinuxCNC does.

The filter sits between the interpreter and the planner. It sees programmed moves and hands
on the path of the jet centre, `radius_mm` to the left (G41) or right (G42) of the programmed
contour. It follows LinuxCNC's cutter compensation move for move, so that `rs274 -g` prints
the same canonical calls for the same program (to its 4 decimals):

Entry. The first XY move after G41/G42 runs from the uncompensated current point to the
programmed end offset perpendicular to *that move* (a line) or radially (an arc; the arc's
centre is moved so that it passes through the current point and the offset end). It must be
longer than the radius, so a pure Z move cannot be the entry move.

Corners. At each later XY move, the turn angle `bend` from the incoming direction (at the
end of the previous move) to the outgoing direction (at the start of this one) is measured
positive away from the jet side:
  - convex (bend > TANGENT_RAD): an arc of the kerf radius around the programmed corner is
    inserted (a straight rapid for G0); it belongs to the outgoing move (its feed, line);
  - tangent (|bend| <= TANGENT_RAD): no arc, the outgoing move starts where the jet is;
  - concave (bend < -TANGENT_RAD, or a reversal): the held incoming move is cut back to the
    intersection of the two offset paths (line/line, line/circle or circle/circle). A
    reversal (|bend - pi| <= TANGENT_RAD) is concave when the jet is outside the arc on either
    side of it (the "top of an h or m" shapes), convex otherwise.
The previous move is therefore held back until the next XY move is known; pure Z moves and
events queue behind it and keep their place (a Z move in a concave corner ends up at the
intersection, like the move before it).

Gouges. Cutting a move back past its own start (a line whose direction reverses, an arc
that would sweep further than programmed), or offset paths that do not meet, mean the jet
cannot reach the concave corner: an error, never a silently rounded corner.

Exit. G40 ends the held move at its offset end; the next move (which must be straight) runs
from there to its programmed end. `flush` (end of program, M0/M1) does the same without
turning compensation off, so a concave corner right after a stop is not joined.

Where rs274 prints something a planner cannot use, we differ: an offset arc that shrinks to
nothing (an inside arc barely larger than the kerf, or an arc cut back to zero length) is
handed on as a straight move, never as an arc whose start equals its end, which reads as a
full circle. Exact tangencies, where LinuxCNC's rounding decides between meeting and an
error, count as meeting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from .arcs import FULL_CIRCLE_EPS_MM, FULL_TURN_EPS_RAD
from .canon import ARC, DWELL, LINE, RAPID, Event, Move
from .errors import GCodeError

LEFT, RIGHT = 1, -1
TANGENT_RAD = 0.05  # LinuxCNC's TOLERANCE_CONCAVE_CORNER: smaller bends get neither arc nor intersection
# A cut-back arc may sweep this much more than programmed before it counts as a gouge. LinuxCNC
# compares the angle with 0.0254 in a G21 program and 0.001 in a G20 one (a length unit's worth,
# compared with an angle: its rule, kept so that an inch program it refuses is refused here too).
SWEEP_SLACK_RAD = 0.0254
SWEEP_SLACK_INCH_RAD = 0.001
ENTRY_ARC_COS_MIN = 1e-4  # below this the entry arc's new centre is at infinity
XY_EPS_MM = 1e-9  # moves shorter than this in XY are pure Z moves
COLLAPSED_MM = 1e-6  # an offset arc whose ends are closer than this has shrunk to nothing

Sink = Callable[[Move | Event], None]
XY = tuple[float, float]

_KEEP = object()


def _with(m: Move, kind=None, start=None, end=None, center=_KEEP, cw=None, turns=None) -> Move:
    """A copy of `m` with some fields changed (dataclasses.replace, at a fraction of the cost)."""
    return Move(
        m.kind if kind is None else kind,
        m.start if start is None else start,
        m.end if end is None else end,
        m.center if center is _KEEP else center,
        m.cw if cw is None else cw,
        m.turns if turns is None else turns,
        m.feed,
        m.line,
        m.column,
        m.attrs,
    )



@dataclass(slots=True)
class _Held:
    """A compensated move waiting for the next corner; `direction` and `sweep_rad` detect reversal."""

    move: Move
    programmed: tuple[XY, XY]  # programmed XY start and end, for messages
    direction: XY | None = None  # programmed XY direction of a line; None: never checked
    sweep_rad: float = 0.0  # programmed sweep of an arc; 0: never checked


class KerfCompensator:
    """Offsets the moves passed to `move` and hands the compensated stream to `sink`."""

    def __init__(self, sink: Sink) -> None:
        self._sink = sink
        self._side = 0  # LEFT, RIGHT or 0 (off)
        self._radius_mm = 0.0
        self._entry_pending = False  # the next XY move is the entry move
        self._exit_pending = False  # the next move is the exit move: straight, from the last offset point
        self._held: list[_Held | Event | Move] = []  # the last XY move and what queued behind it
        self._held_start: XY | None = None  # where the held XY move starts; None: not checked for reversal
        self._last: Move | None = None  # the last compensated XY move, held or not
        self._tool: tuple[float, float, float] | None = None  # where the compensated path ends
        self._position: tuple[float, float, float] | None = None  # end of the last move handed on
        self.inch = False  # the program is in G20 (LinuxCNC's gouge check depends on it)

    @property
    def active(self) -> bool:
        return self._side != 0

    @property
    def idle(self) -> bool:
        """Off, holding nothing, no exit move pending: moves may pass it by (see `moved_to`)."""
        return not self._side and not self._held and not self._exit_pending

    def start(self, side: int, radius_mm: float, line: int, column: int) -> None:
        """G41/G42 (side +1/-1). A negative radius swaps sides, as a negative tool diameter does in LinuxCNC."""
        if side not in (LEFT, RIGHT):
            raise ValueError(f"kerf side must be +1 (left) or -1 (right), not {side!r}")
        if self.active:
            raise GCodeError(
                "kerf compensation is already on; turn it off with G40 before G41/G42",
                code="kerf-state", line=line, column=column,
            )
        if radius_mm < 0.0:
            side, radius_mm = -side, -radius_mm
        self._side, self._radius_mm = side, radius_mm
        self._entry_pending = True

    def stop(self, line: int, column: int) -> None:
        """G40: end the held move at its offset end; the next move is the exit move."""
        if self.active and self._radius_mm > 0.0 and not self._entry_pending:
            self._end_held(line, column)
            self._exit_pending = True
        self._side, self._entry_pending = 0, False

    def move(self, m: Move) -> None:
        """A programmed move (machine coordinates, mm); handed on now, or held until its corner is known."""
        if m.kind == DWELL:
            self._queue_or_emit(m)
            return
        if self._exit_pending:
            if m.kind == ARC:
                raise GCodeError(
                    "the move after G40 (the exit move) must be straight, not an arc",
                    code="kerf-exit", line=m.line, column=m.column,
                )
            self._exit_pending = False
            if not self.active:
                self._emit(m, chained=True)
                return
        if not self.active or self._radius_mm == 0.0:
            self._emit(m, chained=False)
        elif self._entry_pending:
            self._enter(m)
        elif m.kind == ARC:
            self._arc(m)
        elif _xy_length(m) <= XY_EPS_MM:
            self._pure_z(m)
        else:
            self._straight(m)

    def moved_to(self, point: tuple[float, float, float]) -> None:
        """Moves were handed on past the compensator (it is off): the next chained move starts at `point`."""
        if not self.idle:
            raise RuntimeError("moves can be handed on past the compensator only while it is idle")
        self._position = tuple(point)

    def event(self, e: Event) -> None:
        """A non-motion item: handed on now, or queued behind the held move to keep its place."""
        self._queue_or_emit(e)

    def flush(self) -> None:
        """End of program or a stop (M0, M1, M2, M30): emit what is held, the last move ending at its offset end.

        Compensation stays on. A held move found reversed here is reported at its own block.
        """
        self._end_held(None, None)

    # entry

    def _enter(self, m: Move) -> None:
        start, end = _xy(m.start), _xy(m.end)
        distance = math.dist(start, end)
        if distance <= self._radius_mm:
            what = "arc's chord" if m.kind == ARC else "move"
            raise GCodeError(
                f"kerf compensation entry {what} is {distance:.3f} mm long in XY; "
                f"it must be longer than the kerf compensation radius {self._radius_mm:.3f} mm",
                code="kerf-entry", line=m.line, column=m.column,
            )
        if m.kind == ARC:
            entry = self._entry_arc(m)
        else:
            normal = _rotate(_unit_of(_sub(end, start)), self._side)
            entry = _with(m, end=(*_add(end, _scale(normal, self._radius_mm)), m.end[2]))
        # The entry never counts as reversed: cutting it back cannot take its end behind the
        # uncompensated start, only beside it (LinuxCNC does not check it either).
        self._hold(_Held(entry, (start, end)), held_start=None)
        self._entry_pending = False

    def _entry_arc(self, m: Move) -> Move:
        """The arc from the current point to the offset end whose centre lies on the end's radius."""
        center, start, end = m.center, _xy(m.start), _xy(m.end)
        self._check_arc_radius(m, at=start)
        toward_center = _unit_of(_sub(center, end))
        offset_end = _add(end, _scale(toward_center, self._radius_mm if self._inside(m) else -self._radius_mm))
        # The new centre is on the line through offset_end toward the centre, equidistant
        # from offset_end and the start: |c - start| = |c - offset_end| = t along that line.
        chord = _sub(start, offset_end)
        cos_a = _dot(toward_center, chord) / math.hypot(*chord)
        if abs(cos_a) < ENTRY_ARC_COS_MIN:
            raise GCodeError(
                f"no arc through the start and the offset end of the kerf compensation entry arc "
                f"(kerf compensation radius {self._radius_mm:.3f} mm)",
                code="kerf-entry", line=m.line, column=m.column,
            )
        t = math.hypot(*chord) / (2.0 * cos_a)
        new_center = _add(offset_end, _scale(toward_center, t))
        return _with(m, end=(*offset_end, m.end[2]), center=new_center)

    # corners

    def _straight(self, m: Move) -> None:
        corner, end = _xy(m.start), _xy(m.end)
        direction = _sub(end, corner)
        normal = _rotate(_unit_of(direction), self._side)
        incoming = self._incoming()
        bend = self._bend(corner, _angle(direction))
        # A reversal after an arc the jet is outside of is concave, but only while that arc is
        # still held (not after a flush), as in LinuxCNC.
        held_arc = self._first_held_move() is not None and incoming.kind == ARC
        concave = bend < -TANGENT_RAD or bend > math.pi + TANGENT_RAD or (
            bend > math.pi - TANGENT_RAD and held_arc and not self._inside(incoming)
        )

        def meet() -> XY:
            if incoming.kind == ARC:
                return self._arc_meets_line(incoming, corner, direction, m)
            # Two offset lines meet short of the jet's position by r*tan(inside turn/2).
            back = -self._radius_mm * math.tan(bend / 2.0)
            return _sub(self._tool_xy(), _scale(self._incoming_direction(corner), back))

        offset_start = _add(corner, _scale(normal, self._radius_mm))
        anchor = self._join(m, corner, bend, concave, meet, offset_start, check_convex=True)
        start = anchor or self._tool_xy()
        piece = _with(m, start=(*start, m.start[2]), end=(*_add(end, _scale(normal, self._radius_mm)), m.end[2]))
        self._hold(_Held(piece, (corner, end), direction=direction), held_start=anchor)

    def _arc(self, m: Move) -> None:
        corner, end, center = _xy(m.start), _xy(m.end), m.center
        self._check_arc_radius(m, at=end)
        inside = self._inside(m)
        out = -1.0 if inside else 1.0  # the jet is toward the centre when inside the arc
        tangent = _angle(_sub(corner, center)) + (-math.pi / 2 if m.cw else math.pi / 2)
        bend = self._bend(corner, tangent)
        concave = bend < -TANGENT_RAD or bend > math.pi + TANGENT_RAD or (
            abs(bend - math.pi) < TANGENT_RAD and not inside
        )

        def meet() -> XY:
            incoming = self._incoming()
            return self._arcs_meet(incoming, m) if incoming.kind == ARC else self._line_meets_arc(m, corner)

        offset_start = _add(corner, _scale(_unit_of(_sub(corner, center)), out * self._radius_mm))
        anchor = self._join(m, corner, bend, concave, meet, offset_start, check_convex=False)
        start = anchor or self._tool_xy()
        offset_end = _add(end, _scale(_unit_of(_sub(end, center)), out * self._radius_mm))
        if _same_point(corner, end) and math.dist(start, offset_end) < XY_EPS_MM:
            offset_end = start  # a full circle stays one, exactly
        piece = _with(m, start=(*start, m.start[2]), end=(*offset_end, m.end[2]))
        sweep = _sweep_rad(corner, center, _turn(m), end)
        self._hold(_Held(piece, (corner, end), sweep_rad=sweep), held_start=anchor)

    def _join(
        self, m: Move, corner: XY, bend: float, concave: bool,
        meet: Callable[[], XY], offset_start: XY, check_convex: bool,
    ) -> XY | None:
        """Joins the held move to `m` at `corner`; returns where `m` starts, None if nothing was held to join.

        A tangent join starts `m` where the jet is. Before a convex corner arc LinuxCNC checks
        the held move for reversal when a line follows but not when an arc does.
        """
        if concave:
            return self._release_at(meet(), corner, m.line, m.column)
        if bend > TANGENT_RAD:
            if check_convex:
                self._release_at(self._tool_xy(), corner, m.line, m.column)
            else:
                self._release_unchecked()
            self._emit_corner(m, corner, offset_start)
            return offset_start
        self._release_unchecked()
        return self._tool_xy()

    def _pure_z(self, m: Move) -> None:
        """No XY motion: queue behind the held move at the jet's XY, so a concave corner moves it too."""
        x, y = self._tool_xy()
        piece = _with(m, start=(x, y, m.start[2]), end=(x, y, m.end[2]))
        self._held.append(_Held(piece, (_xy(m.start), _xy(m.end)), direction=(0.0, 0.0)))
        self._tool = (x, y, m.end[2])

    def _bend(self, corner: XY, outgoing_rad: float) -> float:
        """Turn from the incoming to the outgoing direction, positive away from the jet, in [-pi/2, 3pi/2)."""
        incoming = self._angle_of_incoming(corner)
        turn = self._side * (incoming - outgoing_rad)
        return (turn + math.pi / 2) % (2 * math.pi) - math.pi / 2

    def _angle_of_incoming(self, corner: XY) -> float:
        """Direction of travel where the jet is now: perpendicular to its offset from the programmed corner."""
        offset = _sub(self._tool_xy(), corner)
        return _angle(offset) - self._side * math.pi / 2

    def _incoming_direction(self, corner: XY) -> XY:
        a = self._angle_of_incoming(corner)
        return (math.cos(a), math.sin(a))

    # intersections of offset paths in concave corners

    def _arc_meets_line(self, arc: Move, corner: XY, direction: XY, m: Move) -> XY:
        """Offset line after an arc: where it crosses the arc's offset circle.

        Like LinuxCNC, the line is offset from the corner as seen on the arc's programmed circle
        (the offset radius with the kerf radius taken back off) along the radius through the
        programmed corner. For an exact arc that is the programmed corner itself; an entry arc,
        whose centre moved, or a slightly spiral arc shift it a little.
        """
        radius = math.dist(_xy(arc.end), arc.center)
        nominal = radius + (self._radius_mm if self._inside(arc) else -self._radius_mm)
        unit = _unit_of(direction)
        offset = _scale(_rotate(unit, self._side), self._radius_mm)
        line_point = _add(self._on_circle(arc.center, nominal, corner), offset)
        roots = _line_circle(line_point, unit, arc.center, radius)
        if roots is None:
            raise self._unreachable(m.line, m.column, corner, "the offset arc before it never meets the offset line")
        # Inside the arc the jet meets the line at its first crossing, outside at its second.
        t = roots[0] if self._inside(arc) else roots[1]
        return _add(line_point, _scale(unit, t))

    def _line_meets_arc(self, m: Move, corner: XY) -> XY:
        """Offset line before an arc: where it crosses the arc's offset circle.

        Like LinuxCNC, the line runs through the corner as seen on the circle of the arc's end
        radius, which differs from the programmed corner only for a slightly spiral arc.
        """
        nominal = math.dist(_xy(m.end), m.center)
        radius = nominal + (-self._radius_mm if self._inside(m) else self._radius_mm)
        offset = _sub(self._tool_xy(), corner)
        direction = self._incoming_direction(corner)
        line_point = _add(self._on_circle(m.center, nominal, corner), offset)
        roots = _line_circle(line_point, direction, m.center, radius)
        if roots is None:
            raise self._unreachable(m.line, m.column, corner, "the offset line before it never meets the offset arc")
        # Inside the arc the jet leaves the line at its second crossing, outside at its first.
        t = roots[1] if self._inside(m) else roots[0]
        return _add(line_point, _scale(direction, t))

    @staticmethod
    def _on_circle(center: XY, radius: float, point: XY) -> XY:
        """The point of the circle on the radius through `point`."""
        return _add(center, _scale(_unit_of(_sub(point, center)), radius))

    def _arcs_meet(self, before: Move, m: Move) -> XY:
        """Two offset circles: the crossing on the side given by the first arc's jet side and the second's turn."""
        center0, radius0 = before.center, math.dist(_xy(before.end), before.center)
        radius1 = math.dist(_xy(m.end), m.center) + (-self._radius_mm if self._inside(m) else self._radius_mm)
        between = math.dist(center0, m.center)
        if radius0 == 0.0 or between == 0.0:
            raise self._unreachable(m.line, m.column, _xy(m.start), "the arcs on either side have the same centre")
        cos_a = (radius0**2 + between**2 - radius1**2) / (2.0 * radius0 * between)
        if abs(cos_a) > 1.0:
            raise self._unreachable(m.line, m.column, _xy(m.start), "the offset arcs on either side never meet")
        left = self._inside(before) == (not m.cw)
        a = _angle(_sub(m.center, center0)) + (math.acos(cos_a) if left else -math.acos(cos_a))
        return (center0[0] + radius0 * math.cos(a), center0[1] + radius0 * math.sin(a))

    # the held queue

    def _hold(self, held: _Held, held_start: XY | None) -> None:
        self._held.append(held)
        self._held_start = held_start
        self._last = held.move
        self._tool = held.move.end

    def _end_held(self, line: int | None, column: int | None) -> None:
        """End the held moves where the jet is, at their offset end, and hand them on."""
        first = self._first_held_move()
        if first is not None:
            line = first.move.line if line is None else line
            column = first.move.column if column is None else column
            self._release_at(self._tool_xy(), first.programmed[0], line, column)

    def _release_at(self, point: XY, corner: XY, line: int, column: int) -> XY | None:
        """End every held move at `point` (the jet's corner point) and emit the queue; None if nothing was held."""
        moves = [h for h in self._held if isinstance(h, _Held)]
        if not moves:
            self._release_unchecked()
            return None
        for h in moves:
            if self._reverses(h, point):
                (x0, y0), (x1, y1) = h.programmed
                what = "arc" if h.move.kind == ARC else "line"
                raise self._unreachable(
                    line, column, corner, f"the {what} from X{x0:.3f} Y{y0:.3f} to X{x1:.3f} Y{y1:.3f} is too short"
                )
        for h in moves:
            h.move = _with(h.move, end=(*point, h.move.end[2]))
        self._release_unchecked()
        return point

    def _reverses(self, h: _Held, point: XY) -> bool:
        if self._held_start is None:
            return False
        if h.move.kind == ARC:
            if not h.sweep_rad:
                return False
            # An arc cut back to nothing sweeps a full turn here: a gouge, as in LinuxCNC.
            sweep = _sweep_rad(self._held_start, h.move.center, _turn(h.move), point)
            return abs(sweep) > abs(h.sweep_rad) + (SWEEP_SLACK_INCH_RAD if self.inch else SWEEP_SLACK_RAD)
        return h.direction is not None and _dot(h.direction, _sub(point, self._held_start)) < 0.0

    def _release_unchecked(self) -> None:
        held, self._held, self._held_start = self._held, [], None
        for item in held:
            if isinstance(item, _Held):
                self._emit(_collapsed(item), chained=True)
            else:
                self._pass(item)

    def _emit_corner(self, m: Move, corner: XY, end: XY) -> None:
        """The arc around a convex corner (a straight rapid for G0), at the Z where the jet is."""
        z = self._tool[2]
        if m.kind == RAPID:
            piece = _with(m, start=self._tool, end=(*end, z), center=None, cw=False, turns=0)
        else:
            piece = _with(m, kind=ARC, start=self._tool, end=(*end, z), center=corner,
                            cw=self._side == LEFT, turns=0)
        self._emit(piece, chained=True)

    def _emit(self, m: Move, chained: bool) -> None:
        """Hand a move on; a chained move starts where the previous one handed on ended."""
        if chained and self._position is not None:
            m = _with(m, start=self._position)
        self._sink(m)
        self._position = m.end

    def _pass(self, item: Event | Move) -> None:
        """Hand on an event (or a dwell) as it is."""
        self._sink(item)

    def _queue_or_emit(self, item: Event | Move) -> None:
        if self._held:
            self._held.append(item)
        else:
            self._pass(item)

    # small helpers

    def _incoming(self) -> Move:
        first = self._first_held_move()
        return first.move if first else self._last

    def _first_held_move(self) -> _Held | None:
        return next((h for h in self._held if isinstance(h, _Held)), None)

    def _tool_xy(self) -> XY:
        return _xy(self._tool)

    def _inside(self, arc: Move) -> bool:
        """The jet is inside an arc when the arc turns toward the jet's side."""
        return (self._side == LEFT) != arc.cw

    def _check_arc_radius(self, m: Move, at: XY) -> None:
        """The jet must fit inside an arc it cuts from the inside (radius measured to `at`, as LinuxCNC does)."""
        radius = math.dist(at, m.center)
        if self._inside(m) and radius <= self._radius_mm:
            relation = "is smaller than" if radius < self._radius_mm else "equals"
            raise GCodeError(
                f"arc radius {radius:.3f} mm {relation} kerf compensation radius {self._radius_mm:.3f} mm",
                code="kerf-arc-radius", line=m.line, column=m.column,
            )

    def _unreachable(self, line: int, column: int, corner: XY, why: str) -> GCodeError:
        return GCodeError(
            f"the jet cannot reach the concave corner at X{corner[0]:.3f} Y{corner[1]:.3f} without gouging "
            f"(kerf compensation radius {self._radius_mm:.3f} mm): {why}",
            code="kerf-concave-corner", line=line, column=column,
        )


def _collapsed(h: _Held) -> Move:
    """A partial arc whose offset ends meet became a straight (Z only) move, not a full circle."""
    m = h.move
    partial = not _same_point(*h.programmed)
    if m.kind == ARC and partial and math.dist(_xy(m.start), _xy(m.end)) < COLLAPSED_MM:
        return _with(m, kind=LINE, end=(*_xy(m.start), m.end[2]), center=None, cw=False, turns=0)
    return m


def _xy(p) -> XY:
    return (p[0], p[1])


def _xy_length(m: Move) -> float:
    return math.hypot(m.end[0] - m.start[0], m.end[1] - m.start[1])


def _add(a: XY, b: XY) -> XY:
    return (a[0] + b[0], a[1] + b[1])


def _sub(a: XY, b: XY) -> XY:
    return (a[0] - b[0], a[1] - b[1])


def _scale(a: XY, k: float) -> XY:
    return (a[0] * k, a[1] * k)


def _dot(a: XY, b: XY) -> float:
    return a[0] * b[0] + a[1] * b[1]


def _angle(a: XY) -> float:
    return math.atan2(a[1], a[0])


def _unit_of(a: XY) -> XY:
    length = math.hypot(*a)
    return (a[0] / length, a[1] / length)


def _rotate(a: XY, side: int) -> XY:
    """A quarter turn toward `side`: left (+1) counter-clockwise, right (-1) clockwise."""
    return (-a[1] * side, a[0] * side)


def _turn(arc: Move) -> int:
    """LinuxCNC's signed turn count: +n counter-clockwise, -n clockwise, n = 1 + extra full turns."""
    return -(arc.turns + 1) if arc.cw else arc.turns + 1


def _same_point(a: XY, b: XY) -> bool:
    """One point, to the rounding of the coordinate transforms: a full circle's end as computed
    through a rotated system in G91 misses its start by 1e-14 mm, and must stay a full circle."""
    return math.dist(a, b) < FULL_CIRCLE_EPS_MM


def _sweep_rad(start: XY, center: XY, turn: int, end: XY) -> float:
    """Signed angle swept from start to end about center; start == end (within the angle
    `arcs.sweep` allows, FULL_TURN_EPS_RAD) is a full turn, as the interpreter has it."""
    delta = _angle(_sub(end, center)) - _angle(_sub(start, center))
    if turn > 0:
        return (delta + 2 * math.pi if delta <= FULL_TURN_EPS_RAD else delta) + (turn - 1) * 2 * math.pi
    return (delta - 2 * math.pi if delta >= -FULL_TURN_EPS_RAD else delta) + (turn + 1) * 2 * math.pi


def _line_circle(point: XY, unit: XY, center: XY, radius: float) -> tuple[float, float] | None:
    """Distances t (ascending) along point + t*unit where the line crosses the circle; None if it misses."""
    rel = _sub(point, center)
    b = _dot(unit, rel)
    disc = b * b - (_dot(rel, rel) - radius * radius)
    if disc < 0.0:
        return None
    root = math.sqrt(disc)
    return (-b - root, -b + root)
