"""The guided calibration of a material, opened from the cutting job: a speed ladder made and loaded,
cut in the automatic cycle, and what its edges showed recorded into the material's chart.

Three steps, as the controller's `cnc.calibration` describes the procedure:

1. the ladder: material, thickness, slowest and fastest speed, rungs and pierce time; the controller
   makes the program, checks it against the machine, stores and loads it (`CalibrationLadder`), or
   refuses with the reason (the dialog stays on the step);
2. the cut: the operator cuts the loaded ladder in the automatic cycle; each rung is announced by a
   message naming its number and speed, as the rungs are listed here;
3. the record: per quality the fastest rung whose edge is good enough, the fastest that cut through,
   the pierce time and kerf, and optionally the trail-back per quality (`CalibrationRecord`).

The dialog is not modal: cycle start is on the screen behind it. Commands go through the screen's
`CommandRunner` (the GUI never waits on the controller); their buttons are enabled only while this
station holds the command lock, as every commanding button of the screen.
"""

from __future__ import annotations

from collections.abc import Callable

import msgspec
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QCheckBox, QComboBox, QDoubleSpinBox, QFormLayout, QHBoxLayout, QLabel, QListWidget, QPushButton, QSpinBox,
    QVBoxLayout, QWidget, QWizard, QWizardPage,
)

from cnc.bus.messages import CalibrationLadder, CalibrationRecord, MaterialEntry, MaterialList, Reply
from cnc.bus.states import CyclePhase

from .adapter import ModelAdapter
from .commands import CommandRunner, enable_while_commanding
from .style import show_reply

QUALITIES = (1, 2, 3, 4, 5)  # as the cutting job's: 1 separation (fastest, rough lower edge) to 5 the finest edge
QUALITY_WORDS = {1: "separation edge", 5: "finest edge"}
MIN_RUNGS, MAX_RUNGS = 2, 40  # what the controller's ladder takes
MAX_SPEED_MM_MIN = 100000.0  # the ladder's upper bound; the machine's own limit is the controller's to check
DEFAULT_RUNGS, DEFAULT_PIERCE_S = 8, 1.0  # the CalibrationLadder message's defaults


def ladder_speeds(slowest_mm_min: float, fastest_mm_min: float, rungs: int) -> list[float]:
    """The rungs' speeds, slowest first, in equal ratios: rung k (from 0) at slowest x r^k with
    r = (fastest / slowest) ** (1 / (rungs - 1)), so each rung is the same percentage faster than the
    one before and the ladder resolves slow and fast speeds alike. The controller makes the ladder's
    program with this formula (`cnc.materials.Ladder.speeds()`); the screen reaches the controller
    only through `cnc.bus`, so it is written again here, and a test holds the two equal."""
    if rungs == 1:
        return [slowest_mm_min]
    ratio = (fastest_mm_min / slowest_mm_min) ** (1.0 / (rungs - 1))
    return [slowest_mm_min * ratio**k for k in range(rungs)]


def rung_text(rung: int, speed_mm_min: float) -> str:
    """A rung as the ladder's message announces it while it is cut: "rung 4: 3374 mm/min"."""
    return f"rung {rung}: {speed_mm_min:.0f} mm/min"


def programmed_speed(speed_mm_min: float) -> float:
    """The speed a rung was cut at: the ladder's program writes its F word to 0.1 mm/min."""
    return round(speed_mm_min, 1)


def ladder_program_name(material_id: str, thickness_mm: float) -> str:
    """The name the controller stores and loads a ladder under (`cnc.calibration.ladder_name`)."""
    return f"ladder-{material_id}-{thickness_mm:g}mm.ngc"


def _material_text(entry: MaterialEntry) -> str:
    rows = entry.thicknesses_mm
    chart = "not calibrated" if not rows else (f"chart {rows[0]:g} mm" if len(rows) == 1
                                              else f"chart {rows[0]:g} to {rows[-1]:g} mm")
    return f"{entry.name} ({entry.id}): {chart}"


