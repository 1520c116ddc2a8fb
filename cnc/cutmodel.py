"""The cutting model: material, thickness and edge quality set a speed cap at every point of the path.

What the operator (or the program's `(MATERIAL, ...)` comment, `gcode/cutcomments.py`) chooses is a
`CutSetup`: a material of the machine's library (`cnc.materials`), its thickness, the quality 1-5,
and the mode, as CAM tools know them: "quality" (the model sets the speed everywhere, the
programmed F is only an upper bound) or "feed" (F as programmed; the model only reports). A
`CutModel` is that setup read off the material's chart; `SegmentQualities` says which quality
holds on every segment of a program (`(QUALITY, n)` comments change it; the lead-in after each
pierce runs at the setup's pierce quality, the finest by default: the jet is not through yet).

**Straight cuts** run at the quality's speed of the chart (`Material.cut`).

**Corners and arcs: the jet lag.** The bottom of a cut runs behind its top: the jet's trail-back
(Hashish, "Near net shaping of thick materials with AWJ", MSEC2016), which grows with the traverse
speed. The chart gives it as measured on the machine (`lag_mm`, the trail-back at each quality's
speed, e.g. read off the speed ladder's edges), and between those points the lag L(v) is taken as
piecewise linear in the speed, through no lag at standstill. We model the bottom of the jet as a
trailer pulled along the path at the distance L behind the top. Then:

- at a corner that turns the path by phi, the bottom cuts across it and strays from the path by
  L sin(min(phi, pi/2));
- on an arc of radius r and sweep theta, shorter than the lag (r theta < L), the same as a corner
  of theta; longer, the bottom settles on a circle of radius sqrt(r^2 - L^2), a deviation of
  r - sqrt(r^2 - L^2) (r when L >= r), and at most the corner's figure.

Each quality allows the bottom edge a deviation e (`[quality] corner_mm`). The largest lag within it:

    corner:  L <= e / sin(min(phi, pi/2))
    arc:     L <= max(e / sin(min(theta, pi/2)), min(sqrt(e (2 r - e)) if e < r else inf, r theta))

and the speed cap is the speed with that lag (L inverted), never above the quality's straight
speed. A material without `lag_mm` or `corner_mm` gets its straight speeds only, and says so
(`CutModel.corners_modelled`). No constant here is a material property: every number comes from
the material file, which cites where its own come from.

A blended corner is an arc of the planner's (`planner/path.py`) and is capped as one; a corner
the planner stops at needs no cap, but one it passes in a corner overlap (`planner/overlap.py`: the
next move starts while the last one still arrives) is turned at speed, and the overlap keeps the
corner's cap on every sample it sums (`planner/sections.py` `_overlap_cap`); the small kinks it runs
through (below 0.01 rad) are capped as corners on both neighbours (`planner/quality.py`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .materials import MATERIALS_DIR, QUALITIES, Material, MaterialError, load_material

if TYPE_CHECKING:
    from .config import MachineConfig

MODES = ("quality", "feed")
MATERIAL_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}")


@dataclass(frozen=True)
class CutSetup:
    """What the job cuts: a material of the library, its thickness, the edge quality, and the mode."""

    material: str
    thickness_mm: float
    quality: int
    mode: str = "quality"
    pierce_quality: int = 5  # of the lead-in after each pierce

    def describe(self) -> str:
        return (f"{self.material} {self.thickness_mm:g} mm quality {self.quality}"
                + ("" if self.mode == "quality" else " (feed as programmed)"))


class CutModel:
    """A `CutSetup` read off its material's chart: per quality the straight speed, the lag curve, the
    allowed deviation; caps for an element of the path at a quality."""

    def __init__(self, material: Material, setup: CutSetup) -> None:
        where = f"{material.path or material.id}: material {material.id!r}"
        if setup.mode not in MODES:
            raise MaterialError(f"{where}: mode {setup.mode!r} is not one of: {', '.join(MODES)}")
        for key in ("quality", "pierce_quality"):
            if getattr(setup, key) not in QUALITIES:
                raise MaterialError(f"{where}: {key} {getattr(setup, key)!r} is not one of 1 to 5")
        self.material, self.setup = material, setup
        points = [material.cut(setup.thickness_mm, q) for q in QUALITIES]  # raises what the chart cannot answer
        self.speed_mm_s = np.array([0.0] + [p.speed_mm_min / 60.0 for p in points])  # index: quality (1..5)
        self.pierce_s = points[setup.quality - 1].pierce_s
        self.kerf_mm = points[setup.quality - 1].kerf_mm
        lags = [p.lag_mm for p in points]
        self.corners_modelled = all(x is not None for x in lags) and bool(material.corner_mm)
        self.corner_mm = np.array([0.0] + list(material.corner_mm)) if material.corner_mm else np.zeros(0)
        if self.corners_modelled:
            speed = self.speed_mm_s[1:]
            order = np.argsort(speed, kind="stable")
            self._lag_v = np.concatenate(([0.0], speed[order]))
            self._lag_l = np.concatenate(([0.0], np.array(lags, dtype=float)[order]))
            if np.any(np.diff(self._lag_l) < 0.0):
                raise MaterialError(f"{where}: lag_mm at {setup.thickness_mm:g} mm falls while the speed rises: "
                                    "the trail-back grows with the speed")

    @property
    def uses_quality(self) -> bool:
        return self.setup.mode == "quality"

    def speed(self, quality: int) -> float:
        """The straight speed of a quality, mm/s."""
        return float(self.speed_mm_s[quality])

    def lag_at(self, v_mm_s: float | np.ndarray) -> np.ndarray:
        """The trail-back at speed v (mm), from the chart's measurements."""
        return np.interp(v_mm_s, self._lag_v, self._lag_l)

    def speed_for_lag(self, lag_mm: np.ndarray) -> np.ndarray:
        """The fastest speed whose trail-back is at most `lag_mm` (inf at or beyond the largest measured)."""
        lag = np.asarray(lag_mm, dtype=float)
        v_pts, l_pts = self._lag_v, self._lag_l
        best = np.zeros(lag.shape)
        for i in range(len(v_pts) - 1):  # the curve is non-decreasing: the answer is the best piece's
            v0, v1, l0, l1 = v_pts[i], v_pts[i + 1], l_pts[i], l_pts[i + 1]
            if l1 > l0:
                inside = v0 + (np.clip(lag, l0, l1) - l0) / (l1 - l0) * (v1 - v0)
                best = np.where(lag >= l0, np.maximum(best, inside), best)
            else:  # flat: the whole piece or none of it
                best = np.where(lag >= l0, np.maximum(best, v1), best)
        return np.where(lag >= l_pts[-1], np.inf, best)

    def turn_cap(self, quality: int, angle_rad: np.ndarray) -> np.ndarray:
        """Speed cap through a corner turning by `angle_rad` at a quality (inf: no cap below the straight speed)."""
        angle = np.abs(np.asarray(angle_rad, dtype=float))
        if not self.corners_modelled:
            return np.full(angle.shape, np.inf)
        e = self.corner_mm[quality]
        with np.errstate(divide="ignore"):
            lag = np.where(angle > 0.0, e / np.sin(np.minimum(angle, math.pi / 2.0)), np.inf)
        return self.speed_for_lag(lag)

    def arc_cap(self, quality: int, radius_mm: np.ndarray, sweep_rad: np.ndarray) -> np.ndarray:
        """Speed cap on arcs of `radius_mm` sweeping `sweep_rad` at a quality (the model in the docstring)."""
        r = np.asarray(radius_mm, dtype=float)
        theta = np.abs(np.asarray(sweep_rad, dtype=float))
        if not self.corners_modelled:
            return np.full(np.broadcast(r, theta).shape, np.inf)
        e = self.corner_mm[quality]
        with np.errstate(divide="ignore", invalid="ignore"):
            as_corner = np.where(theta > 0.0, e / np.sin(np.minimum(theta, math.pi / 2.0)), np.inf)
            settled = np.where(e < r, np.sqrt(np.maximum(e * (2.0 * r - e), 0.0)), np.inf)
        # at L = r theta the model turns from the settled figure to the corner's: the cap stays a hair
        # below that edge, so that the speed it gives (rounded back to a lag) is on the settled side
        lag = np.maximum(as_corner, np.minimum(settled, r * theta * (1.0 - 1e-9)))
        return self.speed_for_lag(lag)

    def bottom_deviation(self, v_mm_s: float, radius_mm: float, sweep_rad: float) -> float:
        """How far the bottom of the cut strays from an arc (radius inf: a corner of `sweep_rad`) at speed v:
        the model's forward direction, which the caps invert (tests check one against the other)."""
        lag = float(self.lag_at(v_mm_s))
        corner = lag * math.sin(min(abs(sweep_rad), math.pi / 2.0))
        if not math.isfinite(radius_mm) or radius_mm * abs(sweep_rad) < lag:
            return corner
        settled = radius_mm - math.sqrt(radius_mm * radius_mm - lag * lag) if lag < radius_mm else radius_mm
        return min(corner, settled)


