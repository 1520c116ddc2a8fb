"""Program: the interpreted result, a numpy structured array of segments plus messages and statistics.

Segments are in machine coordinates, mm and mm/min, in program order. The builder is the
last sink of the canonical stream; it appends into compact per-column arrays (8 bytes a
number, no Python object per segment) and turns them into the numpy array once at the end.
"""

from __future__ import annotations

import json
import math
from array import array
from dataclasses import dataclass, field
from typing import IO

import numpy as np

from .arcs import arc_bounds, arc_length, sweep
from .canon import ARC, DWELL, KIND_NAMES, LINE, RAPID, Event, Move

SEGMENT_DTYPE = np.dtype(
    [
        ("kind", np.uint8),  # RAPID, LINE, ARC, DWELL (gcode.canon)
        ("start", np.float64, (3,)),
        ("end", np.float64, (3,)),
        ("center", np.float64, (2,)),  # arcs only
        ("cw", np.bool_),
        ("turns", np.int32),  # extra full turns of an arc
        ("feed", np.float64),  # mm/min; NaN for rapids and dwells
        ("tolerance", np.float64),  # corner tolerance (G64 P) in mm; 0 = exact stop (G61)
        ("jet", np.bool_),  # jet on during this segment
        ("aux", np.uint32),  # machine outputs from the M-code map (abrasive, aux...) on during this segment
        ("outputs", np.uint32),  # numbered digital outputs (M62-M65 P) on during this segment
        ("dwell", np.float64),  # dwell seconds (DWELL segments)
        ("line", np.int32),  # source line
    ]
)


@dataclass(frozen=True, slots=True)
class Attrs:
    """State that travels with each move: the corner tolerance and the outputs in force."""

    tolerance_mm: float
    jet: bool
    aux: int
    outputs: int


@dataclass
class Message:
    line: int
    segment: int  # index of the segment before which it appears
    kind: str  # "message" (MSG), "stop" (M0), "optional_stop" (M1), "pallet" (M60), "output" (M64/M65), "tool" (M6)
    text: str
    data: dict = field(default_factory=dict)


@dataclass
class Statistics:
    lines: int = 0
    segments: int = 0
    bounds_min: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    bounds_max: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    cut_length_mm: float = 0.0  # feed moves with the jet on
    feed_length_mm: float = 0.0  # all feed moves
    rapid_length_mm: float = 0.0
    pierces: int = 0  # jet off -> on transitions followed by motion
    dwell_s: float = 0.0


@dataclass
class Program:
    """An interpreted, valid program."""

    name: str
    segments: np.ndarray
    messages: list[Message]
    stats: Statistics
    units_final: str = "mm"

    def write_segments_jsonl(self, out: IO[str]) -> None:
        """The exchange format: one JSON object per motion or dwell, machine mm, program order."""
        for s in self.segments:
            kind = int(s["kind"])
            if kind == DWELL:
                out.write(json.dumps({"kind": "dwell", "seconds": float(s["dwell"]), "line": int(s["line"])}) + "\n")
                continue
            rec = {
                "kind": KIND_NAMES[kind],
                "start": [float(v) for v in s["start"]],
                "end": [float(v) for v in s["end"]],
                "feed": None if kind == RAPID else float(s["feed"]),
                "line": int(s["line"]),
            }
            if kind == ARC:
                rec["center"] = [float(v) for v in s["center"]]
                rec["cw"] = bool(s["cw"])
                rec["turns"] = int(s["turns"])
            out.write(json.dumps(rec) + "\n")


