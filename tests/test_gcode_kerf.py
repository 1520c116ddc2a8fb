"""Kerf compensation offsets the path exactly as LinuxCNC's cutter compensation does (rs274 -g, LinuxCNC 2.9).

Each case is a small G-code program beside the canonical calls `rs274 -g` prints for it,
run as `G21 G17 G90 G94 F100` + program + `M2` from X0 Y0 Z0:
  ("FEED"|"TRAVERSE", x, y, z)              STRAIGHT_FEED / STRAIGHT_TRAVERSE
  ("ARC", x, y, cx, cy, rotation, z)        ARC_FEED: rotation -1 cw, +1 ccw, +-2 one extra turn
  ("COMMENT", text), ("DWELL", seconds)
`_steps` turns the program into hand-built Moves and Events (absolute XY, incremental IJ,
no interpreter involved) and drives the KerfCompensator with them. `test_agrees_with_rs274`
re-runs every program through /usr/bin/rs274 where LinuxCNC is installed.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from gcode.canon import ARC, LINE, RAPID, Event, Move
from gcode.errors import GCodeError
from gcode.kerf import KerfCompensator

RS274 = "/usr/bin/rs274"
HEADER = "G21 G17 G90 G94 F100"
TOL_MM = 1e-4  # rs274 prints 4 decimals

CASES = {
    # concave line/line corners join at the offset lines' intersection; the entry is offset
    # square to itself, the exit runs from the last offset point to the programmed end
    "left-entry-concave-lines-exit": ("""
G41.1 D2
G1 X10 Y0
G1 X10 Y10
G1 X0 Y10
G40
G1 X-5 Y10
""", [
        ("FEED", 9, 1, 0),
        ("FEED", 9, 9, 0),
        ("FEED", 0, 9, 0),
        ("FEED", -5, 10, 0),
    ]),
    "right-convex-lines-get-corner-arcs": ("""
G42.1 D2
G1 X10 Y0
G1 X10 Y10
G1 X0 Y10
G40
G1 X0 Y20
""", [
        ("FEED", 10, -1, 0),
        ("ARC", 11, 0, 10, 0, 1, 0),
        ("FEED", 11, 10, 0),
        ("ARC", 10, 11, 10, 10, 1, 0),
        ("FEED", 0, 11, 0),
        ("FEED", 0, 20, 0),
    ]),
    # line->arc, arc->arc (a reversal with the jet inside: convex, a half-turn corner arc), arc->line
    "left-convex-line-arc-arc-line": ("""
G41.1 D2
G1 X10 Y0
G3 X20 Y0 I5 J0
G3 X30 Y0 I5 J0
G1 X40 Y10
G40
G1 X40 Y20
""", [
        ("FEED", 10, 1, 0),
        ("ARC", 11, 0, 10, 0, -1, 0),
        ("ARC", 19, 0, 15, 0, 1, 0),
        ("ARC", 21, 0, 20, 0, -1, 0),
        ("ARC", 29, 0, 25, 0, 1, 0),
        ("ARC", 29.2929, 0.7071, 30, 0, -1, 0),
        ("FEED", 39.2929, 10.7071, 0),
        ("FEED", 40, 20, 0),
    ]),
    # line->arc, arc->arc (the top of an "m": a reversal with the jet outside is concave), arc->line
    "left-concave-line-arc-arc-line": ("""
G41.1 D2
G1 X10 Y0
G2 X20 Y0 I5 J0
G2 X30 Y0 I5 J0
G1 X40 Y-10
G40
G1 X50 Y-10
""", [
        ("FEED", 9.0839, 1, 0),
        ("ARC", 20, 3.3166, 15, 0, -1, 0),
        ("ARC", 30.9846, 0.4296, 25, 0, -1, 0),
        ("FEED", 40.7071, -9.2929, 0),
        ("FEED", 50, -10, 0),
    ]),
    "right-convex-line-arc-arc-line": ("""
