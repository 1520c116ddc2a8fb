"""Materials and their cut charts: the speed, pierce time and kerf a material of a given thickness
needs at an edge quality, on the cutting head the chart was made for.

One TOML file per material under `machines/materials/` (the id is the file name):

    [material]
    name = "Mild steel S235"
    kind = "abrasive"                  # or "water" (pure water jet: leather, textiles, foam)
    source = "where the numbers come from: a cited cut chart, or a calibration (who, when)"

    [head]                             # optional: the cutting head and pump the chart holds for
    orifice_mm = 0.33
    mixing_tube_mm = 1.02              # 0 for a pure water jet
    pressure_bar = 3800
    abrasive_kg_min = 0.35             # 0 for a pure water jet

    [quality]
    fractions = [1.0, f2, f3, f4, f5]  # optional: quality 1 (separation) to 5 (finest) as fractions of
                                       # the separation speed; rows may give their own speeds instead
    corner_mm = [e1, e2, e3, e4, e5]   # optional: how far the bottom of the cut may stray from the
                                       # path in corners and arcs at each quality (`cutmodel.py`)

    [[chart]]                          # one row per thickness, thinnest first
    thickness_mm = 6.0
    separation_mm_min = 300.0          # the speed at which the jet just cuts through (quality 1)
    pierce_s = 2.5
    kerf_mm = 0.9
    quality_mm_min = [q1, q2, q3, q4, q5]   # optional: the speeds judged right per quality (calibration)
    lag_mm = [l1, l2, l3, l4, l5]      # optional: the jet's trail-back (how far the bottom of the cut
                                       # runs behind the top) measured at each quality's speed

The controller ships no number it cannot cite: a material no source covers (the paper's leather
and textiles) ships without chart rows, and the speed-ladder calibration (`ladder_program`,
`record_calibration`) fills them on the machine. Between two rows the speed is interpolated on
logarithmic axes (cutting speed falls as a power of the thickness in the published models:
Zeng and Kim, 7th American Water Jet Conference 1993; Hlavac, Materials 2021, 14, 4032), pierce
time and kerf linearly; outside the chart nothing is extrapolated: the thickness is refused.
Errors name the file, the material and the key.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

QUALITIES = (1, 2, 3, 4, 5)  # 1 separation (fastest, rough lower edge) to 5 the finest edge
KINDS = ("abrasive", "water")
MATERIALS_DIR = "materials"  # beside the machine file


class MaterialError(ValueError):
    """A material file or a request of its chart is wrong; the text names file, material and key."""


@dataclass(frozen=True)
class Head:
    """The cutting head and pump a chart holds for."""

    orifice_mm: float
    mixing_tube_mm: float
    pressure_bar: float
    abrasive_kg_min: float


@dataclass(frozen=True)
class ChartRow:
    thickness_mm: float
    separation_mm_min: float
    pierce_s: float
    kerf_mm: float
    quality_mm_min: tuple[float, ...] = ()  # the five quality speeds, when calibrated
    lag_mm: tuple[float, ...] = ()  # the trail-back at each quality's speed, when measured


@dataclass(frozen=True)
class CutPoint:
    """What cutting one thickness at one quality takes."""

    speed_mm_min: float
    pierce_s: float
    kerf_mm: float
    lag_mm: float | None = None  # the trail-back at this speed, when the chart has it



@dataclass(frozen=True)
class Material:
    id: str
    name: str
    kind: str
    source: str
    head: Head | None  # None: the chart holds for this machine's own head, as it is
    fractions: tuple[float, ...]  # quality 1..5 as fractions of the separation speed; () when the rows give speeds
    chart: tuple[ChartRow, ...]
    path: str = ""
    corner_mm: tuple[float, ...] = ()  # per quality: the bottom edge's allowed deviation in corners and arcs

    @property
    def calibrated(self) -> bool:
        return bool(self.chart)

    @property
    def thickness_range(self) -> tuple[float, float] | None:
        return (self.chart[0].thickness_mm, self.chart[-1].thickness_mm) if self.chart else None

    def cut(self, thickness_mm: float, quality: int) -> CutPoint:
        """Speed, pierce time and kerf for `thickness_mm` at `quality` (1-5); MaterialError says why not."""
        where = f"{self.path or self.id}: material {self.id!r}"
        if quality not in QUALITIES:
            raise MaterialError(f"{where}: quality {quality!r} is not one of 1 to 5")
        if not self.chart:
            raise MaterialError(f"{where}: no cut chart yet: calibrate it (a speed ladder) before cutting by quality")
        if not (math.isfinite(thickness_mm) and thickness_mm > 0.0):
            raise MaterialError(f"{where}: thickness {thickness_mm!r} mm must be a positive number")
        lo, hi = self.thickness_range
        if not lo - 1e-9 <= thickness_mm <= hi + 1e-9:
            raise MaterialError(f"{where}: thickness {thickness_mm:g} mm is outside its chart ({lo:g} to {hi:g} mm): "
                                "nothing is extrapolated; calibrate that thickness")
        rows = self.chart
        k = next(i for i, r in enumerate(rows) if r.thickness_mm >= thickness_mm - 1e-9)
        a, b = rows[max(k - 1, 0)], rows[k]
        speed_a, speed_b = self._speed(a, quality, where), self._speed(b, quality, where)
        if a is b or abs(b.thickness_mm - thickness_mm) < 1e-9:
            return CutPoint(speed_b, b.pierce_s, b.kerf_mm, b.lag_mm[quality - 1] if b.lag_mm else None)
        w = (thickness_mm - a.thickness_mm) / (b.thickness_mm - a.thickness_mm)
        wl = (math.log(thickness_mm) - math.log(a.thickness_mm)) / (math.log(b.thickness_mm) - math.log(a.thickness_mm))
        speed = math.exp(math.log(speed_a) + wl * (math.log(speed_b) - math.log(speed_a)))
        lag = None  # measured on both rows, or not known between them
        if a.lag_mm and b.lag_mm:
            lag = a.lag_mm[quality - 1] + w * (b.lag_mm[quality - 1] - a.lag_mm[quality - 1])
        return CutPoint(speed, a.pierce_s + w * (b.pierce_s - a.pierce_s), a.kerf_mm + w * (b.kerf_mm - a.kerf_mm), lag)

    def _speed(self, row: ChartRow, quality: int, where: str) -> float:
        if row.quality_mm_min:
            return row.quality_mm_min[quality - 1]
        if not self.fractions:
            raise MaterialError(f"{where}: [[chart]] {row.thickness_mm:g} mm has no quality_mm_min and [quality] "
                                "fractions is not given: the speed of a quality is unknown")
        return row.separation_mm_min * self.fractions[quality - 1]


# -- reading -------------------------------------------------------------------------------------
def load_material(path: str | Path) -> Material:
    """Read and check one material file; MaterialError names the file, the material and the key."""
    path = Path(path)
    ident = path.stem
    try:
        raw = tomllib.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise MaterialError(f"{path}: file not found") from None
    except UnicodeDecodeError as exc:
        raise MaterialError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise MaterialError(f"{path}: TOML syntax error: {exc}") from None
    return parse_material(raw, ident, str(path))


def parse_material(raw: dict, ident: str, shown: str) -> Material:
    """A material from its parsed TOML (`shown` names it in errors)."""
    def err(table: str, key: str, why: str) -> MaterialError:
        return MaterialError(f"{shown}: material {ident!r}: [{table}]{' ' + key if key else ''}: {why}")

    _only(raw, ("material", "head", "quality", "chart"), lambda k: MaterialError(
        f"{shown}: material {ident!r}: unknown table [{k}] (known: material, head, quality, chart)"))
    m = _table(raw, "material", err)
    _only(m, ("name", "kind", "source"), lambda k: err("material", k, "unknown key (known: kind, name, source)"))
    name = _text(m, "material", "name", err)
    kind = _text(m, "material", "kind", err)
    if kind not in KINDS:
        raise err("material", "kind", f"{kind!r} is not one of: {', '.join(KINDS)}")
    source = _text(m, "material", "source", err)
    head = None
    if "head" in raw:
        h = _table(raw, "head", err)
        keys = ("orifice_mm", "mixing_tube_mm", "pressure_bar", "abrasive_kg_min")
        _only(h, keys, lambda k: err("head", k, f"unknown key (known: {', '.join(keys)})"))
        head = Head(_number(h, "head", "orifice_mm", err, 0.01, 2.0), _number(h, "head", "mixing_tube_mm", err, 0.0, 5.0),
                    _number(h, "head", "pressure_bar", err, 100.0, 7000.0), _number(h, "head", "abrasive_kg_min", err, 0.0, 5.0))
    if kind == "abrasive" and head is not None and (head.mixing_tube_mm <= 0.0 or head.abrasive_kg_min <= 0.0):
        raise err("head", "mixing_tube_mm" if head.mixing_tube_mm <= 0.0 else "abrasive_kg_min",
                  "an abrasive cut needs a mixing tube and an abrasive rate above 0")
    q = raw.get("quality", {})
    if not isinstance(q, dict):
        raise err("quality", "", "expected a table")
    _only(q, ("fractions", "corner_mm"), lambda k: err("quality", k, "unknown key (known: corner_mm, fractions)"))
    fractions = _five(q, "quality", "fractions", err, 0.0, 1.0) if "fractions" in q else ()
    corner = _five(q, "quality", "corner_mm", err, 0.0, 50.0) if "corner_mm" in q else ()
    rows_raw = raw.get("chart", [])
    if not isinstance(rows_raw, list):
        raise err("chart", "", "expected an array of tables [[chart]]")
    rows = []
    for n, r in enumerate(rows_raw, 1):
        table = f"[chart]] #{n}"
        row_err = lambda t, k, why, n=n: MaterialError(  # noqa: E731
            f"{shown}: material {ident!r}: [[chart]] #{n}{' ' + k if k else ''}: {why}")
        if not isinstance(r, dict):
            raise row_err(table, "", "expected a table")
        rkeys = ("thickness_mm", "separation_mm_min", "pierce_s", "kerf_mm", "quality_mm_min", "lag_mm")
        _only(r, rkeys, lambda k, e=row_err: e("", k, f"unknown key (known: {', '.join(rkeys)})"))
        speeds = _five(r, table, "quality_mm_min", row_err, 1.0, 100000.0) if "quality_mm_min" in r else ()
        lags = _five(r, table, "lag_mm", row_err, 0.0, 100.0) if "lag_mm" in r else ()
        row = ChartRow(_number(r, table, "thickness_mm", row_err, 0.01, 1000.0),
                       _number(r, table, "separation_mm_min", row_err, 1.0, 100000.0),
                       _number(r, table, "pierce_s", row_err, 0.0, 600.0), _number(r, table, "kerf_mm", row_err, 0.01, 10.0),
                       speeds, lags)
        if speeds and speeds[0] > row.separation_mm_min * (1.0 + 1e-9):
            raise row_err(table, "quality_mm_min", f"quality 1 at {speeds[0]:g} mm/min is faster than the separation "
                                                   f"speed {row.separation_mm_min:g}: the jet would not cut through")
        if rows and row.thickness_mm <= rows[-1].thickness_mm:
            raise row_err(table, "thickness_mm", f"{row.thickness_mm:g} mm: rows go from the thinnest to the thickest")
        if rows and row.separation_mm_min > rows[-1].separation_mm_min:
            raise row_err(table, "separation_mm_min", f"{row.separation_mm_min:g} mm/min is faster than the thinner "
                                                      f"row's {rows[-1].separation_mm_min:g}: a thicker cut is slower")
        if lags and speeds:
            for q in range(1, len(QUALITIES)):
                if speeds[q] == speeds[q - 1] and lags[q] != lags[q - 1]:
                    raise row_err(table, "lag_mm", f"qualities {q} and {q + 1} run at the same speed but give different "
                                                   "trail-backs: the lag depends on the speed only")
        rows.append(row)
    if any(r.lag_mm for r in rows) and not all(r.lag_mm for r in rows):
        bare = next(r for r in rows if not r.lag_mm)
        raise MaterialError(f"{shown}: material {ident!r}: [[chart]] {bare.thickness_mm:g} mm: lag_mm: missing while other "
                            "rows give it: measure the trail-back on every row or on none")
    if rows and not fractions and not all(r.quality_mm_min for r in rows):
        bare = next(r for r in rows if not r.quality_mm_min)
        raise MaterialError(f"{shown}: material {ident!r}: [quality] fractions: missing, and the {bare.thickness_mm:g} mm "
                            "row gives no quality_mm_min: one of them must say the speed of each quality")
    return Material(ident, name, kind, source, head, tuple(fractions), tuple(rows), shown, tuple(corner))


def load_library(directory: str | Path) -> dict[str, Material]:
    """Every material file of `directory` by id (none when it does not exist); the first bad file raises."""
    d = Path(directory)
    if not d.is_dir():
        return {}
    return {p.stem: load_material(p) for p in sorted(d.glob("*.toml"))}


def _only(table: dict, known: tuple[str, ...], error) -> None:  # noqa: ANN001 - a callable making the error
    for key in table:
        if key not in known:
            raise error(key)


def _table(raw: dict, name: str, err) -> dict:  # noqa: ANN001
    t = raw.get(name)
    if not isinstance(t, dict):
        raise err(name, "", "missing table" if t is None else "expected a table")
    return t


def _text(t: dict, table: str, key: str, err) -> str:  # noqa: ANN001
    v = t.get(key)
    if not isinstance(v, str) or not v.strip():
        raise err(table, key, "missing" if v is None else f"expected a non-empty string, got {v!r}")
    return v


def _number(t: dict, table: str, key: str, err, lo: float, hi: float) -> float:  # noqa: ANN001
    v = t.get(key)
    if v is None:
        raise err(table, key, f"missing (a number, {lo:g} to {hi:g})")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise err(table, key, f"expected a number, got {v!r}")
    if not lo <= v <= hi:
        raise err(table, key, f"{v!r} is out of range: allowed {lo:g} to {hi:g}")
    return float(v)


def _five(t: dict, table: str, key: str, err, lo: float, hi: float) -> tuple[float, ...]:  # noqa: ANN001
    v = t.get(key)
    if not isinstance(v, list) or len(v) != len(QUALITIES):
        raise err(table, key, f"expected five numbers, quality 1 to 5, got {v!r}")
    out = []
    for q, x in zip(QUALITIES, v):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or not lo < x <= hi:
            raise err(table, key, f"quality {q}: {x!r} is not a number above {lo:g} and at most {hi:g}")
        if out and x > out[-1]:
            raise err(table, key, f"quality {q}: {x:g} is faster than quality {q - 1}'s {out[-1]:g}: a finer edge is slower")
        out.append(float(x))
    return tuple(out)


# -- writing -------------------------------------------------------------------------------------
def render_material(m: Material) -> str:
    """The material file's text (what `load_material` reads back to an equal Material)."""
    def num(x: float) -> str:
        return repr(float(x))

    lines = ["[material]", f"name = {_quote(m.name)}", f"kind = {_quote(m.kind)}", f"source = {_quote(m.source)}", ""]
    if m.head is not None:
        lines += ["[head]", f"orifice_mm = {num(m.head.orifice_mm)}", f"mixing_tube_mm = {num(m.head.mixing_tube_mm)}",
                  f"pressure_bar = {num(m.head.pressure_bar)}", f"abrasive_kg_min = {num(m.head.abrasive_kg_min)}", ""]
    if m.fractions or m.corner_mm:
        lines.append("[quality]")
        if m.fractions:
            lines.append(f"fractions = [{', '.join(num(f) for f in m.fractions)}]")
        if m.corner_mm:
            lines.append(f"corner_mm = [{', '.join(num(e) for e in m.corner_mm)}]")
        lines.append("")
    for r in m.chart:
        lines += ["[[chart]]", f"thickness_mm = {num(r.thickness_mm)}", f"separation_mm_min = {num(r.separation_mm_min)}",
                  f"pierce_s = {num(r.pierce_s)}", f"kerf_mm = {num(r.kerf_mm)}"]
        if r.quality_mm_min:
            lines.append(f"quality_mm_min = [{', '.join(num(s) for s in r.quality_mm_min)}]")
        if r.lag_mm:
            lines.append(f"lag_mm = [{', '.join(num(x) for x in r.lag_mm)}]")
        lines.append("")
    return "\n".join(lines)


