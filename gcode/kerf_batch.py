"""Kerf compensation of the general path's moves in batches: what a subroutine nest needs.

A nest whose parts are O-word subroutine calls runs every contour move through the general
path, and `KerfCompensator` then offsets each one in Python (about half of the program's
interpretation time). `BatchedKerfCompensator` takes the same calls but, while a compensated
stretch (G41/G42 .. G40 and its exit move) holds nothing but plain lines and arcs, only
records its programmed moves; complete stretches wait in a queue with whatever passed the
compensator between them (rapids, jet events, dwells), and are offset together with numpy
(`kerf_bulk.compensate_each`, the rules and formulas of `kerf`) when the queue is long, when
the program ends or stops, and before the fast path hands on moves of its own. The queue then
goes to the program builder's arrays in one step (`_to_builder`), pieces, moves, dwells and
messages in their order, pierces counted as the builder counts them.

Nothing changes for the program: the pieces, their order and the events between them are
those of the per-move compensator (the equivalence tests compare the two). A stretch the bulk
rules do not cover (an entry arc, a rapid, pure Z move, event or dwell inside, a corner whose
offset paths do not meet, a gouge) is replayed through the per-move compensator in its place,
which reports its errors with their line and column. Errors keep their order too: before the
interpreter reports an error of its own, `earlier_error` offsets what is still queued, and
an error there (an earlier line) is the one reported.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from . import kerf_bulk
from .canon import ARC, DWELL, LINE, Event, Move
from .errors import GCodeError
from .fastpath import piece_geometry
from .kerf import XY_EPS_MM, KerfCompensator, Sink, _xy_length
from .program import ProgramBuilder

QUEUE_MOVES = 8192  # offset the queued stretches once they hold this many moves
_NO_CENTRE = (0.0, 0.0)


@dataclass(slots=True)
class _Stretch:
    """One compensated stretch as programmed, waiting to be offset."""

    side: int
    radius_mm: float
    start_at: tuple[int, int]  # line and column of the G41/G42
    inch: bool  # the program's units then (G20), for the gouge check of a replay
    moves: list[Move] = field(default_factory=list)  # entry move first
    stop_at: tuple[int, int] | None = None  # line and column of the G40, once read
    exit: Move | None = None  # the exit move, once read: the stretch is complete


class BatchedKerfCompensator(KerfCompensator):
    """`KerfCompensator` with plain stretches offset in batches (see the module docstring)."""

    def __init__(self, sink: Sink, batching: bool = True) -> None:
        super().__init__(sink)
        self._open: _Stretch | None = None  # the stretch being recorded
        self._queue: list[_Stretch | tuple[Move | Event, bool]] = []  # in program order
        self._queued_moves = 0
        self._enabled = batching  # off: exactly the per-move compensator (equivalence tests)
        self._batching = batching  # also off while a stretch is replayed through the per-move compensator
        self.offset_in_bulk = 0  # stretches offset in batches, and replayed per move (for the tests)
        self.replayed = 0

    @property
    def idle(self) -> bool:
        return self._open is None and super().idle

    def start(self, side: int, radius_mm: float, line: int, column: int) -> None:
        if self._open is not None:  # G41/G42 between G40 and its exit move
            self._give_up_open()
        idle_before = super().idle
        super().start(side, radius_mm, line, column)  # checks, and the sign of the radius
        if self._batching and idle_before and self._radius_mm > 0.0:
            self._open = _Stretch(self._side, self._radius_mm, (line, column), self.inch)
            self._entry_pending = False

    def stop(self, line: int, column: int) -> None:
        st = self._open
        if st is not None:
            if st.moves:
                st.stop_at = (line, column)
                self._side = 0
                return
            self._give_up_open()
        super().stop(line, column)

    def move(self, m: Move) -> None:
        st = self._open
        if st is not None:
            if st.stop_at is None:
                if m.kind == ARC or (m.kind == LINE and _xy_length(m) > XY_EPS_MM):
                    st.moves.append(m)
                    return
            elif m.kind != ARC and m.kind != DWELL:
                st.exit = m
                self._open = None
                self._queue.append(st)
                self._queued_moves += len(st.moves) + 1
                if self._queued_moves >= QUEUE_MOVES:
                    self.drain()
                return
            self._give_up_open()
        super().move(m)

    def event(self, e: Event) -> None:
        if self._open is not None:
            self._give_up_open()
        super().event(e)

    def flush(self) -> None:
        if self._open is not None:
            self._give_up_open()
        super().flush()
        self.drain()

    def moved_to(self, point: tuple[float, float, float]) -> None:
        self.drain()
        super().moved_to(point)

    def drain(self) -> None:
        """Offset and hand on everything queued, in order (the open stretch stays open)."""
        while self._queue:
            queue, self._queue, self._queued_moves = self._queue, [], 0
            pieces = self._offset([q for q in queue if isinstance(q, _Stretch)])
            builder = self._sink if isinstance(self._sink, ProgramBuilder) else None
            run: list = []  # what goes to the program builder in one step
            k = 0
            for item in queue:
                if isinstance(item, _Stretch):
                    done = pieces[k]
                    k += 1
                    if done is None:
                        if run:
                            self._to_builder(builder, run)
                            run = []
                        self.replayed += 1
                        self._replay(item)
                        continue
                    self.offset_in_bulk += 1
                    if builder is not None:
                        run.append(done)
                    else:
                        self._hand_on_pieces(done)
                elif builder is not None and _bulk_item(item[0]):
                    run.append(item)
                else:
                    if run:
                        self._to_builder(builder, run)
                        run = []
                    m, chained = item
                    if isinstance(m, Move) and m.kind != DWELL:
                        super()._emit(m, chained)
                    else:
                        super()._pass(m)
            if run:
                self._to_builder(builder, run)

    def _to_builder(self, builder: ProgramBuilder, run: list) -> None:
        """Offset stretches and the moves, dwells and events between them into the program
        builder's arrays in one step: what `_emit` and `_pass` would do item by item (each
        chained move starts where the last move handed on ends; a jet-off event makes the next
        cut pierce again; messages keep their place before the next segment)."""
        src: list[int] = []  # batch piece index of each piece segment
        dst: list[int] = []  # and its segment index in this run
        own: list[tuple] = []  # (segment, kind, start, end, centre, cw, turns, feed, line, attrs, dwell)
        chained: list[int] = []  # segments whose start is where the last move ended
        events: list[tuple[int, Event]] = []  # (segments before it, message event)
        jet_offs: list[int] = []  # segments before each jet-off event
        n = 0
        every = None
        for item in run:
            if isinstance(item, _Pieces):
                every = item.every
                count = item.stop - item.first
                src.extend(range(item.first, item.stop))
                dst.extend(range(n, n + count))
                chained.append(n)
                n += count
                continue
            m, chain = item
            if isinstance(m, Move):
                own.append((n, m.kind, m.start, m.end, m.center, m.cw, m.turns, m.feed, m.line, m.attrs, 0.0))
                if chain:
                    chained.append(n)
                n += 1
            elif m.kind == "dwell":
                d = m.data
                p = d["position"]
                own.append((n, DWELL, p, p, None, False, 0, math.nan, m.line, _DwellAttrs(d), d["seconds"]))
                n += 1
            elif m.kind == "jet":
                if not m.data["on"]:
                    jet_offs.append(n)
            else:
                events.append((n, m))
        kind = np.empty(n, dtype=np.uint8)
        start, end, center = np.empty((n, 3)), np.empty((n, 3)), np.zeros((n, 2))
        cw, turns = np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int32)
        feed, dwell, tol = np.empty(n), np.zeros(n), np.empty(n)
        jet, aux, outputs, line = np.zeros(n, dtype=bool), np.empty(n, dtype=np.uint32), np.empty(n, dtype=np.uint32), np.empty(n, dtype=np.int32)
        if src:
            r, at, to = every.result, np.array(src), np.array(dst)
            kind[to], start[to], end[to], center[to], cw[to] = r.kind[at], every.start[at], r.end[at], r.center[at], r.cw[at]
            feed[to], line[to], jet[to], aux[to] = every.feed[at], every.line[at], every.jet[at], every.aux[at]
            outputs[to], tol[to] = every.outputs[at], every.tolerance[at]
        for i, k, s0, e0, c0, cw0, t0, f0, ln, a, dw in own:
            kind[i], start[i], end[i], cw[i], turns[i], feed[i], line[i], dwell[i] = k, s0, e0, cw0, t0, f0, ln, dw
            if c0 is not None:
                center[i] = c0
            jet[i], aux[i], outputs[i], tol[i] = a.jet, a.aux, a.outputs, (0.0 if k == DWELL else a.tolerance_mm)
        moving = kind != DWELL
        # chained starts: the end of the last move before them (in this run, or handed on before it)
        last_move = np.maximum.accumulate(np.where(moving, np.arange(n), -1))
        for i in chained:
            before = int(last_move[i - 1]) if i > 0 else -1
            if before >= 0:
                start[i] = end[before]
            elif self._position is not None:
                start[i] = self._position
        length, lo, hi = piece_geometry(kind[moving], start[moving], end[moving], center[moving], cw[moving])
        full_length = np.zeros(n)
        full_length[moving] = length
        # pierces: a cut with the jet on after a cut with it off, or after a jet-off event
        cut = np.flatnonzero((kind == LINE) | (kind == ARC))
        # offs[i]: jet-off events before segment i (an event recorded at i comes before segment i)
        offs = np.searchsorted(np.array(jet_offs, dtype=np.int64), np.arange(n + 1), side="right") if jet_offs \
            else np.zeros(n + 1, dtype=np.int64)
        was_on = builder._jet_was_on
        if len(cut):
            cj = jet[cut]
            prev_on = np.concatenate(([was_on and offs[cut[0]] == 0], cj[:-1] & (offs[cut[1:]] == offs[cut[:-1]])))
            pierces = int((cj & ~prev_on).sum())
            after = bool(cj[-1]) and int(offs[n]) == int(offs[cut[-1]])
        else:
            pierces, after = 0, was_on and not jet_offs
        base = len(builder.kind)
        builder.extend(
            kind, start, end, center, cw, feed, dwell, jet, aux, line, None, tol, full_length,
            lo.min(axis=0) if len(lo) else np.full(3, np.inf), hi.max(axis=0) if len(hi) else np.full(3, -np.inf),
            pierces, after, outputs=outputs, turns=turns,
        )
        builder._jet_was_on = after  # also when the run was events only (extend then adds nothing)
        for i, e in events:
            builder.message_at(e, base + i)
        if moving.any():
            self._position = tuple(end[np.flatnonzero(moving)[-1]].tolist())

    def earlier_error(self) -> GCodeError | None:
        """The interpreter met an error: the first error among the moves recorded or queued
        before it (they come from earlier lines), or None. Leaves the compensator unusable."""
        st, self._open = self._open, None
        self._side, self._held, self._exit_pending, self._entry_pending = 0, [], False, False
        try:
            self.drain()
            if st is not None:
                self._replay(st)
        except GCodeError as err:
            return err
        return None

    # -- the per-move compensator's output, queued behind stretches still to be offset

    def _emit(self, m: Move, chained: bool) -> None:
        if self._queue:
            self._queue.append((m, chained))
        else:
            super()._emit(m, chained)

    def _pass(self, item: Event | Move) -> None:
        if self._queue:
            self._queue.append((item, False))
        else:
            super()._pass(item)

    # -- stretches the bulk rules do not cover

    def _give_up_open(self) -> None:
        """The open stretch meets something only the per-move compensator handles: run it
        there now, after what is queued (so that an earlier error comes first)."""
        st, self._open = self._open, None
        self._side = 0
        self.drain()
        self.replayed += 1
        self._replay(st)

    def _replay(self, st: _Stretch) -> None:
        """Run a recorded stretch through the per-move compensator, as far as it was read."""
        self._batching, inch_now, self.inch = False, self.inch, st.inch
        try:
            self.start(st.side, st.radius_mm, *st.start_at)
            for m in st.moves:
                self.move(m)
            if st.stop_at is not None:
                self.stop(*st.stop_at)
            if st.exit is not None:
                self.move(st.exit)
        finally:
            self._batching, self.inch = self._enabled, inch_now

    def _offset(self, stretches: list[_Stretch]) -> list["_Pieces | None"]:
        """Each stretch's offset pieces, or None where the bulk rules do not cover it."""
        if not stretches:
            return []
        moves = [m for st in stretches for m in (*st.moves, st.exit)]
        count = np.array([len(st.moves) + 1 for st in stretches])
        n = len(moves)
        ids = np.repeat(np.arange(len(stretches)), count)
        at_first = np.concatenate(([0], np.cumsum(count)[:-1]))
        first = np.zeros(n, dtype=bool)
        first[at_first] = True
        exit_ = np.zeros(n, dtype=bool)
        exit_[at_first + count - 1] = True
        kind = np.fromiter((m.kind for m in moves), dtype=np.uint8, count=n)
        chain = itertools.chain.from_iterable
        start = np.fromiter(chain(m.start for m in moves), float, 3 * n).reshape(n, 3)
        end = np.fromiter(chain(m.end for m in moves), float, 3 * n).reshape(n, 3)
        center = np.fromiter(chain(m.center or _NO_CENTRE for m in moves), float, 2 * n).reshape(n, 2)
        cw = np.fromiter((m.cw for m in moves), dtype=bool, count=n)
        turns = np.fromiter((m.turns for m in moves), dtype=np.int64, count=n)
        side = np.repeat([float(st.side) for st in stretches], count)
        radius = np.repeat([st.radius_mm for st in stretches], count)
        result, bad = kerf_bulk.compensate_each(kind, start, end, center, cw, ids, side, radius, first, exit_)
        bad = bad | (turns != 0)  # multi-turn arcs: the per-move compensator
        bad_stretch = np.zeros(len(stretches), dtype=bool)
        bad_stretch[ids[bad]] = True
        # pieces of stretch k: [bounds[k], bounds[k + 1]); each starts where the one before ends,
        # the first where its entry move starts
        owner = ids[result.source]
        bounds = np.searchsorted(owner, np.arange(len(stretches) + 1))
        piece_start = result.start.copy()
        piece_start[bounds[:-1]] = start[at_first]
        every = _PieceArrays(result, piece_start, moves)
        if isinstance(self._sink, ProgramBuilder):  # what `_to_builder` needs of each piece's programmed move
            attrs, src = [m.attrs for m in moves], result.source
            every.feed = np.array([m.feed for m in moves])[src]
            every.line = np.array([m.line for m in moves], dtype=np.int32)[src]
            every.jet = np.array([a.jet for a in attrs], dtype=bool)[src]
            every.aux = np.array([a.aux for a in attrs], dtype=np.uint32)[src]
            every.outputs = np.array([a.outputs for a in attrs], dtype=np.uint32)[src]
            every.tolerance = np.array([a.tolerance_mm for a in attrs])[src]
        return [None if b else _Pieces(every, int(bounds[k]), int(bounds[k + 1])) for k, b in enumerate(bad_stretch.tolist())]

    def _hand_on_pieces(self, p: "_Pieces") -> None:
        """An offset stretch to a sink that is no program builder, move by move."""
        a, b, every = p.first, p.stop, p.every
        r = every.result
        moves = [every.moves[k] for k in r.source[a:b].tolist()]
        corner = r.corner[a:b].tolist()
        for j, m in enumerate(moves):
            end, centre, cw = tuple(r.end[a + j].tolist()), tuple(r.center[a + j].tolist()), bool(r.cw[a + j])
            if corner[j]:  # the arc around a convex corner, with its move's feed and line
                piece = Move(ARC, m.start, end, centre, cw, 0, m.feed, m.line, m.column, m.attrs)
            elif j == len(moves) - 1:  # the exit move as programmed
                piece = m
            else:
                piece = Move(m.kind, m.start, end, m.center, m.cw, m.turns, m.feed, m.line, m.column, m.attrs)
            KerfCompensator._emit(self, piece, chained=True)


