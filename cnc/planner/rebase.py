"""A loaded program started from where the head now is, without interpreting it again.

A program's first move starts where the head stands, and so may more of it: an axis the program
never names stays where it was, G91 moves add up from the start, a G92 taken there shifts what
follows. When the head moved between loading and cycle start, the program must run as if it had
been interpreted from the new position; interpreting a million lines again at the start would
keep the operator waiting seconds.

At load the planner interprets the program a second time from a probe position, a fraction of a
millimetre away on each axis. Comparing the two gives, for every coordinate of every segment,
whether it moves with the start: then by exactly the probe's offset (1) or not at all (0). A
program whose every coordinate does one or the other is a pure shift of its start (`StartShift`),
and starting it from anywhere is adding the head's displacement to the coordinates that move. A
program where anything else changes with the start (an R-format arc from the start point, an
inverse-time feed on the first move, a kerf lead-in whose direction depends on where it comes
from) is not, and is interpreted again at the start as before.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from gcode.program import Program

PROBE_MM = (0.375, 0.25, 0.3125)  # the probe start's offset per axis: exact in binary, unlike any CAM grid
_SAME = ("kind", "cw", "turns", "tolerance", "jet", "aux", "outputs", "dwell", "line")
_MOVING = (("start", 3), ("end", 3), ("center", 2))


@dataclass(frozen=True)
class StartShift:
    """Which coordinates of a program move with its start: `rows` the segments with any, `moves`
    per such segment the 8 flags (start xyz, end xyz, centre xy)."""

    rows: np.ndarray
    moves: np.ndarray  # (len(rows), 8) bool

    def apply(self, program: Program, delta: tuple[float, float, float]) -> Program:
        """`program` as interpreted from a start `delta` (mm, xyz) away from its own."""
        segments = program.segments.copy()
        if len(self.rows):
            d = np.asarray(delta, dtype=float)
            part = segments[self.rows]
            part["start"] += self.moves[:, 0:3] * d
            part["end"] += self.moves[:, 3:6] * d
            part["center"] += self.moves[:, 6:8] * d[:2]
            segments[self.rows] = part
        return dataclasses.replace(program, segments=segments)


def start_shift(program: Program, probe: Program, offset: tuple[float, float, float]) -> StartShift | None:
    """How `program` moves with its start, from `probe` (the same text interpreted from a start
    `offset` away); None when the change is not a pure shift of some coordinates."""
    a, b = program.segments, probe.segments
    if len(a) != len(b) or len(program.messages) != len(probe.messages):
        return None
    for name in _SAME:
        if not np.array_equal(a[name], b[name]):
            return None
    if not np.array_equal(a["feed"], b["feed"], equal_nan=True):
        return None
    off = np.asarray(offset, dtype=float)
    flags = []
    for name, width in _MOVING:
        for axis in range(width):
            d = b[name][:, axis] - a[name][:, axis]
            if off[axis] == 0.0:
                if np.any(np.abs(d) > 1e-9):
                    return None
                flags.append(np.zeros(len(a), dtype=bool))
                continue
            ratio = d / off[axis]
            moves = np.abs(ratio - 1.0) <= 1e-6
            if not np.all(moves | (np.abs(ratio) <= 1e-6)):
                return None
            flags.append(moves)
    table = np.stack(flags, axis=1) if flags else np.zeros((len(a), 8), dtype=bool)
    rows = np.flatnonzero(table.any(axis=1))
    return StartShift(rows, table[rows])