G42.1 D2
G1 X10 Y0
G2 X20 Y0 I5 J0
G2 X30 Y0 I5 J0
G1 X40 Y-10
G40
G1 X40 Y-20
""", [
        ("FEED", 10, -1, 0),
        ("ARC", 11, 0, 10, 0, 1, 0),
        ("ARC", 19, 0, 15, 0, -1, 0),
        ("ARC", 21, 0, 20, 0, 1, 0),
        ("ARC", 29, 0, 25, 0, -1, 0),
        ("ARC", 29.2929, -0.7071, 30, 0, 1, 0),
        ("FEED", 39.2929, -10.7071, 0),
        ("FEED", 40, -20, 0),
    ]),
    "right-concave-line-arc-arc-line": ("""
G42.1 D2
G1 X10 Y0
G3 X20 Y0 I5 J0
G3 X30 Y0 I5 J0
G1 X40 Y10
G40
G1 X50 Y10
""", [
        ("FEED", 9.0839, -1, 0),
        ("ARC", 20, -3.3166, 15, 0, 1, 0),
        ("ARC", 30.9846, -0.4296, 25, 0, 1, 0),
        ("FEED", 40.7071, 9.2929, 0),
        ("FEED", 50, 10, 0),
    ]),
    # a disc cut from outside (clockwise, G41): convex corner arc, then the whole offset circle
    "full-circle-outside-a-disc": ("""
G0 X20 Y10
G41.1 D2
G1 X0 Y-10
G2 X0 Y-10 I0 J10
G40
G1 X0 Y-20
""", [
        ("TRAVERSE", 20, 10, 0),
        ("FEED", 0.7071, -10.7071, 0),
        ("ARC", 0, -11, 0, -10, -1, 0),
        ("ARC", 0, -11, 0, 0, -1, 0),
        ("FEED", 0, -20, 0),
    ]),
    # a hole cut from inside (clockwise, G42) after a square approach: convex corner arc,
    # then the whole offset circle
    "full-circle-inside-a-hole-after-a-convex-corner": ("""
G0 X-20 Y0
G42.1 D2
G1 X-10 Y0
G2 X-10 Y0 I10 J0
G40
G1 X-20 Y0
""", [
        ("TRAVERSE", -20, 0, 0),
        ("FEED", -10, -1, 0),
        ("ARC", -9, 0, -10, 0, 1, 0),
        ("ARC", -9, 0, 0, 0, -1, 0),
        ("FEED", -20, 0, 0),
    ]),
    # a hole cut from inside (counter-clockwise, G41) entered from its centre: the entry meets
    # the offset circle, which is cut from there round (a little less than a full turn)
    "full-circle-inside-a-hole-entered-from-its-centre": ("""
G41.1 D2
G1 X-10 Y0
G3 X-10 Y0 I10 J0
G40
G1 X0 Y0
""", [
        ("FEED", -8.9443, -1, 0),
        ("ARC", -9, 0, 0, 0, 1, 0),
        ("FEED", 0, 0, 0),
    ]),
    "helix-full-circle-keeps-z-and-extra-turn": ("""
G0 X-20 Y0
G42.1 D2
G1 X-10 Y0
G2 X-10 Y0 I10 J0 Z-2 P2
G40
G1 X-20 Y0 Z0
""", [
        ("TRAVERSE", -20, 0, 0),
        ("FEED", -10, -1, 0),
        ("ARC", -9, 0, -10, 0, 1, 0),
        ("ARC", -9, 0, 0, 0, -2, -2),
        ("FEED", -20, 0, 0),
    ]),
    # clockwise with G41: the jet stays outside the 20 x 10 part
    "rectangle-cut-outside": ("""
G0 X-5 Y-5
G41.1 D2
G1 X0 Y0
G1 X0 Y10
G1 X20 Y10
G1 X20 Y0
G1 X0 Y0
G40
G1 X-5 Y-5
""", [
        ("TRAVERSE", -5, -5, 0),
        ("FEED", -1, 0.4142, 0),
        ("FEED", -1, 10, 0),
        ("ARC", 0, 11, 0, 10, -1, 0),
        ("FEED", 20, 11, 0),
        ("ARC", 21, 10, 20, 10, -1, 0),
        ("FEED", 21, 0, 0),
        ("ARC", 20, -1, 20, 0, -1, 0),
        ("FEED", 0, -1, 0),
        ("FEED", -5, -5, 0),
    ]),
    # counter-clockwise with G41: the jet stays inside the 20 x 10 hole
    "rectangle-cut-inside": ("""
