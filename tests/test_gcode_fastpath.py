"""The bulk fast path gives exactly what the general path gives, errors included."""

from __future__ import annotations

import random

import numpy as np
import pytest

from gcode.dialect import Dialect
from gcode.errors import GCodeError
from gcode.interp import Interpreter

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

DIALECT = Dialect(axes="xyz", default_tolerance_mm=0.05)


def _program(seed: int, n: int = 400, bad_line: int | None = None) -> str:
    rng = random.Random(seed)
    out = ["G21 G90 G17", "G10 L2 P1 X12.5 Y-3", "G54 M3 F600", "G0 X1 Y1"]
    x = y = 1.0
    mode = 0
    for k in range(n):
        r = rng.random()
        if mode >= 2 and 0.35 <= r < 0.55:
            r = 0.1  # a bare X/Y line after an arc would be an arc without a centre
        nx, ny = x + rng.uniform(-20, 20), y + rng.uniform(-20, 20)
        if r < 0.35:
            out.append(f"G1 X{nx:.3f} Y{ny:.3f}" + (f" F{rng.randint(100, 3000)}" if rng.random() < 0.3 else ""))
            mode = 1
        elif r < 0.55:
            out.append(f"X{nx:.4f} Y{ny:.4f}")
        elif r < 0.65:
            out.append(f"G0 X{nx:.2f} Y{ny:.2f} Z{rng.uniform(0, 5):.2f}")
            mode = 0
        elif r < 0.8:
            # an arc with a consistent centre: pick a centre and put the end on the circle
            cx, cy = x + rng.uniform(-10, 10), y + rng.uniform(-10, 10)
            rad = ((x - cx) ** 2 + (y - cy) ** 2) ** 0.5
            ang = rng.uniform(0, 6.283)
            nx, ny = cx + rad * np.cos(ang), cy + rad * np.sin(ang)
            out.append(f"G{rng.choice((2, 3))} X{nx:.6f} Y{ny:.6f} I{cx - x:.6f} J{cy - y:.6f}")
            mode = 2
        elif r < 0.9:
            rr = rng.uniform(15, 40) * rng.choice((1, -1))
            out.append(f"G{rng.choice((2, 3))} X{nx:.3f} Y{ny:.3f} R{rr:.3f} F{rng.randint(200, 900)}")
            mode = 2
        else:
            out.append(f"N{k} G01 X{nx:.3f} Y{ny:.3f}")
            mode = 1
        x, y = nx, ny
        extra = rng.random()
        if extra < 0.04:
            out.append(rng.choice(["M5", "M3", "M7", "M9", "M8", "M5 M9"]))
        elif extra < 0.06:
            out.append(f"G4 P{rng.uniform(0, 1):.3f}")
        elif extra < 0.07:
            out.append("M3 G4 P0.2")
        if bad_line is not None and k == bad_line:
            out.append(rng.choice(["G1 X1 X2", "G2 X5 Y5 I1 J1", "G0 Z1 Z2", "G1 X3 R2", "G2 X7 Y7 R0.1"]))
    out.append("M5 M2")
    return "\n".join(out) + "\n"


def _both(text: str, dialect: Dialect = DIALECT):
    results = []
    for fast in (False, True):
        try:
            results.append(Interpreter(dialect, "p.ngc", fast=fast).run(text))
        except GCodeError as err:
            results.append(err)
    return results


@pytest.mark.parametrize("seed", range(8))
def test_fast_path_equals_general_path_on_plain_cam_programs(seed):
    slow, fast = _both(_program(seed))
    assert not isinstance(slow, GCodeError), str(slow)
    assert len(slow.segments) == len(fast.segments)
    for name in slow.segments.dtype.names:
        a, b = slow.segments[name], fast.segments[name]
        if a.dtype.kind == "f":
            assert np.allclose(a, b, rtol=0, atol=1e-9, equal_nan=True), name
        else:
            assert np.array_equal(a, b), name
    s, f = slow.stats, fast.stats
    assert (s.pierces, s.segments, s.lines) == (f.pierces, f.segments, f.lines)
    assert s.dwell_s == pytest.approx(f.dwell_s) and s.pierces > 1 and s.dwell_s > 0
    for attr in ("cut_length_mm", "feed_length_mm", "rapid_length_mm"):
        assert getattr(s, attr) == pytest.approx(getattr(f, attr), rel=1e-12)
    assert np.allclose(s.bounds_min, f.bounds_min) and np.allclose(s.bounds_max, f.bounds_max)