def library_of(config: "MachineConfig") -> Path:
    """The machine's material library (`[cutting] materials_dir`, relative to the machine file)."""
    return Path(config.source).parent / (config.cutting.materials_dir or MATERIALS_DIR)


def model_for(setup: CutSetup, config: "MachineConfig") -> CutModel:
    """The model of a setup, its material's file read from the machine's library (only that one: a
    broken file of another material does not stop this job); MaterialError says why not."""
    if not MATERIAL_ID.fullmatch(setup.material):  # a name from a command: never a path out of the library
        raise MaterialError(f"{setup.material!r} is not a material id (letters, digits, _ . -, the name of its file "
                            "in the library without .toml)")
    directory = library_of(config)
    path = directory / f"{setup.material}.toml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in directory.glob("*.toml"))) if directory.is_dir() else ""
        raise MaterialError(f"material {setup.material!r} is not in the library {directory} (known: {known or 'none'})")
    return CutModel(load_material(path), setup)


def setup_of_program(messages, given: CutSetup | None) -> CutSetup | None:  # noqa: ANN001 - gcode Messages
    """The job's setup: `given` (the operator's, on the screen or over Zenoh) when there is one, else the
    program's first `(MATERIAL, ...)` comment, else None (the program cuts at its F)."""
    if given is not None:
        return given
    for m in messages:
        if m.kind == "material":
            d = m.data
            return CutSetup(d["material"], float(d["thickness_mm"]), int(d["quality"]), d.get("mode", "quality"))
    return None

