"""The cutting job on the AUTO page against a real controller on the virtual clock (pytest-qt,
offscreen): the material library as the controller has it (an uncalibrated material listed greyed),
the thickness held to the chart, each quality offered with its interpolated straight speed, the job
applied and shown in force, a refusal shown with its reason, and back to the program's own feed;
the controls greyed without a loaded program or the lock, and during the automatic cycle."""

from __future__ import annotations

import tomllib

import pytest
from PySide6.QtCore import Qt

from cnc.bus.messages import MaterialEntry
from cnc.materials import parse_material
from hmi.cutjob import PROGRAMMED_FEED, CutJobPanel, quality_speeds
from hmi.model import Screen
from hmi.style import duration

from .conftest import NEAR_HOME, full_controller, machine_config
from .test_cut_model import HIDE, hide_library
from .test_hmi_window import WAIT_MS, _screen_on, click, shot, take_lock
from .test_zenoh_interface import PART

FELT = """[material]
name = "Test felt"
kind = "water"
source = "not calibrated yet"
"""


@pytest.fixture
def cut_controller(tmp_path):
    """The whole controller with the test hide in its material library (a tmp dir)."""
    library = hide_library(tmp_path / "materials")
    config = machine_config(**NEAR_HOME, **{"cutting.materials_dir": str(library)})
    with full_controller(config, tmp_path / "history.sqlite") as sup:
        yield sup


@pytest.fixture
def cut_screen(qtbot, cut_controller):
    yield from _screen_on(qtbot, cut_controller)


def ready_in_auto_from_the_screen(qtbot, screen) -> None:
    """With the lock taken: reset, home all, then the AUTO page, each from its button."""
    w, model = screen.window, screen.model
    click(qtbot, screen, w.bar.reset)
    qtbot.waitUntil(lambda: all(a.drive_enabled for a in model.status.axes), timeout=WAIT_MS)
    click(qtbot, screen, w.pages[Screen.MANUAL].home_all)
    qtbot.waitUntil(lambda: model.status.machine_state == "READY", timeout=WAIT_MS)
    click(qtbot, screen, w.bar.auto)


def speeds_shown(panel: CutJobPanel) -> list[str]:
    return [panel.quality.itemText(i) for i in range(panel.quality.count())]


def listed(panel: CutJobPanel) -> dict[str, tuple[str, bool]]:
    """The material list as the operator sees it: id -> (text, selectable)."""
    items = panel.material.model()
    return {panel.material.itemData(i): (panel.material.itemText(i), items.item(i).isEnabled())
            for i in range(panel.material.count())}


def test_the_quality_speeds_offered_are_the_chart_s_read_as_the_controller_s_model_reads_it():
    model = parse_material(tomllib.loads(HIDE), "hide", "hide.toml")
    rows = [r.thickness_mm for r in model.chart]
    hide = MaterialEntry("hide", model.name, model.kind, model.source, rows,
                         [[model.cut(t, q).speed_mm_min for q in range(1, 6)] for t in rows], True)
    for thickness in (2.0, 2.37, 3.0, 3.5, 3.99, 4.0):
        assert quality_speeds(hide, thickness) == pytest.approx(
            [model.cut(thickness, q).speed_mm_min for q in range(1, 6)], rel=1e-12), thickness
    assert quality_speeds(hide, 4.0) == [3000.0, 2400.0, 1800.0, 1200.0, 600.0], "exact at a row"
    for outside in (1.99, 4.01):
        with pytest.raises(ValueError, match="outside the chart"):
            quality_speeds(hide, outside)
    with pytest.raises(ValueError, match="not calibrated"):
        quality_speeds(MaterialEntry("felt", "Test felt", "water", "none", [], [], False), 2.0)