@pytest.mark.parametrize("seed", range(6))
def test_fast_path_reports_the_same_error_as_the_general_path(seed):
    slow, fast = _both(_program(seed, bad_line=150 + seed * 17))
    assert isinstance(slow, GCodeError) and isinstance(fast, GCodeError)
    assert (str(slow), slow.code) == (str(fast), fast.code)


def test_fast_path_respects_a_machine_without_z():
    slow, fast = _both(_program(3), Dialect(axes="xy"))
    assert isinstance(slow, GCodeError) and str(slow) == str(fast) and "Z word" in slow.message


def _contour_program(side: str, n: int = 600) -> str:
    """A closed many-sided contour around (300, 300), lines and arcs on the circle, cut with kerf compensation."""
    import math

    out = ["G21 G90 F900", "G0 X500 Y300", "M3", f"{side} D0.3 G1 X500 Y300.5"]
    px, py = 500.0, 300.5
    for k in range(1, n + 1):
        a = 2 * math.pi * k / n
        x, y = 300 + 200 * math.cos(a), 300.5 + 200 * math.sin(a)
        if k % 97 == 0:
            out.append("M7 G4 P0.1" if k % 2 else "M9")
        if k % 5 == 0:
            out.append(f"G3 X{x:.6f} Y{y:.6f} I{300 - px:.6f} J{300.5 - py:.6f}")
        else:
            out.append(f"G1 X{x:.6f} Y{y:.6f}")
        px, py = x, y
    out += ["G40 G1 X520 Y300", "M5", "M2"]
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("side", ["G41.1", "G42.1"])
def test_fast_path_with_kerf_compensation_on_equals_the_general_path(side):
    slow, fast = _both(_contour_program(side))
    assert not isinstance(slow, GCodeError), str(slow)
    assert len(slow.segments) == len(fast.segments) > 600
    for name in ("kind", "start", "end", "center", "cw", "feed", "line", "jet", "aux", "dwell", "tolerance"):
        a, b = slow.segments[name], fast.segments[name]
        assert np.allclose(a, b, atol=1e-9, equal_nan=True) if a.dtype.kind == "f" else np.array_equal(a, b), name


def test_a_kerf_entry_after_a_bulk_run_starts_where_that_run_ended():
    """Regression: moves the fast path hands on past the compensator must move its chain point too."""
    lines = ["G21 G90 F1000", "G0 X0 Y0", "G41.1 D2 G1 X10 Y0", "G1 X10 Y10", "G1 X0 Y10", "G40 G1 X-5 Y15", "M5"]
    lines += [f"G0 X{50 + k} Y{k}" for k in range(12)]
    lines += ["M3", "G41.1 D2 G1 X80 Y0", "G1 X80 Y10", "G1 X70 Y10", "G40 G1 X60 Y20", "M2"]
    slow, fast = _both("\n".join(lines) + "\n")
    assert np.allclose(slow.segments["start"], fast.segments["start"]) and np.allclose(slow.segments["end"], fast.segments["end"])
    moves = fast.segments
    assert np.allclose(moves["start"][1:], moves["end"][:-1]), "every segment starts where the last one ended"


def test_the_exit_move_after_a_bare_g40_keeps_its_chained_start_in_a_bulk_run():
    """After `G40` alone, the next move is the exit move: it runs from the last offset point."""
    lines = ["G21 G90 F1000", "G0 X0 Y0", "G41.1 D2 G1 X10 Y0", "G1 X10 Y10", "G40"]
    lines += [f"G1 X{10 - k} Y{10 + k}" for k in range(1, 30)] + ["M2"]
    slow, fast = _both("\n".join(lines) + "\n")
    assert np.allclose(slow.segments["start"], fast.segments["start"]) and np.allclose(slow.segments["end"], fast.segments["end"])
    assert tuple(fast.segments["start"][3][:2]) == pytest.approx((9.0, 10.0)), "the exit starts at the offset corner"


