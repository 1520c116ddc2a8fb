"""The guided material calibration from the cutting job against a real controller on the virtual clock
(pytest-qt, offscreen): the ladder for an uncalibrated material made and loaded (a refused one shown
with its reason, the dialog staying on its step), its rungs listed as their messages announce them,
what the cut showed recorded into the material's file (a refusal writing nothing), and the material
then offered for a job; the commanding buttons greyed without the lock."""

from __future__ import annotations

import tomllib

import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QComboBox, QWizard

from cnc.materials import Ladder
from hmi.calibration import CalibrationDialog, ladder_program_name, ladder_speeds
from hmi.model import Screen

from .test_hmi_cutjob import FELT, cut_controller, cut_screen, listed, ready_in_auto_from_the_screen  # noqa: F401 - the fixtures, by import
from .test_hmi_window import WAIT_MS, click, shot, take_lock


def choose(box: QComboBox, text: str) -> None:
    """Pick an offered item by what the operator reads."""
    index = box.findText(text)
    assert index >= 0, f"{text!r} is not offered: {[box.itemText(i) for i in range(box.count())]}"
    box.setCurrentIndex(index)


def answer_to(qtbot, dialog: CalibrationDialog, button):
    """Click a command button of the dialog and return the controller's answer as the dialog shows it."""
    qtbot.waitUntil(button.isEnabled, timeout=WAIT_MS)
    with qtbot.waitSignal(dialog.answered, timeout=WAIT_MS) as blocker:
        qtbot.mouseClick(button, Qt.MouseButton.LeftButton)
    return blocker.args[0]


def test_the_rungs_listed_are_the_speeds_of_the_controllers_ladder():
    for slowest, fastest, rungs in ((600.0, 6000.0, 5), (100.0, 100000.0, 40), (1000.0, 1001.0, 2), (250.0, 4000.0, 8)):
        assert ladder_speeds(slowest, fastest, rungs) == pytest.approx(
            Ladder(3.0, slowest, fastest, rungs).speeds(), rel=1e-12), (slowest, fastest, rungs)