def test_the_cutting_job_is_chosen_on_the_auto_page_shown_in_force_and_given_back_to_the_program(
        qtbot, cut_controller, cut_screen, tmp_path):
    sup, screen = cut_controller, cut_screen
    w, model = screen.window, screen.model
    auto = w.pages[Screen.AUTO]
    panel = auto.cut_job
    assert not panel.apply.isEnabled(), "read-only: greyed"
    take_lock(qtbot, screen)
    ready_in_auto_from_the_screen(qtbot, screen)
    qtbot.waitUntil(lambda: w.current_screen is Screen.AUTO, timeout=WAIT_MS)

    qtbot.waitUntil(lambda: "hide" in listed(panel), timeout=WAIT_MS)  # asked for when the page is shown
    assert listed(panel) == {"hide": ("Test hide", True)}
    assert not panel.apply.isEnabled() and panel.refresh_button.isEnabled(), "no program loaded: nothing to set up"
    (tmp_path / "materials" / "felt.toml").write_text(FELT)
    with qtbot.waitSignal(panel.listed, timeout=WAIT_MS):
        qtbot.mouseClick(panel.refresh_button, Qt.MouseButton.LeftButton)
    assert listed(panel) == {"felt": ("Test felt (not calibrated)", False), "hide": ("Test hide", True)}
    assert panel.material.currentData() == "hide", "an uncalibrated material is never chosen for the operator"

    part = tmp_path / "part.ngc"
    part.write_text(PART)
    with qtbot.waitSignal(auto.program.uploaded, timeout=WAIT_MS) as loaded:
        auto.program.load_file(part)
    assert loaded.args[0].ok, loaded.args[0].reason
    qtbot.waitUntil(panel.apply.isEnabled, timeout=WAIT_MS)
    assert panel.in_force.text() == PROGRAMMED_FEED and sup.motion()["cut"] == ""

    panel.material.setCurrentIndex(panel.material.findData("hide"))
    assert (panel.thickness.minimum(), panel.thickness.maximum(), panel.thickness.decimals()) == (2.0, 4.0, 2)
    for outside, held in ((9.0, 4.0), (1.0, 2.0)):
        panel.thickness.setValue(outside)
        assert panel.thickness.value() == held, "a thickness outside the chart cannot be entered"
    assert speeds_shown(panel) == ["1: 6000 mm/min", "2: 4800 mm/min", "3: 3600 mm/min", "4: 2400 mm/min",
                                   "5: 1200 mm/min"], "at a chart row, its speeds"
    panel.thickness.setValue(3.0)
    # between the 2 and 4 mm rows on log-log axes: v = v2 * (v4 / v2) ** (ln 1.5 / ln 2) = v2 * 2/3 here
    assert speeds_shown(panel) == ["1: 4000 mm/min", "2: 3200 mm/min", "3: 2400 mm/min", "4: 1600 mm/min",
                                   "5: 800 mm/min"]
    panel.quality.setCurrentIndex(panel.quality.findData(2))
    assert panel.mode.currentData() == "quality"

    job = "hide 3 mm quality 2, by the operator"
    reply = click(qtbot, screen, panel.apply)
    assert reply.reason == job
    qtbot.waitUntil(lambda: panel.in_force.text() == job and panel.reply.text() == job, timeout=WAIT_MS)
    assert sup.motion()["cut"] == job
    program_tab = w.pages[Screen.AUTO].program
    qtbot.waitUntil(lambda: f"cutting job: {job}" in program_tab.info.text() and sup.motion()["planned_s"] > 0,
                    timeout=WAIT_MS)
    planned = sup.motion()["planned_s"]
    qtbot.waitUntil(lambda: f"planned cycle time {duration(planned)}" in program_tab.info.text(), timeout=WAIT_MS)
    shot(w, "auto_cut_job")

    (tmp_path / "materials" / "hide.toml").unlink()  # the library changed behind the list shown
    panel.quality.setCurrentIndex(panel.quality.findData(4))
    with qtbot.waitSignal(panel.answered, timeout=WAIT_MS) as refused:
        click(qtbot, screen, panel.apply, ok=False)
    assert "material 'hide' is not in the library" in refused.args[0].reason
    assert panel.reply.text() == f"✖ {refused.args[0].reason}"
    assert panel.in_force.text() == job and sup.motion()["cut"] == job, "a refusal changes nothing"
    hide_library(tmp_path / "materials")

    click(qtbot, screen, auto.cycle_start)  # the automatic cycle: its transport procedure first
    qtbot.waitUntil(lambda: model.status.cycle_phase != "NONE", timeout=WAIT_MS)
    qtbot.waitUntil(lambda: not panel.apply.isEnabled() and not panel.programs_own.isEnabled(), timeout=WAIT_MS)
    procedure = w.pages[Screen.PROCEDURE].procedure  # the operator stops it at its awaited step, and ends it
    click(qtbot, screen, procedure.stop)
    qtbot.waitUntil(procedure.end.isEnabled, timeout=WAIT_MS)
    click(qtbot, screen, procedure.end)
    qtbot.waitUntil(lambda: model.status.cycle_phase == "NONE" and w.current_screen is Screen.AUTO, timeout=WAIT_MS)
    qtbot.waitUntil(panel.programs_own.isEnabled, timeout=WAIT_MS)

    reply = click(qtbot, screen, panel.programs_own)
    assert reply.reason == "part.ngc cuts at its programmed feed"
    qtbot.waitUntil(lambda: panel.in_force.text() == PROGRAMMED_FEED, timeout=WAIT_MS)
    assert sup.motion()["cut"] == ""

    click(qtbot, screen, w.bar.lock_button)  # released: read-only again
    qtbot.waitUntil(lambda: not panel.apply.isEnabled() and not panel.material.isEnabled(), timeout=WAIT_MS)