def _quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def with_row(m: Material, row: ChartRow) -> Material:
    """`m` with `row` in its chart (replacing the row of the same thickness), checked as a file is."""
    rows = sorted([r for r in m.chart if abs(r.thickness_mm - row.thickness_mm) > 1e-9] + [row], key=lambda r: r.thickness_mm)
    updated = replace(m, chart=tuple(rows))
    return parse_material(tomllib.loads(render_material(updated)), m.id, m.path or m.id)


# -- calibration: the speed ladder -----------------------------------------------------------------
@dataclass(frozen=True)
class Ladder:
    """A speed-ladder test cut: `rungs` straight cuts of `length_mm`, each at its own speed, spaced
    `pitch_mm` apart from (`x_mm`, `y_mm`) upwards; the operator judges the edges afterwards."""

    thickness_mm: float
    slowest_mm_min: float
    fastest_mm_min: float
    rungs: int = 8
    length_mm: float = 60.0
    pitch_mm: float = 10.0
    x_mm: float = 20.0
    y_mm: float = 20.0
    pierce_s: float = 1.0

    def speeds(self) -> list[float]:
        """The rungs' speeds, slowest first, in equal ratios (rung k at slowest x r^k)."""
        if self.rungs == 1:
            return [self.slowest_mm_min]
        r = (self.fastest_mm_min / self.slowest_mm_min) ** (1.0 / (self.rungs - 1))
        return [self.slowest_mm_min * r**k for k in range(self.rungs)]