G0 X10 Y5
G41.1 D2
G1 X10 Y0
G1 X20 Y0
G1 X20 Y10
G1 X0 Y10
G1 X0 Y0
G1 X10 Y0
G40
G1 X10 Y5
""", [
        ("TRAVERSE", 10, 5, 0),
        ("FEED", 11, 1, 0),
        ("FEED", 19, 1, 0),
        ("FEED", 19, 9, 0),
        ("FEED", 1, 9, 0),
        ("FEED", 1, 1, 0),
        ("FEED", 10, 1, 0),
        ("FEED", 10, 5, 0),
    ]),
    # a 40 x 20 part with R5 corners, cut clockwise from outside with a 3 mm kerf radius
    "rounded-rectangle-around-a-part": ("""
G0 X-10 Y5
G41.1 D6
G1 X0 Y5
G1 X0 Y15
G2 X5 Y20 I5 J0
G1 X35 Y20
G2 X40 Y15 I0 J-5
G1 X40 Y5
G2 X35 Y0 I-5 J0
G1 X5 Y0
G2 X0 Y5 I0 J5
G40
G1 X-10 Y5
""", [
        ("TRAVERSE", -10, 5, 0),
        ("FEED", -3, 8, 0),
        ("FEED", -3, 15, 0),
        ("ARC", 5, 23, 5, 15, -1, 0),
        ("FEED", 35, 23, 0),
        ("ARC", 43, 15, 35, 15, -1, 0),
        ("FEED", 43, 5, 0),
        ("ARC", 35, -3, 35, 5, -1, 0),
        ("FEED", 5, -3, 0),
        ("ARC", -3, 5, 5, 5, -1, 0),
        ("FEED", -10, 5, 0),
    ]),
    # G0 is offset like G1; a convex corner gets a straight rapid to the next offset line
    "rapids-are-compensated-like-lines": ("""
G41.1 D2
G0 X10 Y0
G0 X10 Y-10
G1 X0 Y-10
G0 X0 Y-5
G40
G0 X-5 Y-5
""", [
        ("TRAVERSE", 10, 1, 0),
        ("TRAVERSE", 11, 0, 0),
        ("TRAVERSE", 11, -10, 0),
        ("ARC", 10, -11, 10, -10, -1, 0),
        ("FEED", 0, -11, 0),
        ("TRAVERSE", -1, -10, 0),
        ("TRAVERSE", -1, -5, 0),
        ("TRAVERSE", -5, -5, 0),
    ]),
    "events-keep-their-place-behind-held-moves": ("""
G41.1 D2
G1 X10 Y0
(before corner)
G4 P0.5
G1 X10 Y10
(after corner)
G1 X20 Y10
G40
G1 X20 Y20
""", [
        ("FEED", 9, 1, 0),
        ("COMMENT", "before corner"),
        ("DWELL", 0.5),
        ("FEED", 9, 10, 0),
        ("COMMENT", "after corner"),
        ("ARC", 10, 11, 10, 10, -1, 0),
        ("FEED", 20, 11, 0),
        ("FEED", 20, 20, 0),
    ]),
    # a Z move is held with the move before it: moved into a concave corner, before a convex arc
    "pure-z-moves-wait-at-the-corner": ("""
G41.1 D2
G1 X10 Y0
G1 Z-1
G1 X10 Y10
G1 Z1
G1 X20 Y10
""", [
        ("FEED", 9, 1, 0),
        ("FEED", 9, 1, -1),
        ("FEED", 9, 10, -1),
        ("FEED", 9, 10, 1),
        ("ARC", 10, 11, 10, 10, -1, 1),
        ("FEED", 20, 11, 1),
    ]),
    # a 0.03 rad bend gets neither arc nor intersection (the next line starts where the jet
    # is); a 0.06 rad bend gets an arc
    "bends-under-0.05-rad-join-straight": ("""
