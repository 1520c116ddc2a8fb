"""The material library: cut charts read and checked (every error names the file, the material and
the key), speeds between rows interpolated as the power law the published models give, nothing
extrapolated; the speed ladder and what a calibration records; `waterjet materials`."""

from __future__ import annotations

import math
import shutil
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cnc.cli import main
from cnc.config import load_machine
from cnc.machine_dialect import dialect_for
from cnc.materials import (
    ChartRow, Ladder, MaterialError, ladder_program, load_library, load_material, parse_material, record_calibration,
)
from gcode.canon import LINE
from gcode.interp import Interpreter

from .conftest import REPO

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

STEEL = """# a chart for the tests: test data, not a shipped material
[material]
name = "Test steel"
kind = "abrasive"
source = "test data"

[head]
orifice_mm = 0.33
mixing_tube_mm = 1.02
pressure_bar = 3800
abrasive_kg_min = 0.35

[quality]
fractions = [1.0, 0.8, 0.6, 0.45, 0.3]

[[chart]]
thickness_mm = 2.0
separation_mm_min = 1000.0
pierce_s = 1.0
kerf_mm = 0.8

[[chart]]
thickness_mm = 8.0
separation_mm_min = 250.0
pierce_s = 4.0
kerf_mm = 1.0
quality_mm_min = [250.0, 190.0, 150.0, 100.0, 60.0]
"""


def write(tmp_path: Path, text: str, name: str = "steel") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def test_a_chart_gives_speed_pierce_and_kerf_per_thickness_and_quality(tmp_path):
    m = load_material(write(tmp_path, STEEL))
    assert m.calibrated and m.thickness_range == (2.0, 8.0) and m.head.pressure_bar == 3800.0
    assert m.cut(2.0, 1).speed_mm_min == 1000.0 and m.cut(2.0, 3).speed_mm_min == pytest.approx(600.0)
    assert m.cut(8.0, 2).speed_mm_min == 190.0, "a row's own quality speeds come before the fractions"
    mid = m.cut(4.0, 1)  # half way on logarithmic axes: the geometric mean of the speeds
    assert mid.speed_mm_min == pytest.approx(math.sqrt(1000.0 * 250.0))
    assert mid.pierce_s == pytest.approx(2.0) and mid.kerf_mm == pytest.approx(0.8 + 0.2 / 3)
    assert all(m.cut(5.0, q).speed_mm_min > m.cut(5.0, q + 1).speed_mm_min for q in (1, 2, 3, 4)), "finer is slower"


@settings(max_examples=60, deadline=None)
@given(c=st.floats(1000.0, 50000.0), k=st.floats(0.5, 1.5), h=st.floats(1.0, 20.0))
def test_between_rows_the_power_law_of_the_published_models_is_kept(c, k, h):
    """Zeng-Kim and Hlavac give the speed as a power of the thickness: a chart sampled from any such
    law gives that law back between its rows."""
    rows = [ChartRow(t, c * t**-k, 1.0, 0.5) for t in (1.0, 4.0, 20.0)]
    text = "\n".join(["[material]", 'name = "law"', 'kind = "water"', 'source = "test"', "[quality]",
                      "fractions = [1.0, 0.8, 0.6, 0.4, 0.2]"]
                     + [f"[[chart]]\nthickness_mm = {r.thickness_mm}\nseparation_mm_min = {r.separation_mm_min!r}\n"
                        f"pierce_s = 1.0\nkerf_mm = 0.5" for r in rows])
    m = parse_material(tomllib.loads(text), "law", "law.toml")
    assert m.cut(h, 1).speed_mm_min == pytest.approx(c * h**-k, rel=1e-9)


@pytest.mark.parametrize("change, where", [
    (("kind = \"abrasive\"", "kind = \"plasma\""), "[material] kind: 'plasma' is not one of: abrasive, water"),
    (("source = \"test data\"\n", ""), "[material] source: missing"),
    (("orifice_mm = 0.33", "orifice_mm = 0.33\nnozzle = 1"), "[head] nozzle: unknown key"),
    (("mixing_tube_mm = 1.02", "mixing_tube_mm = 0"), "[head] mixing_tube_mm: an abrasive cut needs a mixing tube"),
    (("fractions = [1.0, 0.8, 0.6, 0.45, 0.3]", "fractions = [1.0, 0.8, 0.9, 0.45, 0.3]"),
     "[quality] fractions: quality 3: 0.9 is faster than quality 2's 0.8"),
    (("fractions = [1.0, 0.8, 0.6, 0.45, 0.3]", "fractions = [1.0, 0.8]"), "[quality] fractions: expected five numbers"),
    (("thickness_mm = 8.0", "thickness_mm = 1.5"), "[[chart]] #2 thickness_mm: 1.5 mm: rows go from the thinnest"),
    (("separation_mm_min = 250.0", "separation_mm_min = 2500.0"),
     "[[chart]] #2 separation_mm_min: 2500 mm/min is faster than the thinner row's 1000"),
    (("quality_mm_min = [250.0,", "quality_mm_min = [300.0,"), "[[chart]] #2 quality_mm_min: quality 1 at 300 mm/min is faster"),
    (("pierce_s = 4.0", "pierce_s = -1"), "[[chart]] #2 pierce_s: -1 is out of range"),
    (("kerf_mm = 1.0", "kerf_mm = \"wide\""), "[[chart]] #2 kerf_mm: expected a number, got 'wide'"),
    (("[quality]\nfractions = [1.0, 0.8, 0.6, 0.45, 0.3]\n", ""),
     "[quality] fractions: missing, and the 2 mm row gives no quality_mm_min"),
])
def test_every_mistake_in_a_material_file_names_the_file_the_material_and_the_key(tmp_path, change, where):
    old, new = change
    assert old in STEEL
    path = write(tmp_path, STEEL.replace(old, new))
    with pytest.raises(MaterialError) as exc:
        load_material(path)
    assert str(exc.value).startswith(f"{path}: material 'steel': ") and where in str(exc.value), str(exc.value)