def ladder_program(material: Material, ladder: Ladder, jet_on: int = 3, jet_off: int = 5) -> str:
    """The G-code of a speed ladder for `material`: a pierce and one straight cut per rung, the rung's
    number and speed in a message, so that the operator can match each edge to its speed."""
    where = f"{material.path or material.id}: material {material.id!r}: ladder"
    if not 2 <= ladder.rungs <= 40:
        raise MaterialError(f"{where}: rungs {ladder.rungs} must be 2 to 40")
    if not 0.0 < ladder.slowest_mm_min < ladder.fastest_mm_min <= 100000.0:
        raise MaterialError(f"{where}: speeds {ladder.slowest_mm_min:g} to {ladder.fastest_mm_min:g} mm/min must rise "
                            "from above 0 to at most 100000")
    for key in ("thickness_mm", "length_mm", "pitch_mm", "pierce_s"):
        value = getattr(ladder, key)
        if not (math.isfinite(value) and value > 0.0):
            raise MaterialError(f"{where}: {key} {value!r} must be a positive number")
    name = material.name.replace("(", "[").replace(")", "]")  # a comment cannot hold brackets
    lines = [f"(speed ladder: {name}, {ladder.thickness_mm:g} mm, {ladder.rungs} rungs "
             f"{ladder.slowest_mm_min:g} to {ladder.fastest_mm_min:g} mm/min)",
             "(cut it, then note per quality the fastest rung whose edge is good enough, and the fastest that cut through)",
             "G21 G90 G17 G40 G64 P0.05"]
    for k, speed in enumerate(ladder.speeds(), 1):
        y = ladder.y_mm + (k - 1) * ladder.pitch_mm
        lines += [f"(MSG,rung {k}: {speed:.0f} mm/min)", f"G0 X{ladder.x_mm:.3f} Y{y:.3f}", f"M{jet_on}",
                  f"G4 P{ladder.pierce_s:g}", f"G1 X{ladder.x_mm + ladder.length_mm:.3f} F{speed:.1f}", f"M{jet_off}"]
    lines += [f"G0 X{ladder.x_mm:.3f} Y{ladder.y_mm:.3f}", "M2", ""]
    return "\n".join(lines)