G41.1 D2
G1 X10 Y0
G1 X20 Y0.3
G1 X30 Y0
""", [
        ("FEED", 10, 1, 0),
        ("FEED", 19.97, 1.2996, 0),
        ("ARC", 20.03, 1.2996, 20, 0.3, -1, 0),
        ("FEED", 30.03, 0.9996, 0),
    ]),
    # the second entry is computed from the programmed point but starts where the jet is
    "g40-then-g41-without-motion": ("""
G41.1 D2
G1 X10 Y0
G40
G41.1 D2
G1 X10 Y10
G40
G1 X20 Y10
""", [
        ("FEED", 10, 1, 0),
        ("FEED", 9, 10, 0),
        ("FEED", 20, 10, 0),
    ]),
    # a stop hands the held move on at its offset end, so the next (concave) corner cannot
    # cut it back any more
    "stop-flushes-so-the-next-concave-corner-is-not-joined": ("""
G41.1 D2
G1 X10 Y0
M0
G1 X10 Y10
G1 X0 Y10
""", [
        ("FEED", 10, 1, 0),
        ("FEED", 9, 9, 0),
        ("FEED", 0, 9, 0),
    ]),
    "zero-radius-passes-moves-through": ("""
G41.1 D0
G1 X1 Y0
G2 X2 Y0 I0.5 J0
G40
G3 X3 Y0 I0.5 J0
""", [
        ("FEED", 1, 0, 0),
        ("ARC", 2, 0, 1.5, 0, -1, 0),
        ("ARC", 3, 0, 2.5, 0, 1, 0),
    ]),
    "negative-diameter-swaps-sides": ("""
G41.1 D-2
G1 X10 Y0
G1 X10 Y10
G40
G1 X10 Y20
""", [
        ("FEED", 10, -1, 0),
        ("ARC", 11, 0, 10, 0, 1, 0),
        ("FEED", 11, 10, 0),
        ("FEED", 10, 20, 0),
    ]),
    # an entry arc ends offset radially; its centre moves so that it still starts at X0 Y0
    "entry-arc-inside": ("""
G41.1 D4
G3 X10 Y0 I5 J0
G1 X10 Y-10
""", [
        ("ARC", 8, 0, 4, 0, 1, 0),
        ("ARC", 12, 0, 10, 0, -1, 0),
        ("FEED", 12, -10, 0),
    ]),
    # jet outside the arc, then a reversal onto a line: the top of an "h" is a concave corner
    "entry-arc-outside-then-h-shape": ("""