def _nest(seed: int, parts: int = 60, gouge_at: int | None = None) -> str:
    """A nest of small parts cut with kerf compensation, as a CAM post writes it, with variety:
    both sides, both directions, nozzle-table D and direct diameters, lines, I/J and R arcs,
    and now and then what the bulk compensator leaves to the per-move one."""
    import math

    rng = random.Random(seed)
    out = ["G21 G90 G17 F2400", "T1 M6"]
    for k in range(parts):
        ox, oy = 30 + (k % 12) * 60.0, 30 + (k // 12) * 50.0
        comp = rng.choice(["G41 D1", "G42 D2", "G41.1 D0.6", "G42.1 D0.3"])
        ccw = rng.random() < 0.5
        out += [f"G0 X{ox - 3:.3f} Y{oy - 3:.3f}", "M3", "G4 P0.2", f"{comp} G1 X{ox:.3f} Y{oy:.3f}"]
        shape = rng.random() if gouge_at != k else 0.0
        pts: list[str] = []
        if shape < 0.4:  # rounded rectangle
            w, h, r = rng.uniform(20, 40), rng.uniform(15, 30), rng.uniform(2, 5)
            steps = rng.randint(2, 6)
            pts += [f"G1 X{ox + (w - r) * i / steps:.4f} Y{oy:.4f}" for i in range(1, steps + 1)]
            pts += [f"G3 X{ox + w:.4f} Y{oy + r:.4f} I0 J{r:.4f}", f"G1 X{ox + w:.4f} Y{oy + h - r:.4f}",
                    f"G3 X{ox + w - r:.4f} Y{oy + h:.4f} I{-r:.4f} J0", f"G1 X{ox:.4f} Y{oy + h:.4f}", f"G1 X{ox:.4f} Y{oy:.4f}"]
        elif shape < 0.75:  # circle of R arcs and chords
            rad = rng.uniform(8, 16)
            n = rng.randint(12, 30)
            cx, cy = ox, oy + rad
            for i in range(1, n + 1):
                a = -math.pi / 2 + (1 if ccw else -1) * 2 * math.pi * i / n
                x, y = cx + rad * math.cos(a), cy + rad * math.sin(a)
                g = 3 if ccw else 2
                pts.append(f"G{g} X{x:.4f} Y{y:.4f} R{rad:.4f}" if i % 3 == 0 else f"G1 X{x:.4f} Y{y:.4f}")
        else:  # slot
            ln, rad = rng.uniform(15, 30), rng.uniform(3, 6)
            pts += [f"G1 X{ox + ln:.3f} Y{oy:.3f}", f"G3 X{ox + ln:.3f} Y{oy + 2 * rad:.3f} I0 J{rad:.3f}",
                    f"G1 X{ox:.3f} Y{oy + 2 * rad:.3f}", f"G3 X{ox:.3f} Y{oy:.3f} I0 J{-rad:.3f}"]
        if gouge_at == k:  # two 0.2 mm slots, into and out of the part: the jet fits neither side
            x0 = ox + (w - r) / steps
            pts[1:1] = [f"G1 X{x0:.4f} Y{oy + 0.5:.4f}", f"G1 X{x0 + 0.2:.4f} Y{oy + 0.5:.4f}", f"G1 X{x0 + 0.2:.4f} Y{oy:.4f}",
                        f"G1 X{x0 + 0.4:.4f} Y{oy:.4f}", f"G1 X{x0 + 0.4:.4f} Y{oy - 0.5:.4f}", f"G1 X{x0 + 0.6:.4f} Y{oy - 0.5:.4f}",
                        f"G1 X{x0 + 0.6:.4f} Y{oy:.4f}"]
        odd = rng.random()
        if odd < 0.05 and len(pts) > 2:
            pts.insert(2, "M7")  # an event inside the contour: left to the per-move compensator
        out += pts
        if odd > 0.95:
            out += ["G40", f"G1 X{ox - 4:.3f} Y{oy - 4:.3f}"]  # a bare G40: the next move is the exit
        else:
            out.append(f"G40 G1 X{ox - 4:.3f} Y{oy - 4:.3f}")
        out += ["M5"]
    out += ["G0 X0 Y0", "M2"]
    return "\n".join(out) + "\n"


NEST_DIALECT = Dialect(axes="xyz", tool_diameters_mm={1: 0.8, 2: 1.2}, default_tolerance_mm=0.05)


@pytest.mark.parametrize("seed", range(6))
def test_bulk_kerf_compensation_of_a_nest_equals_the_per_move_compensator(seed):
    slow, fast = _both(_nest(seed), NEST_DIALECT)
    if isinstance(slow, GCodeError):
        assert isinstance(fast, GCodeError) and (str(slow), slow.code) == (str(fast), fast.code)
        return
    assert len(slow.segments) == len(fast.segments) > 1000
    for name in slow.segments.dtype.names:
        a, b = slow.segments[name], fast.segments[name]
        assert np.allclose(a, b, atol=1e-9, equal_nan=True) if a.dtype.kind == "f" else np.array_equal(a, b), name
    s, f = slow.stats, fast.stats
    assert (s.pierces, s.segments) == (f.pierces, f.segments) and s.pierces == 60
    assert s.cut_length_mm == pytest.approx(f.cut_length_mm, rel=1e-12)
    assert np.allclose(s.bounds_min, f.bounds_min) and np.allclose(s.bounds_max, f.bounds_max)


@pytest.mark.parametrize("seed", range(3))
def test_bulk_kerf_reports_a_gouge_as_the_per_move_compensator_does(seed):
    slow, fast = _both(_nest(seed, gouge_at=20 + seed * 7), NEST_DIALECT)
    assert isinstance(slow, GCodeError) and slow.code.startswith("kerf"), str(slow)
    assert isinstance(fast, GCodeError) and (str(slow), slow.code) == (str(fast), fast.code)


def _same(slow, fast) -> None:
    if isinstance(slow, GCodeError):
        assert isinstance(fast, GCodeError) and (str(slow), slow.code) == (str(fast), fast.code)
        return
    assert not isinstance(fast, GCodeError), str(fast)
    assert len(slow.segments) == len(fast.segments) > 0
    for name in slow.segments.dtype.names:
        a, b = slow.segments[name], fast.segments[name]
        assert np.allclose(a, b, atol=1e-9, equal_nan=True) if a.dtype.kind == "f" else np.array_equal(a, b), name
    assert slow.messages == fast.messages and slow.units_final == fast.units_final
    assert (slow.stats.pierces, slow.stats.segments) == (fast.stats.pierces, fast.stats.segments)


@pytest.mark.parametrize("seed", range(4))
def test_inch_and_metric_parts_in_one_bulk_run_equal_the_general_path(seed):
    """G20/G21 inside a run: F on a G20 line in the units before it, axis words, I/J and R in the
    units after it, absolute and incremental, kerf stretches in inches (G41 D and G41.1 D)."""
    from bench.nests import cam_nest

    text = cam_nest(30, seed=seed, inch_every=2 + seed % 2)
    extra = "\n".join([
        "G20 F60 G1 X1 Y1", "X1.5", "G21 F2 G1 X50", "G3 X60 Y35.4 R10", "G20 G2 X2.7622 Y1.5937 I0.2 J0.1",
        "G91 G1 X0.1 Y0.1", "G21 X5 Y5", "G90 G20 G41.1 D0.03 G1 X3 Y3", "G1 X4", "G1 Y4", "G40 G1 X5 Y5",
        "G21 G41 D1 G1 X100 Y100", "G1 X110", "G20", "G1 Y5", "G40 G1 X3 Y3", "G21",
    ] * 3)
    slow, fast = _both(text.replace("G0 X0 Y0\nM2", extra + "\nG0 X0 Y0\nM2"), NEST_DIALECT)
    assert not isinstance(slow, GCodeError), str(slow)
    _same(slow, fast)
    assert sorted(set(np.round(slow.segments["feed"][~np.isnan(slow.segments["feed"])], 6))) [:2] == [2 * 25.4, 60.0], \
        "G20 F60: 60 mm/min; G21 F2: 2 in/min"