def _bulk_item(item: Move | Event) -> bool:
    """Whether `_to_builder` takes this item: not a dwell passed as a move, nor an arc of
    several turns (`piece_geometry` measures one)."""
    return not isinstance(item, Move) or (item.kind != DWELL and (item.kind != ARC or item.turns == 0))


@dataclass(slots=True)
class _DwellAttrs:
    """A dwell event's output state, read like a move's attributes."""

    jet: bool
    aux: int
    outputs: int

    def __init__(self, data: dict) -> None:
        self.jet, self.aux, self.outputs = bool(data.get("jet", False)), data.get("aux", 0), data.get("outputs", 0)


@dataclass(slots=True)
class _PieceArrays:
    """The offset pieces of every stretch of one batch."""

    result: kerf_bulk.Compensated
    start: np.ndarray  # (n, 3), chained within each stretch
    moves: list[Move]  # the programmed moves, `result.source` indexes them
    feed: np.ndarray | None = None  # per piece, from its programmed move (for a program builder)
    line: np.ndarray | None = None
    jet: np.ndarray | None = None
    aux: np.ndarray | None = None
    outputs: np.ndarray | None = None
    tolerance: np.ndarray | None = None


@dataclass(slots=True)
class _Pieces:
    """One stretch's pieces: [first, stop) of the batch's arrays."""

    every: _PieceArrays
    first: int
    stop: int