def test_a_material_is_calibrated_from_the_cutting_job_ladder_loaded_then_what_its_cut_showed_recorded(
        qtbot, cut_controller, cut_screen, tmp_path):
    sup, screen = cut_controller, cut_screen
    w = screen.window
    panel = w.pages[Screen.AUTO].cut_job
    felt_file = tmp_path / "materials" / "felt.toml"
    felt_file.write_text(FELT)
    take_lock(qtbot, screen)
    ready_in_auto_from_the_screen(qtbot, screen)
    qtbot.waitUntil(lambda: w.current_screen is Screen.AUTO and "felt" in listed(panel), timeout=WAIT_MS)
    assert listed(panel)["felt"] == ("Test felt (not calibrated)", False)

    qtbot.mouseClick(panel.calibrate, Qt.MouseButton.LeftButton)
    dialog = panel.calibration
    qtbot.waitExposed(dialog)
    ladder, next_button = dialog.ladder_page, dialog.button(QWizard.WizardButton.NextButton)
    assert ladder.material.itemText(ladder.material.findData("felt")) == "Test felt (felt): not calibrated"
    ladder.material.setCurrentIndex(ladder.material.findData("felt"))
    ladder.thickness.setValue(3.0)
    ladder.slowest.setValue(600.0)
    ladder.fastest.setValue(90000.0)
    ladder.rungs.setValue(5)
    ladder.pierce.setValue(0.5)
    refused = answer_to(qtbot, dialog, ladder.make)
    assert not refused.ok and "the fastest rung 90000 mm/min is beyond this machine's" in refused.reason
    assert ladder.reply.text() == f"✖ {refused.reason}"
    assert dialog.currentPage() is ladder and not next_button.isEnabled(), "a refused ladder stays on its step"
    assert sup.motion()["program_name"] != "ladder-felt-3mm.ngc"

    ladder.fastest.setValue(6000.0)
    made = answer_to(qtbot, dialog, ladder.make)
    assert made.ok, made.reason
    assert made.reason.startswith("ladder-felt-3mm.ngc loaded: 5 rungs at 600, 1067, 1897, 3374, 6000 mm/min")
    assert ladder.reply.text() == made.reason
    assert sup.motion()["program_name"] == "ladder-felt-3mm.ngc" == ladder_program_name("felt", 3.0)
    assert next_button.isEnabled()
    ladder.rungs.setValue(6)
    assert not next_button.isEnabled(), "other parameters than the ladder loaded: it is made again first"
    ladder.rungs.setValue(5)
    assert next_button.isEnabled()

    qtbot.mouseClick(next_button, Qt.MouseButton.LeftButton)
    cut = dialog.cut_page
    assert dialog.currentPage() is cut
    rungs = [cut.rungs.item(i).text() for i in range(cut.rungs.count())]
    assert rungs == ["rung 1: 600 mm/min", "rung 2: 1067 mm/min", "rung 3: 1897 mm/min", "rung 4: 3374 mm/min",
                     "rung 5: 6000 mm/min"], "as the ladder's messages announce them, and as the controller said"
    qtbot.waitUntil(lambda: cut.loaded.text() == "Loaded: ladder-felt-3mm.ngc", timeout=WAIT_MS)
    shot(dialog, "auto_calibration_cut")

    qtbot.mouseClick(next_button, Qt.MouseButton.LeftButton)
    record = dialog.record_page
    assert dialog.currentPage() is record and record.pierce.value() == 0.5, "the ladder's pierce time offered"
    assert [record.separation.itemText(i) for i in range(record.separation.count())] == rungs[::-1], "fastest first"
    qtbot.mouseClick(record.record, Qt.MouseButton.LeftButton)
    assert record.reply.text() == "✖ choose the rung of quality 1", "nothing sent while a choice is missing"
    for box, rung in zip(record.quality, ("rung 4: 3374 mm/min", "rung 3: 1897 mm/min", "rung 4: 3374 mm/min",
                                          "rung 2: 1067 mm/min", "rung 1: 600 mm/min")):
        choose(box, rung)
    choose(record.separation, "rung 4: 3374 mm/min")
    record.pierce.setValue(0.5)
    record.kerf.setValue(0.2)
    refused = answer_to(qtbot, dialog, record.record)
    assert not refused.ok
    speeds = [round(s, 1) for s in Ladder(3.0, 600.0, 6000.0, 5).speeds()]  # as the rungs' F words say
    assert f"quality 3: {speeds[3]:g} is faster than quality 2's {speeds[2]:g}: a finer edge is slower" \
        in refused.reason
    assert record.reply.text() == f"✖ {refused.reason}"
    assert "[[chart]]" not in felt_file.read_text(), "a refusal writes nothing"
    assert not dialog.button(QWizard.WizardButton.FinishButton).isEnabled()

    choose(record.quality[2], "rung 3: 1897 mm/min")
    assert all(not box.isEnabled() for box in record.lag)
    record.trail_back.setChecked(True)
    for box, lag_mm in zip(record.lag, (0.9, 0.6, 0.6, 0.25, 0.1)):  # the lag is the rung's: 2 and 3 share one
        box.setValue(lag_mm)
    shot(dialog, "auto_calibration_record")
    with qtbot.waitSignal(panel.listed, timeout=WAIT_MS):  # the cutting job asks for the library again
        recorded = answer_to(qtbot, dialog, record.record)
    assert recorded.ok and recorded.reason == "felt: 3 mm recorded; its chart covers 3 mm"
    assert record.reply.text() == recorded.reason
    (row,) = tomllib.loads(felt_file.read_text())["chart"]
    assert row["thickness_mm"] == 3.0 and row["separation_mm_min"] == speeds[3]
    assert row["quality_mm_min"] == [speeds[3], speeds[2], speeds[2], speeds[1], speeds[0]], "as the rungs cut"
    assert (row["pierce_s"], row["kerf_mm"], row["lag_mm"]) == (0.5, 0.2, [0.9, 0.6, 0.6, 0.25, 0.1])
    # the library asked for again after the record (a listing asked before it may answer first)
    qtbot.waitUntil(lambda: listed(panel)["felt"] == ("Test felt", True), timeout=WAIT_MS)
    assert ladder.material.itemText(ladder.material.findData("felt")) == "Test felt (felt): chart 3 mm"

    finish = dialog.button(QWizard.WizardButton.FinishButton)
    assert finish.isEnabled()
    qtbot.mouseClick(finish, Qt.MouseButton.LeftButton)
    assert not dialog.isVisible()
    qtbot.mouseClick(panel.calibrate, Qt.MouseButton.LeftButton)
    assert dialog.isVisible() and dialog.currentPage() is ladder and not next_button.isEnabled(), "a new calibration"

    click(qtbot, screen, w.bar.lock_button)  # released: nothing can be sent
    qtbot.waitUntil(lambda: not ladder.make.isEnabled() and not record.record.isEnabled(), timeout=WAIT_MS)
    dialog.close()