def record_calibration(path: str | Path, thickness_mm: float, separation_mm_min: float, quality_mm_min: list[float],
                       pierce_s: float, kerf_mm: float, who: str = "", lag_mm: list[float] | None = None) -> Material:
    """Write what a speed ladder showed into the material file at `path`: the row of `thickness_mm`
    (replaced when it exists) with the separation speed and the speed judged right per quality; the
    source line says who calibrated; `lag_mm`, when given, the trail-back measured on each quality's rung.
    Checked before the file is replaced (never half written)."""
    path = Path(path)
    m = load_material(path)
    row = ChartRow(float(thickness_mm), float(separation_mm_min), float(pierce_s), float(kerf_mm),
                   tuple(float(s) for s in quality_mm_min), tuple(float(x) for x in lag_mm or ()))
    updated = with_row(m, row)
    if who:
        note = f"calibrated {thickness_mm:g} mm by {who}"
        updated = replace(updated, source=m.source if note in m.source else f"{m.source}; {note}")
    original = path.read_text(encoding="utf-8").splitlines()
    header = []  # the file's opening comments stay
    for line in original:
        if not line.startswith("#"):
            break
        header.append(line)
    text = "\n".join(header + [render_material(updated)]) if header else render_material(updated)
    parse_material(tomllib.loads(text), m.id, str(path))
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return load_material(path)