class ProgramBuilder:
    """Sink of the canonical stream: collects segments and messages, computes statistics."""

    def __init__(self) -> None:
        self.kind = array("B")
        self.cw = array("B")
        self.jet = array("B")
        self.turns = array("i")
        self.aux = array("I")
        self.outputs = array("I")
        self.line = array("i")
        self.floats = array("d")  # start(3) end(3) center(2) feed tolerance dwell = 11 per segment
        self.messages: list[Message] = []
        self.stats = Statistics()
        self._lo = [math.inf] * 3
        self._hi = [-math.inf] * 3
        self._jet_was_on = False

    def __call__(self, item: Move | Event) -> None:
        if isinstance(item, Move):
            self.move(item)
        else:
            self.event(item)

    def move(self, m: Move) -> None:
        a: Attrs = m.attrs
        cx, cy = m.center if m.center is not None else (0.0, 0.0)
        self.kind.append(m.kind)
        self.cw.append(m.cw)
        self.jet.append(a.jet)
        self.turns.append(m.turns)
        self.aux.append(a.aux)
        self.outputs.append(a.outputs)
        self.line.append(m.line)
        self.floats.extend((*m.start, *m.end, cx, cy, m.feed, a.tolerance_mm, 0.0))
        self._account(m, a)

    def event(self, e: Event) -> None:
        if e.kind == "dwell":
            seconds = e.data["seconds"]
            self.kind.append(DWELL)
            self.cw.append(0)
            self.jet.append(bool(e.data.get("jet", False)))
            self.turns.append(0)
            self.aux.append(e.data.get("aux", 0))
            self.outputs.append(e.data.get("outputs", 0))
            self.line.append(e.line)
            p = e.data["position"]
            self.floats.extend((*p, *p, 0.0, 0.0, math.nan, 0.0, seconds))
            self.stats.dwell_s += seconds
            return
        if e.kind == "jet":
            if not e.data["on"]:
                self._jet_was_on = False  # the next cutting move with the jet on pierces again
            return
        self.message_at(e, len(self.kind))

    def message_at(self, e: Event, segment: int) -> None:
        """A message event that appears before segment `segment` (see `event`)."""
        self.messages.append(Message(e.line, segment, e.kind, e.data.get("text", ""), e.data))

    def _account(self, m: Move, a: Attrs) -> None:
        st = self.stats
        (x0, y0, z0), (x1, y1, z1) = m.start, m.end
        if m.kind == ARC:
            cx, cy = m.center
            r = math.hypot(x0 - cx, y0 - cy)
            swept = sweep(x0, y0, x1, y1, cx, cy, m.cw, m.turns)
            length = arc_length(r, swept, z1 - z0)
            bx0, by0, bx1, by1 = arc_bounds(x0, y0, cx, cy, r, math.atan2(y0 - cy, x0 - cx), swept)
            self._extend(bx0, by0, min(z0, z1), bx1, by1, max(z0, z1))
        else:
            length = math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2 + (z1 - z0) ** 2)
            self._extend(min(x0, x1), min(y0, y1), min(z0, z1), max(x0, x1), max(y0, y1), max(z0, z1))
        if m.kind == RAPID:
            st.rapid_length_mm += length
        else:
            st.feed_length_mm += length
            if a.jet:
                st.cut_length_mm += length
        if m.kind != RAPID:
            if a.jet and not self._jet_was_on:
                st.pierces += 1
            self._jet_was_on = a.jet

    def extend(
        self, kind: np.ndarray, start: np.ndarray, end: np.ndarray, center: np.ndarray, cw: np.ndarray,
        feed: np.ndarray, dwell: np.ndarray, jet: np.ndarray, aux: np.ndarray, line: np.ndarray, attrs: Attrs,
        tolerance: np.ndarray, length: np.ndarray, lo: np.ndarray, hi: np.ndarray, pierces: int, jet_was_on_after: bool,
        outputs: np.ndarray | None = None, turns: np.ndarray | None = None,
    ) -> None:
        """Append a run of segments computed in bulk (the interpreter's fast path, offset contours);
        the same result as `move`/`event` one by one, with pierces counted by the caller.
        `outputs` per segment, or `attrs.outputs` for all; `turns` per segment, or none."""
        n = len(kind)
        if not n:
            return
        self.kind.frombytes(kind.astype(np.uint8).tobytes())
        self.cw.frombytes(cw.astype(np.uint8).tobytes())
        self.jet.frombytes(jet.astype(np.uint8).tobytes())
        self.turns.frombytes((np.zeros(n) if turns is None else turns).astype(np.int32).tobytes())
        self.aux.frombytes(aux.astype(np.uint32).tobytes())
        self.outputs.frombytes((np.full(n, attrs.outputs) if outputs is None else outputs).astype(np.uint32).tobytes())
        self.line.frombytes(line.astype(np.int32).tobytes())
        block = np.empty((n, 11))
        block[:, 0:3], block[:, 3:6], block[:, 6:8] = start, end, center
        block[:, 8], block[:, 9], block[:, 10] = feed, tolerance, dwell
        self.floats.frombytes(block.tobytes())
        st = self.stats
        rapid, move = kind == RAPID, (kind == LINE) | (kind == ARC)
        st.rapid_length_mm += float(length[rapid].sum())
        st.feed_length_mm += float(length[move].sum())
        st.cut_length_mm += float(length[move & jet.astype(bool)].sum())
        st.dwell_s += float(dwell.sum())
        st.pierces += pierces
        self._jet_was_on = jet_was_on_after
        self._extend(*lo, *hi)

    def _extend(self, x0: float, y0: float, z0: float, x1: float, y1: float, z1: float) -> None:
        lo, hi = self._lo, self._hi
        if x0 < lo[0]:
            lo[0] = x0
        if y0 < lo[1]:
            lo[1] = y0
        if z0 < lo[2]:
            lo[2] = z0
        if x1 > hi[0]:
            hi[0] = x1
        if y1 > hi[1]:
            hi[1] = y1
        if z1 > hi[2]:
            hi[2] = z1

    def build(self, name: str, lines: int) -> Program:
        n = len(self.kind)
        seg = np.zeros(n, dtype=SEGMENT_DTYPE)
        if n:
            f = np.frombuffer(self.floats, dtype=np.float64).reshape(n, 11)
            seg["kind"] = np.frombuffer(self.kind, dtype=np.uint8)
            seg["start"] = f[:, 0:3]
            seg["end"] = f[:, 3:6]
            seg["center"] = f[:, 6:8]
            seg["feed"] = f[:, 8]
            seg["tolerance"] = f[:, 9]
            seg["dwell"] = f[:, 10]
            seg["cw"] = np.frombuffer(self.cw, dtype=np.uint8).astype(bool)
            seg["jet"] = np.frombuffer(self.jet, dtype=np.uint8).astype(bool)
            seg["turns"] = np.frombuffer(self.turns, dtype=np.int32)
            seg["aux"] = np.frombuffer(self.aux, dtype=np.uint32)
            seg["outputs"] = np.frombuffer(self.outputs, dtype=np.uint32)
            seg["line"] = np.frombuffer(self.line, dtype=np.int32)
        st = self.stats
        st.lines, st.segments = lines, n
        if math.isfinite(self._lo[0]):
            st.bounds_min, st.bounds_max = tuple(self._lo), tuple(self._hi)
        return Program(name, seg, self.messages, st)
