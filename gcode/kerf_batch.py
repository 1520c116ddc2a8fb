"""Kerf compensation of the general path's moves in batches: what a subroutine nest needs.

A nest whose parts are O-word subroutine calls runs every contour move through the general
path, and `KerfCompensator` then offsets each one in Python (about half of the program's
interpretation time). `BatchedKerfCompensator` takes the same calls but, while a compensated
stretch (G41/G42 .. G40 and its exit move) holds nothing but plain lines and arcs, only
records its programmed moves; complete stretches wait in a queue with whatever passed the
compensator between them (rapids, jet events, dwells), and are offset together with numpy
(`kerf_bulk.compensate_each`, the rules and formulas of `kerf`) when the queue is long, when
the program ends or stops, and before the fast path hands on moves of its own.

Nothing changes for the program: the pieces, their order and the events between them are
those of the per-move compensator (the equivalence tests compare the two). A stretch the bulk
rules do not cover (an entry arc, a rapid, pure Z move, event or dwell inside, a corner whose
offset paths do not meet, a gouge) is replayed through the per-move compensator in its place,
which reports its errors with their line and column. Errors keep their order too: before the
interpreter reports an error of its own, `earlier_error` offsets what is still queued, and
an error there (an earlier line) is the one reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import kerf_bulk
from .canon import ARC, DWELL, LINE, RAPID, Event, Move
from .errors import GCodeError
from .fastpath import piece_geometry
from .kerf import XY_EPS_MM, KerfCompensator, Sink, _xy_length
from .program import ProgramBuilder

QUEUE_MOVES = 8192  # offset the queued stretches once they hold this many moves


@dataclass(slots=True)
class _Stretch:
    """One compensated stretch as programmed, waiting to be offset."""

    side: int
    radius_mm: float
    start_at: tuple[int, int]  # line and column of the G41/G42
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
            self._open = _Stretch(self._side, self._radius_mm, (line, column))
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
            k = 0
            for item in queue:
                if isinstance(item, _Stretch):
                    done = pieces[k]
                    k += 1
                    if done is None:
                        self.replayed += 1
                        self._replay(item)
                    else:
                        self.offset_in_bulk += 1
                        self._hand_on_pieces(done)
                else:
                    m, chained = item
                    if isinstance(m, Move) and m.kind != DWELL:
                        super()._emit(m, chained)
                    else:
                        super()._pass(m)

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
        self._batching = False
        try:
            self.start(st.side, st.radius_mm, *st.start_at)
            for m in st.moves:
                self.move(m)
            if st.stop_at is not None:
                self.stop(*st.stop_at)
            if st.exit is not None:
                self.move(st.exit)
        finally:
            self._batching = self._enabled

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
        start = np.array([m.start for m in moves], dtype=float)
        end = np.array([m.end for m in moves], dtype=float)
        center = np.array([m.center if m.center is not None else (0.0, 0.0) for m in moves], dtype=float)
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
        ok = ~bad_stretch[owner]
        length, lo, hi = piece_geometry(result.kind[ok], piece_start[ok], result.end[ok], result.center[ok], result.cw[ok])
        every = _PieceArrays(result, piece_start, np.zeros(len(owner)), np.zeros((len(owner), 3)), np.zeros((len(owner), 3)), moves)
        every.length[ok], every.lo[ok], every.hi[ok] = length, lo, hi
        return [None if b else _Pieces(every, int(bounds[k]), int(bounds[k + 1])) for k, b in enumerate(bad_stretch.tolist())]

    def _hand_on_pieces(self, p: "_Pieces") -> None:
        """An offset stretch to the sink: into the program builder's arrays in one step when the
        sink is one and the stretch starts where the last move handed on ends, else move by move."""
        a, b, every = p.first, p.stop, p.every
        r = every.result
        source = r.source[a:b].tolist()
        moves = [every.moves[k] for k in source]
        start0 = tuple(every.start[a].tolist())
        sink = self._sink
        if isinstance(sink, ProgramBuilder) and (self._position is None or tuple(self._position) == start0):
            attrs = [m.attrs for m in moves]
            kind, jet = r.kind[a:b], np.array([t.jet for t in attrs], dtype=bool)
            cutting = jet[kind != RAPID]
            before = np.concatenate(([sink._jet_was_on], cutting[:-1]))
            pierces = int((cutting & ~before).sum())
            after = bool(cutting[-1]) if len(cutting) else sink._jet_was_on
            sink.extend(
                kind, every.start[a:b], r.end[a:b], r.center[a:b], r.cw[a:b],
                np.array([m.feed for m in moves]), np.zeros(b - a), jet,
                np.array([t.aux for t in attrs], dtype=np.uint32), np.array([m.line for m in moves], dtype=np.int32),
                attrs[0], np.array([t.tolerance_mm for t in attrs]), every.length[a:b],
                every.lo[a:b].min(axis=0), every.hi[a:b].max(axis=0), pierces, after,
                outputs=np.array([t.outputs for t in attrs], dtype=np.uint32),
            )
            self._position = tuple(r.end[b - 1].tolist())
            return
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


@dataclass(slots=True)
class _PieceArrays:
    """The offset pieces of every stretch of one batch."""

    result: kerf_bulk.Compensated
    start: np.ndarray  # (n, 3), chained within each stretch
    length: np.ndarray
    lo: np.ndarray  # (n, 3) bounds of each piece
    hi: np.ndarray
    moves: list[Move]  # the programmed moves, `result.source` indexes them


@dataclass(slots=True)
class _Pieces:
    """One stretch's pieces: [first, stop) of the batch's arrays."""

    every: _PieceArrays
    first: int
    stop: int
