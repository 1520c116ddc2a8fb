"""The canonical stream between the interpreter and its consumers: moves and ordered events.

The interpreter turns blocks into `Move`s (in machine coordinates, mm, mm/min) and `Event`s
(dwell, outputs, messages, stops) in program order. Kerf compensation is a filter on this
stream: it may hold a move back until it knows the next one (to compute the corner), so
events travel in the same stream and keep their place relative to the moves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

RAPID, LINE, ARC, DWELL = 0, 1, 2, 3
KIND_NAMES = {RAPID: "rapid", LINE: "line", ARC: "arc", DWELL: "dwell"}


@dataclass(slots=True)
class Move:
    """One rapid, straight feed or arc in machine coordinates (mm).

    For arcs `center` is (cx, cy) in the XY plane, `cw` the direction and `turns` the number
    of extra full turns (LinuxCNC's P word minus 1; 0 for an ordinary arc). A full circle
    has start == end in XY. Z may change linearly along an arc (a helix).
    `feed` is mm/min (NaN for rapids); `attrs` is carried through unchanged and copied to
    any move kerf compensation inserts (tolerance, jet state, outputs, ...).
    """

    kind: int
    start: tuple[float, float, float]
    end: tuple[float, float, float]
    center: tuple[float, float] | None = None
    cw: bool = False
    turns: int = 0
    feed: float = math.nan
    line: int = 0
    column: int = 0
    attrs: Any = None


@dataclass(slots=True)
class Event:
    """A non-motion item that keeps its place in the stream (dwell, output change, message, stop)."""

    kind: str
    line: int = 0
    data: dict = field(default_factory=dict)