G41.1 D4
G2 X10 Y0 I5 J0
G1 X10 Y10
""", [
        ("ARC", 8, 5.6569, 6, 0, -1, 0),
        ("FEED", 8, 10, 0),
    ]),
}

# program, error code, line of the offending block (rs274 reports the same block)
ERRORS = {
    "comp-on-when-on": ("G41.1 D2\nG41.1 D2", "kerf-state", 2),
    "entry-not-longer-than-radius": ("G41.1 D4\nG1 X1 Y0", "kerf-entry", 2),
    "pure-z-cannot-be-the-entry-move": ("G41.1 D2\nG1 Z-1", "kerf-entry", 2),
    "entry-arc-too-short": ("G41.1 D4\nG3 X1 Y0 I0.5 J0", "kerf-entry", 2),
    "inside-arc-smaller-than-radius": ("G41.1 D4\nG1 X10 Y0\nG3 X10 Y2 I0 J1", "kerf-arc-radius", 3),
    "inside-entry-arc-smaller-than-radius": ("G41.1 D10\nG3 X8 Y0 I4 J0", "kerf-arc-radius", 2),
    "line-too-short-for-its-concave-corners": ("G41.1 D2\nG1 X10 Y0\nG1 X13 Y0\nG1 X10 Y1", "kerf-concave-corner", 4),
    "rapid-too-short-for-its-concave-corners": ("G41.1 D2\nG1 X10 Y0\nG0 X13 Y0\nG1 X10 Y1", "kerf-concave-corner", 4),
    "offset-line-never-meets-offset-arc": ("G41.1 D2\nG1 X10 Y0\nG3 X5 Y1 I-3 J-2", "kerf-concave-corner", 3),
    "offset-arc-never-meets-offset-line": ("G41.1 D2\nG1 X10 Y0\nG3 X9 Y3 I1 J2\nG1 X13 Y4", "kerf-concave-corner", 4),
    "offset-arcs-never-meet": ("G41.1 D2\nG1 X10 Y0\nG3 X9 Y3 I1 J2\nG3 X7 Y5 I0 J2", "kerf-concave-corner", 4),
    "arcs-with-the-same-centre": ("G41.1 D2\nG1 X10 Y0\nG3 X12 Y-8 I1 J-4\nG2 X10 Y0 I-1 J4", "kerf-concave-corner", 4),
    "arc-cut-back-to-nothing": ("G42.1 D2\nG1 X10 Y0\nG3 X9 Y-1 I0 J-1\nG40", "kerf-concave-corner", 4),
    "reversed-line-found-at-g40": ("G41.1 D2\nG1 X3 Y0\nG1 X0 Y1\nG40", "kerf-concave-corner", 4),
    "arc-after-g40": ("G41.1 D2\nG1 X10 Y0\nG40\nG2 X0 Y10 I-5 J5", "kerf-exit", 4),
}

_WORD = re.compile(r"([A-Z])\s*([-+]?\d*\.?\d+)")


def _steps(program: str):
    """Yield (what, payload, line) for the compensator: the moves and events a block makes, in order."""
    position, motion, feed = (0.0, 0.0, 0.0), 1, 100.0
    for n, text in enumerate(program.strip().splitlines(), 1):
        comment = re.fullmatch(r"\((.*)\)", text.strip())
        if comment:
            yield "event", Event("comment", n, {"text": comment.group(1)}), n
            continue
        words = _WORD.findall(text.upper())
        g = [float(v) for letter, v in words if letter == "G"]
        w = {letter: float(v) for letter, v in words if letter != "G"}
        feed = w.get("F", feed)
        if 4 in g:
            yield "event", Event("dwell", n, {"seconds": w["P"]}), n
            continue
        if 40 in g:
            yield "stop", None, n
        if 41.1 in g or 42.1 in g:
            yield "start", (1 if 41.1 in g else -1, w["D"] / 2.0), n
        motion = next((c for c in (0, 1, 2, 3) if c in g), motion)
        if w.get("M") in (0, 1, 2, 30):
            yield "flush", None, n
        if not any(axis in w for axis in "XYZ"):
            continue
        end = (w.get("X", position[0]), w.get("Y", position[1]), w.get("Z", position[2]))
        if motion in (2, 3):
            center = (position[0] + w.get("I", 0.0), position[1] + w.get("J", 0.0))
            turns = int(w.get("P", 1)) - 1
            move = Move(ARC, position, end, center=center, cw=motion == 2, turns=turns, feed=feed, line=n, column=1)
        else:
            move = Move(RAPID if motion == 0 else LINE, position, end,
                        feed=math.nan if motion == 0 else feed, line=n, column=1)
        yield "move", move, n
        position = end


def _run(program: str) -> list[Move | Event]:
    out: list[Move | Event] = []
    kerf = KerfCompensator(out.append)
    for what, payload, n in _steps(program):
        if what == "start":
            kerf.start(*payload, line=n, column=1)
        elif what == "stop":
            kerf.stop(n, 1)
        elif what == "flush":
            kerf.flush()
        elif what == "event":
            kerf.event(payload)
        else:
            kerf.move(payload)
    kerf.flush()
    return out


def _canon(items: list[Move | Event]) -> list[tuple]:
    """What rs274 would print for these items."""
    calls = []
    for item in items:
        if isinstance(item, Event):
            calls.append(("COMMENT", item.data["text"]) if item.kind == "comment" else ("DWELL", item.data["seconds"]))
        elif item.kind == ARC:
            rotation = -(item.turns + 1) if item.cw else item.turns + 1
            calls.append(("ARC", *item.end[:2], *item.center, rotation, item.end[2]))
        else:
            calls.append(("TRAVERSE" if item.kind == RAPID else "FEED", *item.end))
    return calls


def _assert_same_calls(got: list[tuple], want: list[tuple]) -> None:
    assert [c[0] for c in got] == [c[0] for c in want], f"got {got}\nwant {want}"
    for g, w in zip(got, want):
        if g[0] == "COMMENT":
            assert g == w
        else:
            assert g[1:] == pytest.approx(w[1:], abs=TOL_MM), f"got {g}, want {w}"


@pytest.mark.parametrize("name", CASES)
def test_offsets_as_linuxcnc_prints(name: str) -> None:
    program, expected = CASES[name]
    _assert_same_calls(_canon(_run(program)), expected)


@pytest.mark.parametrize("name", CASES)
def test_every_move_starts_where_the_previous_one_ended(name: str) -> None:
    moves = [m for m in _run(CASES[name][0]) if isinstance(m, Move)]
    for before, after in zip(moves, moves[1:]):
        assert after.start == pytest.approx(before.end, abs=1e-12)


def test_contour_around_a_part_keeps_the_jet_one_kerf_radius_off_the_part() -> None:
    """Every point of the compensated contour is 3 mm from the R5-cornered 40 x 20 part."""
    moves = [m for m in _run(CASES["rounded-rectangle-around-a-part"][0]) if isinstance(m, Move)]
    contour = moves[2:-1]  # after the rapid and the entry, before the exit

    def distance_to_part(x: float, y: float) -> float:
        # the part is the 30 x 10 core [5, 35] x [5, 15] grown by 5 mm
        return math.hypot(max(5 - x, 0, x - 35), max(5 - y, 0, y - 15)) - 5.0

    for m in contour:
        for t in (0.0, 0.25, 0.5, 0.75, 1.0):
            if m.kind == ARC:
                radius = math.dist(m.start[:2], m.center)
                a0 = math.atan2(m.start[1] - m.center[1], m.start[0] - m.center[0])
                a = a0 - t * math.pi / 2  # every arc here is a clockwise quarter turn
                point = (m.center[0] + radius * math.cos(a), m.center[1] + radius * math.sin(a))
            else:
                point = tuple(s + t * (e - s) for s, e in zip(m.start[:2], m.end[:2]))
            assert distance_to_part(*point) == pytest.approx(3.0, abs=1e-9)
    assert moves[-2].end[:2] == pytest.approx((-3.0, 5.0))  # back where the contour began, offset


@pytest.mark.parametrize(("name", "radius_mm"), [
    ("full-circle-outside-a-disc", 11.0),
    ("full-circle-inside-a-hole-after-a-convex-corner", 9.0),
    ("helix-full-circle-keeps-z-and-extra-turn", 9.0),
])
def test_full_circle_stays_a_full_circle(name: str, radius_mm: float) -> None:
    circle = [m for m in _run(CASES[name][0]) if isinstance(m, Move) and m.kind == ARC][-1]
    assert circle.start[:2] == circle.end[:2]  # exactly: start == end is how a full circle is told
    assert math.dist(circle.start[:2], circle.center) == pytest.approx(radius_mm)


def test_corner_arc_runs_at_the_outgoing_moves_feed_and_line() -> None:
    out: list[Move | Event] = []
    kerf = KerfCompensator(out.append)
    kerf.start(+1, 1.0, line=1, column=1)
    kerf.move(Move(LINE, (0, 0, 0), (10, 0, 0), feed=100.0, line=2, column=3, attrs={"tol": 0.1}))
    kerf.move(Move(LINE, (10, 0, 0), (10, -10, 0), feed=200.0, line=3, column=5, attrs={"tol": 0.2}))
    kerf.flush()
    first, corner, second = out
    assert (first.feed, first.line, first.column, first.attrs) == (100.0, 2, 3, {"tol": 0.1})
    assert corner.kind == ARC and corner.cw and corner.center == (10, 0)
    assert (corner.feed, corner.line, corner.column, corner.attrs) == (200.0, 3, 5, {"tol": 0.2})
    assert (second.feed, second.line, second.column, second.attrs) == (200.0, 3, 5, {"tol": 0.2})


def test_an_event_between_two_moves_comes_out_between_them() -> None:
    out: list[Move | Event] = []
    kerf = KerfCompensator(out.append)
    jet_off = Event("output", 3, {"jet": False})
    kerf.start(-1, 1.0, line=1, column=1)
    kerf.move(Move(LINE, (0, 0, 0), (10, 0, 0), feed=100.0, line=2))
    kerf.event(jet_off)
    assert out == []  # the line waits for its corner, the event waits behind it
    kerf.move(Move(LINE, (10, 0, 0), (10, 10, 0), feed=100.0, line=4))
    assert [type(x) for x in out] == [Move, Event, Move] and out[1] is jet_off
    assert [m.line for m in out if isinstance(m, Move)] == [2, 4]  # line, then the corner arc of line 4
    kerf.flush()
    assert out[-1].end == pytest.approx((11, 10, 0))


def test_events_pass_straight_through_when_nothing_is_held() -> None:
    out: list[Move | Event] = []
    kerf = KerfCompensator(out.append)
    message = Event("message", 1, {"text": "hello"})
    kerf.event(message)
    kerf.start(+1, 1.0, line=2, column=1)
    kerf.event(message)
    assert out == [message, message]


def test_inactive_compensator_hands_moves_on_unchanged() -> None:
    out: list[Move | Event] = []
    kerf = KerfCompensator(out.append)
    moves = [Move(RAPID, (0, 0, 0), (5, 5, 0)), Move(ARC, (5, 5, 0), (5, 5, 0), center=(6, 5), cw=True, feed=50.0)]
    for m in moves:
        kerf.move(m)
    assert not kerf.active and out == moves and all(a is b for a, b in zip(out, moves))


def test_active_follows_g41_and_g40() -> None:
    kerf = KerfCompensator(lambda item: None)
    assert not kerf.active
    kerf.start(+1, 0.0, line=1, column=1)
    assert kerf.active
    kerf.stop(2, 1)
    assert not kerf.active
    kerf.stop(3, 1)  # G40 when already off is harmless
    assert not kerf.active


@pytest.mark.parametrize("name", ERRORS)
def test_rejects_what_linuxcnc_rejects(name: str) -> None:
    program, code, line = ERRORS[name]
    with pytest.raises(GCodeError) as caught:
        _run(program)
    assert (caught.value.code, caught.value.line) == (code, line)


def test_arc_radius_error_gives_both_radii() -> None:
    with pytest.raises(GCodeError) as caught:
        _run("G41.1 D10\nG3 X8 Y0 I4 J0")
    assert caught.value.message == "arc radius 4.000 mm is smaller than kerf compensation radius 5.000 mm"
    assert (caught.value.line, caught.value.column) == (2, 1)


def test_concave_corner_error_names_the_corner_and_the_short_line() -> None:
    with pytest.raises(GCodeError) as caught:
        _run(ERRORS["line-too-short-for-its-concave-corners"][0])
    message = caught.value.message
    assert "cannot reach the concave corner at X13.000 Y0.000" in message
    assert "kerf compensation radius 1.000 mm" in message
    assert "line from X10.000 Y0.000 to X13.000 Y0.000 is too short" in message


def test_a_rejected_move_hands_nothing_on() -> None:
    out: list[Move | Event] = []
    kerf = KerfCompensator(out.append)
    kerf.start(+1, 1.0, line=1, column=1)
    kerf.move(Move(LINE, (0, 0, 0), (10, 0, 0), feed=100.0, line=2))
    kerf.move(Move(LINE, (10, 0, 0), (13, 0, 0), feed=100.0, line=3))
    emitted = list(out)
    with pytest.raises(GCodeError):
        kerf.move(Move(LINE, (13, 0, 0), (10, 1, 0), feed=100.0, line=4))
    assert out == emitted


def test_gouge_found_at_the_end_of_the_program_is_reported_at_the_reversed_move() -> None:
    # LinuxCNC reports it at M2; flush() has no block of its own, so it names the held move
    with pytest.raises(GCodeError) as caught:
        _run("G41.1 D2\nG1 X3 Y0\nG1 X0 Y1")
    assert (caught.value.code, caught.value.line) == ("kerf-concave-corner", 3)


def test_offset_arc_shrunk_to_a_point_is_handed_on_as_a_straight_move() -> None:
    # rs274 prints a zero-radius ARC_FEED here; a planner would take start == end for a full circle
    out: list[Move | Event] = []
    kerf = KerfCompensator(out.append)
    kerf.start(-1, 1.0 - 1e-9, line=1, column=1)
    kerf.move(Move(LINE, (0, 0, 0), (10, 0, 0), feed=100.0, line=2))
    kerf.move(Move(ARC, (10, 0, 0), (12, 0, -1), center=(11, 0), cw=True, feed=100.0, line=3))  # radius 1
    kerf.flush()
    entry, corner, shrunk = out
    assert corner.kind == ARC and corner.line == 3
    assert shrunk.kind == LINE and shrunk.line == 3 and shrunk.center is None
    assert shrunk.start == pytest.approx((11, 0, 0)) and shrunk.end == pytest.approx((11, 0, -1))


# ---------------------------------------------------------------------------------------
# the same programs through LinuxCNC itself (only where it is installed)

needs_rs274 = pytest.mark.skipif(not Path(RS274).is_file() or shutil.which(RS274) is None,
                                 reason="LinuxCNC rs274 not installed")
_CALL = re.compile(r"^\s*\d+ N\.+ (STRAIGHT_TRAVERSE|STRAIGHT_FEED|ARC_FEED|COMMENT|DWELL)\((.*)\)\s*$")


def _rs274(program: str, tmp_path: Path) -> tuple[list[tuple], str | None]:
    """rs274's canonical calls for `program` and the block it stopped at with an error (or None)."""
    source = tmp_path / "case.ngc"
    source.write_text(f"{HEADER}\n{program.strip()}\nM2\n")
    # a private HOME and directory: rs274 shares its tool table through $HOME/.tool.mmap and
    # keeps parameters in ./rs274ngc.var, so concurrent runs would disturb each other
    done = subprocess.run(
        [RS274, "-g", str(source)], cwd=tmp_path, env={**os.environ, "HOME": str(tmp_path)},
        stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=30,
    )
    calls = []
    for text in done.stdout.splitlines():
        match = _CALL.match(text)
        if not match:
            continue
        name, args = match.groups()
        if name == "COMMENT":
            comment = args.strip('"')
            if not comment.startswith("interpreter:"):
                calls.append(("COMMENT", comment))
            continue
        values = [float(a) for a in args.split(",")]
        if name == "ARC_FEED":
            calls.append(("ARC", values[0], values[1], values[2], values[3], int(values[4]), values[5]))
        elif name == "DWELL":
            calls.append(("DWELL", values[0]))
        else:
            calls.append(("TRAVERSE" if name == "STRAIGHT_TRAVERSE" else "FEED", *values[:3]))
    failed_block = done.stderr.strip().splitlines()[-1] if done.returncode else None
    return calls, failed_block


@pytest.mark.linuxcnc
@needs_rs274
@pytest.mark.parametrize("name", CASES)
def test_agrees_with_rs274(name: str, tmp_path: Path) -> None:
    program, expected = CASES[name]
    calls, failed_block = _rs274(program, tmp_path)
    assert failed_block is None
    _assert_same_calls(calls, expected)  # the numbers written above are still what LinuxCNC prints
    _assert_same_calls(_canon(_run(program)), calls)


@pytest.mark.linuxcnc
@needs_rs274
@pytest.mark.parametrize("name", ERRORS)
def test_rejects_at_the_block_rs274_rejects(name: str, tmp_path: Path) -> None:
    program, code, line = ERRORS[name]
    _, failed_block = _rs274(program, tmp_path)
    assert failed_block == program.splitlines()[line - 1]