class _CommandPage(QWizardPage):
    """A step that sends one command and shows the answer; `answered(reply)` follows on the GUI thread."""

    answered = Signal(object)  # the Reply
    _reply = Signal(object)  # the Reply, from the command thread

    def __init__(self, commands: CommandRunner) -> None:
        super().__init__()
        self.commands = commands
        self.pending = False  # a command is on its way: its button waits for the answer
        self.reply = QLabel("")
        self.reply.setWordWrap(True)
        self.reply.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self._reply.connect(self._on_reply, Qt.ConnectionType.QueuedConnection)
        self._enable: Callable[[], None] = lambda: None

    def send(self, msg: msgspec.Struct) -> None:
        self.pending = True
        self._enable()
        self.reply.setText("")
        future = self.commands.send(msg)
        future.add_done_callback(lambda f: self._reply.emit(f.result()))

    def _on_reply(self, reply: Reply) -> None:
        self.pending = False
        self._enable()
        show_reply(self.reply, reply.ok, reply.reason)
        self.taken(reply)
        self.answered.emit(reply)

    def taken(self, reply: Reply) -> None:
        """What the step does with the controller's answer (shown already)."""


class LadderPage(_CommandPage):
    """Step 1: the ladder's parameters and "Make and load the ladder"; complete once the ladder of
    the parameters shown is loaded."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner) -> None:
        super().__init__(commands)
        self.model = adapter.model
        self.made: CalibrationLadder | None = None  # the ladder the controller made and loaded last
        self.setTitle("1. The speed ladder")
        self.material = QComboBox()
        self.material.setToolTip("Any material of the library, calibrated or not (a calibrated one gets "
                                 "another thickness, or the row of this thickness again)")
        self.thickness = QDoubleSpinBox()
        self.thickness.setRange(0.1, 500.0)
        self.thickness.setDecimals(2)
        self.thickness.setSingleStep(0.5)
        self.thickness.setValue(1.0)
        self.thickness.setSuffix(" mm")
        self.slowest = self._speed_box(500.0, "The slowest rung: slow enough that its edge is the finest wanted")
        self.fastest = self._speed_box(5000.0, "The fastest rung: fast enough that it does not cut through "
                                               "(the controller refuses a speed beyond the machine's)")
        self.rungs = QSpinBox()
        self.rungs.setRange(MIN_RUNGS, MAX_RUNGS)
        self.rungs.setValue(DEFAULT_RUNGS)
        self.rungs.setToolTip("Straight cuts from the slowest to the fastest speed, each the same percentage faster")
        self.pierce = QDoubleSpinBox()
        self.pierce.setRange(0.1, 60.0)
        self.pierce.setDecimals(1)
        self.pierce.setSingleStep(0.1)
        self.pierce.setValue(DEFAULT_PIERCE_S)
        self.pierce.setSuffix(" s")
        self.pierce.setToolTip("The dwell at each rung's pierce")
        self.make = QPushButton("Make and load the ladder")
        self.make.setToolTip("The controller makes the ladder, checks it against the machine, stores and loads it")
        self.make.clicked.connect(lambda: self.send(self.request()))
        for box in (self.thickness, self.slowest, self.fastest, self.pierce, self.rungs):
            box.valueChanged.connect(lambda _value: self.completeChanged.emit())
        self.material.currentIndexChanged.connect(lambda _index: self.completeChanged.emit())
        self._lay_out()
        self._enable = enable_while_commanding(adapter, [self.make], extra=self._may_make)
        adapter.status.connect(self._enable)

    @staticmethod
    def _speed_box(value: float, tip: str) -> QDoubleSpinBox:
        box = QDoubleSpinBox()
        box.setRange(1.0, MAX_SPEED_MM_MIN)
        box.setDecimals(0)
        box.setSingleStep(100.0)
        box.setValue(value)
        box.setSuffix(" mm/min")
        box.setToolTip(tip)
        return box

    def _lay_out(self) -> None:
        intro = QLabel("Bracket the speed the material needs: the slowest rung should leave the finest edge "
                       "wanted, the fastest should no longer cut through. The rungs rise in equal ratios.")
        intro.setWordWrap(True)
        form = QFormLayout()
        form.addRow("Material", self.material)
        form.addRow("Thickness", self.thickness)
        form.addRow("Slowest", self.slowest)
        form.addRow("Fastest", self.fastest)
        form.addRow("Rungs", self.rungs)
        form.addRow("Pierce time", self.pierce)
        layout = QVBoxLayout(self)
        layout.addWidget(intro)
        layout.addLayout(form)
        layout.addWidget(self.make, 0, Qt.AlignmentFlag.AlignLeft)
        layout.addWidget(self.reply)
        layout.addStretch(1)

    def _may_make(self) -> bool:
        """Not while a command is on its way, nor while the automatic cycle runs (a load is refused then)."""
        st = self.model.status
        return not self.pending and st is not None and st.cycle_phase == CyclePhase.NONE.name

    def show_materials(self, listing: MaterialList) -> None:
        """Offer every material of the library, keeping the choice."""
        keep = self.material.currentData()
        self.material.blockSignals(True)
        self.material.clear()
        for entry in listing.entries:
            self.material.addItem(_material_text(entry), entry.id)
            self.material.setItemData(self.material.count() - 1, f"{entry.kind} jet; {entry.source}",
                                      Qt.ItemDataRole.ToolTipRole)
        index = self.material.findData(keep) if keep is not None else -1
        self.material.setCurrentIndex(index if index >= 0 else min(0, self.material.count() - 1))
        self.material.blockSignals(False)
        self.completeChanged.emit()

    def request(self) -> CalibrationLadder:
        """The ladder the inputs say."""
        return CalibrationLadder(self.material.currentData() or "", self.thickness.value(), self.slowest.value(),
                                 self.fastest.value(), self.rungs.value(), self.pierce.value())

    def taken(self, reply: Reply) -> None:
        if reply.ok:
            self.made = self.request()
        self.completeChanged.emit()

    def isComplete(self) -> bool:  # noqa: N802 - Qt's override
        """On to the cut once the ladder of these very parameters is loaded (changed: made again first)."""
        return self.made is not None and self.made == self.request()


class CutPage(QWizardPage):
    """Step 2: how to cut the loaded ladder, its rungs as their messages announce them, and whether
    the ladder is still the program loaded."""

    def __init__(self, adapter: ModelAdapter, ladder: LadderPage) -> None:
        super().__init__()
        self.model, self.ladder = adapter.model, ladder
        self.setTitle("2. Cut the ladder")
        steps = QLabel("<ol><li>Put the material on the machine: the loaded program's preview shows where "
                       "the rungs are cut.</li>"
                       "<li>Switch to AUTO and press <b>Cycle start</b>. Each rung is announced by a message "
                       "with its number and speed, as listed below.</li>"
                       "<li>When the cut is done, judge each rung's edge and its lower side, measure the kerf "
                       "(and the trail-back, if you can), then go on to record them.</li></ol>")
        steps.setWordWrap(True)
        self.rungs = QListWidget()
        self.loaded = QLabel("")
        self.loaded.setWordWrap(True)
        layout = QVBoxLayout(self)
        layout.addWidget(steps)
        layout.addWidget(QLabel("The rungs, slowest first"))
        layout.addWidget(self.rungs, 1)
        layout.addWidget(self.loaded)
        adapter.status.connect(self._show_loaded)

    def initializePage(self) -> None:  # noqa: N802 - Qt's override
        """The rungs of the ladder made."""
        made = self.ladder.made
        self.rungs.clear()
        if made is not None:
            speeds = ladder_speeds(made.slowest_mm_min, made.fastest_mm_min, made.rungs)
            self.rungs.addItems([rung_text(k, s) for k, s in enumerate(speeds, 1)])
        self._show_loaded()

    def _show_loaded(self) -> None:
        """Whether the program loaded now is still the ladder (another program loaded meanwhile is not)."""
        made, st = self.ladder.made, self.model.status
        if made is None or st is None:
            return
        expected = ladder_program_name(made.material, made.thickness_mm)
        name = st.program.name if st.program is not None else ""
        if name == expected:
            show_reply(self.loaded, True, f"Loaded: {expected}")
        else:
            show_reply(self.loaded, False, f"The program loaded is {name or 'none'}, not {expected}: "
                                           "go back and make the ladder again to cut it")


class RecordPage(_CommandPage):
    """Step 3: what the cut ladder showed, per quality and for the row, and "Record"; complete once recorded."""

    recorded = Signal(object)  # the Reply of a calibration written: the material library changed

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, ladder: LadderPage) -> None:
        super().__init__(commands)
        self.ladder = ladder
        self.filled_for: CalibrationLadder | None = None  # the ladder whose rungs the choices offer
        self.done = False
        self.setTitle("3. Record what the cut showed")
        self.heading = QLabel("")
        self.heading.setWordWrap(True)
        self.quality = [self._rung_box(f"the fastest rung whose edge is good enough for quality {q}")
                        for q in QUALITIES]
        self.separation = self._rung_box("the fastest rung that cut through")
        self.pierce = QDoubleSpinBox()
        self.pierce.setRange(0.1, 60.0)
        self.pierce.setDecimals(1)
        self.pierce.setSingleStep(0.1)
        self.pierce.setSuffix(" s")
        self.pierce.setToolTip("A pierce time that went through")
        self.kerf = QDoubleSpinBox()
        self.kerf.setRange(0.0, 5.0)
        self.kerf.setDecimals(2)
        self.kerf.setSingleStep(0.01)
        self.kerf.setSuffix(" mm")
        self.kerf.setSpecialValueText("measure it")
        self.kerf.setToolTip("The width of the cut, measured")
        self.trail_back = QCheckBox("Trail-back measured on each quality's rung")
        self.trail_back.setToolTip("How far the bottom of the cut runs behind the top: with it, corners and arcs "
                                   "are slowed to each quality's allowed deviation")
        self.lag = [self._lag_box(q) for q in QUALITIES]
        self.trail_back.toggled.connect(self._enable_lags)
        self.record = QPushButton("Record")
        self.record.setToolTip("Write this row into the material's chart (an engineer's change)")
        self.record.clicked.connect(self.send_record)
        self._lay_out()
        self._enable = enable_while_commanding(adapter, [self.record], extra=lambda: not self.pending)

    @staticmethod
    def _rung_box(tip: str) -> QComboBox:
        box = QComboBox()
        box.setPlaceholderText("choose the rung")
        box.setToolTip(tip)
        return box

    @staticmethod
    def _lag_box(quality: int) -> QDoubleSpinBox:
        box = QDoubleSpinBox()
        box.setRange(0.0, 20.0)
        box.setDecimals(2)
        box.setSingleStep(0.05)
        box.setSuffix(" mm")
        box.setToolTip(f"trail-back at quality {quality}'s rung")
        box.setEnabled(False)
        return box

    def _enable_lags(self, on: bool) -> None:
        for box in self.lag:
            box.setEnabled(on)

    def _lay_out(self) -> None:
        form = QFormLayout()
        for q, box in zip(QUALITIES, self.quality):
            word = QUALITY_WORDS.get(q)
            form.addRow(f"Quality {q}" + (f" ({word})" if word else ""), box)
        form.addRow("Cut through up to", self.separation)
        form.addRow("Pierce time", self.pierce)
        form.addRow("Kerf", self.kerf)
        lags = QHBoxLayout()
        for q, box in zip(QUALITIES, self.lag):
            lags.addWidget(QLabel(f"{q}"))
            lags.addWidget(box)
        layout = QVBoxLayout(self)
        layout.addWidget(self.heading)
        layout.addLayout(form)
        layout.addWidget(self.trail_back)
        layout.addLayout(lags)
        layout.addWidget(self.record, 0, Qt.AlignmentFlag.AlignLeft)
        layout.addWidget(self.reply)
        layout.addStretch(1)

    def initializePage(self) -> None:  # noqa: N802 - Qt's override
        """The rungs of the ladder made, fastest first, in every choice; kept while it is the same ladder."""
        made = self.ladder.made
        if made is None or made == self.filled_for:
            return
        self.filled_for, self.done = made, False
        self.heading.setText(f"{made.material}, {made.thickness_mm:g} mm: choose per quality the fastest rung whose "
                             "edge is good enough (a finer edge is slower), and the fastest that cut through.")
        speeds = ladder_speeds(made.slowest_mm_min, made.fastest_mm_min, made.rungs)
        rungs = list(reversed(list(enumerate(speeds, 1))))
        for box in (*self.quality, self.separation):
            box.clear()
            for k, speed in rungs:
                box.addItem(rung_text(k, speed), programmed_speed(speed))
            box.setCurrentIndex(-1)
        self.pierce.setValue(made.pierce_s)
        self.kerf.setValue(0.0)
        self.reply.setText("")
        self.completeChanged.emit()

    def missing(self) -> str:
        """What is still to be entered before the row can be recorded ("" when nothing is)."""
        for q, box in zip(QUALITIES, self.quality):
            if box.currentIndex() < 0:
                return f"choose the rung of quality {q}"
        if self.separation.currentIndex() < 0:
            return "choose the fastest rung that cut through"
        if self.kerf.value() <= 0.0:
            return "measure the kerf"
        return ""

    def send_record(self) -> None:
        """Send the row; what is missing is said instead, and nothing is sent."""
        made, missing = self.ladder.made, self.missing()
        if made is None or missing:
            show_reply(self.reply, False, missing or "make and cut a ladder first")
            return
        self.send(CalibrationRecord(made.material, made.thickness_mm, self.separation.currentData(),
                                    [box.currentData() for box in self.quality], self.pierce.value(),
                                    self.kerf.value(),
                                    [box.value() for box in self.lag] if self.trail_back.isChecked() else []))

    def taken(self, reply: Reply) -> None:
        if reply.ok:
            self.done = True
            self.recorded.emit(reply)
        self.completeChanged.emit()

    def isComplete(self) -> bool:  # noqa: N802 - Qt's override
        """Finished once the row is recorded."""
        return self.done


class CalibrationDialog(QWizard):
    """The three steps; `answered(reply)` after each command, `recorded(reply)` when the library changed."""

    answered = Signal(object)  # the Reply to the last command
    recorded = Signal(object)  # the Reply of a calibration written

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Calibrate a material")
        self.setOption(QWizard.WizardOption.NoBackButtonOnStartPage)
        self.ladder_page = LadderPage(adapter, commands)
        self.cut_page = CutPage(adapter, self.ladder_page)
        self.record_page = RecordPage(adapter, commands, self.ladder_page)
        for page in (self.ladder_page, self.cut_page, self.record_page):
            self.addPage(page)
        for page in (self.ladder_page, self.record_page):
            page.answered.connect(self.answered)
        self.record_page.recorded.connect(self.recorded)
        self.accepted.connect(self._start_over_when_opened)
        self._start_over = False

    def show_materials(self, listing: MaterialList) -> None:
        """The library as the cutting job lists it (a material calibrated meanwhile says so)."""
        self.ladder_page.show_materials(listing)

    def present(self) -> None:
        """Show the dialog, where the operator left it; at the first step again after a calibration finished."""
        if self._start_over:
            self._start_over = False
            self.ladder_page.made = self.record_page.filled_for = None
            for page in (self.ladder_page, self.record_page):
                page.reply.setText("")
            self.restart()
        self.show()
        self.raise_()
        self.activateWindow()

    def _start_over_when_opened(self) -> None:
        self._start_over = True