def test_what_a_chart_cannot_answer_is_refused_and_nothing_is_extrapolated(tmp_path):
    m = load_material(write(tmp_path, STEEL))
    for thickness, quality, why in ((12.0, 3, "outside its chart (2 to 8 mm)"), (1.0, 3, "outside its chart"),
                                    (4.0, 6, "quality 6 is not one of 1 to 5"), (-1.0, 1, "must be a positive number"),
                                    (math.nan, 1, "must be a positive number")):
        with pytest.raises(MaterialError, match=why.replace("(", r"\(").replace(")", r"\)")):
            m.cut(thickness, quality)
    leather = load_library(REPO / "machines" / "materials")["leather"]
    assert not leather.calibrated and leather.kind == "water"
    with pytest.raises(MaterialError, match="no cut chart yet: calibrate it"):
        leather.cut(2.0, 3)


def test_the_shipped_materials_load_and_cite_where_their_numbers_come_from():
    library = load_library(REPO / "machines" / "materials")
    assert {"leather", "textile"} <= set(library)
    assert all(m.source.strip() for m in library.values())


def test_a_speed_ladder_cuts_one_rung_per_speed_and_a_calibration_is_recorded(tmp_path):
    config = load_machine(REPO / "machines" / "waterjet.toml")
    path = tmp_path / "leather.toml"
    shutil.copy(REPO / "machines" / "materials" / "leather.toml", path)
    leather = load_material(path)
    ladder = Ladder(2.0, 3000.0, 24000.0, rungs=4)
    assert ladder.speeds() == pytest.approx([3000.0, 6000.0, 12000.0, 24000.0])
    program = Interpreter(dialect_for(config), "ladder").run(ladder_program(leather, ladder).encode())
    cuts = program.segments[(program.segments["kind"] == LINE) & program.segments["jet"]]
    assert len(cuts) == 4 and sorted(cuts["feed"]) == pytest.approx(ladder.speeds())
    assert [m.text for m in program.messages if m.kind == "message"][:2] == ["rung 1: 3000 mm/min", "rung 2: 6000 mm/min"]

    before = path.read_text()
    with pytest.raises(MaterialError, match="quality 2: 21000 is faster than quality 1's 20000"):
        record_calibration(path, 2.0, 20000.0, [20000.0, 21000.0, 12000.0, 9000.0, 6000.0], 0.3, 0.2)
    assert path.read_text() == before, "a refused calibration leaves the file as it was"
    m = record_calibration(path, 2.0, 20000.0, [20000.0, 16000.0, 12000.0, 9000.0, 6000.0], 0.3, 0.2, who="A. Operator")
    assert m.cut(2.0, 3).speed_mm_min == 12000.0 and "calibrated 2 mm by A. Operator" in m.source
    m = record_calibration(path, 4.0, 9000.0, [9000.0, 7000.0, 5000.0, 4000.0, 3000.0], 0.6, 0.25)
    m = record_calibration(path, 2.0, 22000.0, [22000.0, 16000.0, 12000.0, 9000.0, 6000.0], 0.3, 0.2)
    assert [r.thickness_mm for r in m.chart] == [2.0, 4.0] and m.chart[0].separation_mm_min == 22000.0, "replaced"
    assert path.read_text().startswith("# Leather"), "the file's opening comments stay"
    assert load_material(path) == m


def test_waterjet_materials_lists_shows_cuts_prints_a_ladder_and_records(tmp_path, capsys):
    shutil.copy(REPO / "machines" / "waterjet.toml", tmp_path / "machine.toml")
    (tmp_path / "materials").mkdir()
    write(tmp_path / "materials", STEEL)
    shutil.copy(REPO / "machines" / "materials" / "leather.toml", tmp_path / "materials" / "leather.toml")
    machine = str(tmp_path / "machine.toml")

    def run(*args: str) -> tuple[int, str, str]:
        code = main(["materials", "--machine", machine, *args])
        out = capsys.readouterr()
        return code, out.out, out.err

    code, out, _ = run()
    assert code == 0 and "leather" in out and "not calibrated" in out and "2 thicknesses, 2 to 8 mm" in out
    code, out, _ = run("cut", "steel", "--thickness", "4", "--quality", "1")
    assert code == 0 and "500 mm/min" in out
    code, _, err = run("cut", "steel", "--thickness", "9", "--quality", "1")
    assert code == 1 and "outside its chart" in err
    code, _, err = run("show", "granite")
    assert code == 1 and "no material 'granite'" in err and "known: leather, steel" in err
    code, out, _ = run("ladder", "leather", "--thickness", "2", "--from", "3000", "--to", "24000", "--rungs", "4")
    assert code == 0 and out.count("G4 P1") == 4
    code, _, err = run("ladder", "leather", "--thickness", "2", "--from", "3000", "--to", "900000")
    assert code == 1 and "beyond this machine's" in err
    code, out, _ = run("record", "leather", "--thickness", "2", "--separation", "20000", "--quality",
                       "20000,16000,12000,9000,6000", "--pierce", "0.3", "--kerf", "0.2", "--who", "A. Operator")
    assert code == 0 and "2 mm recorded" in out
    code, out, _ = run("show", "leather")
    assert code == 0 and "12000" in out and "A. Operator" in out
    code, _, err = run("record", "leather", "--thickness", "2", "--separation", "20000", "--quality", "1,2", "--pierce",
                       "0.3", "--kerf", "0.2")
    assert code == 2 and "five speeds" in err
