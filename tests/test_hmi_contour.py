"""The contour field: categories per progress, the head cross, fit, and a 100k-segment load."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cnc.bus.messages import ProgramPath
from cnc.config import load_machine
from cnc.gateway.door import program_path
from cnc.machine_dialect import dialect_for
from gcode.interp import Interpreter
from hmi.contour import ContourView

pytest.importorskip("pytestqt")
REPO = Path(__file__).resolve().parent.parent
TOL = 0.01

PROGRAM = """G21 G90 G17
G0 X10 Y10
G1 X50 Y10 F1000
G1 X50 Y30
G3 X30 Y50 I-20 J0
G1 X10 Y10
G0 X100 Y100
G1 X120 Y100
G2 X120 Y100 I10 J0
M2
"""


def steps(radius: float, sweep: float) -> int:
    """Chords an arc needs for a sagitta within TOL."""
    return math.ceil(abs(sweep) / (2 * math.acos(1 - TOL / radius)))


@pytest.fixture
def path() -> ProgramPath:
    config = load_machine(REPO / "machines" / "waterjet.toml")
    return program_path(Interpreter(dialect_for(config), "t.ngc").run(PROGRAM))


@pytest.fixture
def view(qtbot, path):
    w = ContourView(path, travel_mm=(0.0, 1600.0, 0.0, 1200.0), tolerance_mm=TOL)
    qtbot.addWidget(w)
    w.resize(640, 480)
    w.show()
    qtbot.waitExposed(w)
    w.fit()
    return w


def test_loading_counts_vertices_per_category(view, path):
    assert path.kind == [0, 1, 1, 2, 1, 0, 1, 2]
    quarter, circle = steps(20, math.pi / 2), steps(10, 2 * math.pi)
    # part 1: 3 line vertices + quarter arc (start shared) + closing line end; part 2: line + full circle
    # before the run reaches its first segment nothing is being cut: every feed vertex is to cut
    assert view.point_counts() == {"cut": 0, "current": 0, "to_cut": (quarter + 4) + (circle + 2), "rapid": 4}
    assert view.progress == -1
    view.set_progress(0)  # segment 0, the rapid from the origin, is the one "being cut"
    assert view.point_counts() == {"cut": 0, "current": 2, "to_cut": (quarter + 4) + (circle + 2), "rapid": 4}
    view.set_progress(6)
    view.set_progress(-1)
    assert view.point_counts()["cut"] == 0 and view.point_counts()["current"] == 0, "a new run starts all to cut"


def test_progress_moves_segments_from_to_cut_to_cut(view):
    quarter, circle = steps(20, math.pi / 2), steps(10, 2 * math.pi)
    view.set_progress(4)  # segments 1-3 cut (2 lines + arc), 4 (a line) being cut
    assert view.point_counts() == {"cut": quarter + 3, "current": 2, "to_cut": circle + 2, "rapid": 4}
    view.set_progress(7)  # being cut: the full circle
    assert view.point_counts() == {"cut": quarter + 4 + 2, "current": circle + 1, "to_cut": 0, "rapid": 4}
    view.set_progress(8)
    assert view.point_counts()["cut"] == quarter + circle + 6
    assert view.point_counts()["current"] == 0


def test_progress_on_a_rapid_draws_the_rapid_as_current(view):
    view.set_progress(5)
    counts = view.point_counts()
    assert counts["current"] == 2 and counts["to_cut"] == steps(10, 2 * math.pi) + 2


def test_the_cross_follows_set_head(view):
    assert view.head_position() is None
    view.set_head(33.0, 44.0)
    assert view.head_position() == pytest.approx((33.0, 44.0))
    view.set_visible_range(0, 10, 0, 10)
    view.set_head(5.5, 6.5)
    assert view.head_position() == pytest.approx((5.5, 6.5))


def test_fit_shows_the_whole_path(view):
    view.set_visible_range(0, 5, 0, 5)
    view.fit()
    assert view.path_bounds() == pytest.approx((0.0, 140.0, 0.0, 110.0), abs=TOL)  # rapid from the origin
    x0, x1, y0, y1 = view.visible_range()
    assert x0 <= 0 and x1 >= 140 and y0 <= 0 and y1 >= 110
    assert min(x1 - x0, y1 - y0) < 2 * 130  # framed, not the whole table


def test_zooming_in_swaps_the_overview_for_the_fine_tessellation(view):
    view.set_travel(0, 1600, 0, 1200)
    view.set_visible_range(0, 1600, 0, 1200)
    assert view.showing_overview
    view.set_visible_range(25, 35, 25, 35)
    assert not view.showing_overview


def test_a_100k_segment_path_loads_and_renders(qtbot):
    n = 100_000
    rng = np.random.default_rng(1)
    kind = np.where(np.arange(n) % 50 == 0, 0, np.where(np.arange(n) % 3 == 0, 2, 1))
    xy = np.cumsum(rng.uniform(-1, 1, (n + 1, 2)), axis=0) + 800
    center = (xy[:-1] + xy[1:]) / 2  # semicircles on the chord
    path = ProgramPath(
        kind=kind.tolist(), start_x=xy[:-1, 0].tolist(), start_y=xy[:-1, 1].tolist(),
        end_x=xy[1:, 0].tolist(), end_y=xy[1:, 1].tolist(), center_x=center[:, 0].tolist(),
        center_y=center[:, 1].tolist(), cw=(np.arange(n) % 2 == 0).tolist(), line=list(range(n)),
    )
    w = ContourView(travel_mm=(0.0, 1600.0, 0.0, 1200.0))
    qtbot.addWidget(w)
    w.resize(1024, 768)
    w.show()
    qtbot.waitExposed(w)
    w.set_path(path)
    w.fit()
    assert not w.grab().isNull()
    counts = w.point_counts()
    assert counts["rapid"] == 2 * n // 50 and counts["to_cut"] > n
    w.set_progress(n // 2)
    assert w.point_counts()["cut"] > n // 2


def test_screenshot(view):
    view.set_progress(4)
    view.set_head(50.0, 20.0)
    out = REPO / "tests" / "screenshots"
    out.mkdir(exist_ok=True)
    assert view.grab().save(str(out / "contour.png"))
