"""The cutting job on the automatic page: the material, thickness, edge quality and mode the loaded
program is cut with, chosen from the controller's material library before cycle start.

Each quality is offered with its straight speed at the thickness chosen, read off the material's
chart as the controller reads it (`cnc.materials`): exact at a chart row, between two rows
interpolated on logarithmic axes (the cutting speed falls as a power of the thickness), nothing
outside the chart. The controller has the last word: it takes the job, says what is in force, or
refuses with the reason. The library is asked for on a worker thread: the screen never waits.
"""

from __future__ import annotations

import math
from typing import Protocol

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QShowEvent, QStandardItemModel
from PySide6.QtWidgets import (
    QComboBox, QDoubleSpinBox, QFormLayout, QGroupBox, QHBoxLayout, QLabel, QPushButton, QVBoxLayout, QWidget,
)

from cnc.bus.messages import MaterialEntry, MaterialList, Reply, SetCut
from cnc.bus.states import CyclePhase

from .adapter import ModelAdapter
from .calibration import CalibrationDialog
from .commands import BackgroundQuery, CommandRunner, enable_while_commanding
from .style import show_reply

QUALITIES = (1, 2, 3, 4, 5)  # 1 separation (fastest, rough lower edge) to 5 the finest edge
MODES = (("machine uses quality", "quality"), ("machine uses feed", "feed"))  # (shown, SetCut.mode)
PROGRAMMED_FEED = "programmed feed"  # what is in force when no job is: the program's own F
DEFAULT_QUALITY = 3
THICKNESS_STEP_MM = 0.5
_ON_ROW_MM = 1e-9  # a thickness this close to a chart row is that row (as `cnc.materials` takes it)


class MaterialSource(Protocol):
    """What answers the material library query (`hmi.connection.Connection` fits); a blocking call."""

    def materials(self) -> MaterialList: ...


def quality_speeds(entry: MaterialEntry, thickness_mm: float) -> list[float]:
    """The straight speed of qualities 1..5 for `thickness_mm`, mm/min, from the material's chart:
    a row's own speeds at a row; between rows a and b, on log-log axes,
    v = v_a * (v_b / v_a) ** (ln(t / t_a) / ln(t_b / t_a)), as the controller's model computes it.
    ValueError for a material without a chart or a thickness outside it (nothing is extrapolated)."""
    rows = entry.thicknesses_mm
    if not rows:
        raise ValueError(f"material {entry.id!r} has no cut chart: it is not calibrated")
    if not rows[0] - _ON_ROW_MM <= thickness_mm <= rows[-1] + _ON_ROW_MM:
        raise ValueError(f"thickness {thickness_mm:g} mm is outside the chart of {entry.id!r} "
                         f"({rows[0]:g} to {rows[-1]:g} mm)")
    k = next(i for i, t in enumerate(rows) if t >= thickness_mm - _ON_ROW_MM)
    if k == 0 or abs(rows[k] - thickness_mm) < _ON_ROW_MM:
        return list(entry.speeds_mm_min[k])
    t_a, t_b = rows[k - 1], rows[k]
    w = math.log(thickness_mm / t_a) / math.log(t_b / t_a)
    return [math.exp(math.log(v_a) + w * (math.log(v_b) - math.log(v_a)))
            for v_a, v_b in zip(entry.speeds_mm_min[k - 1], entry.speeds_mm_min[k])]


class CutJobPanel(QGroupBox):
    """The job in force, the choice of material, thickness, quality and mode, Apply, the program's own."""

    listed = Signal(object)  # the MaterialList shown
    answered = Signal(object)  # the Reply to the last job sent
    _listing = Signal(object)  # the MaterialList or the exception, from the worker
    _reply = Signal(object)  # the Reply, from the command thread

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, source: MaterialSource,
                 parent: QWidget | None = None) -> None:
        super().__init__("Cutting job", parent)
        self.adapter, self.model, self.commands, self.source = adapter, adapter.model, commands, source
        self.calibration: CalibrationDialog | None = None  # made when first asked for
        self.queries = BackgroundQuery("hmi-materials")
        self.entries: dict[str, MaterialEntry] = {}
        self.listing: MaterialList | None = None
        self.in_force = QLabel(PROGRAMMED_FEED)
        self.in_force.setWordWrap(True)
        self.in_force.setStyleSheet("font-weight: bold;")
        self.material = QComboBox()
        self.material.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToMinimumContentsLengthWithIcon)
        self.material.setMinimumContentsLength(16)
        self.material.currentIndexChanged.connect(lambda _index: self._show_chart())
        self.thickness = QDoubleSpinBox()
        self.thickness.setDecimals(2)
        self.thickness.setSingleStep(THICKNESS_STEP_MM)
        self.thickness.setSuffix(" mm")
        self.thickness.valueChanged.connect(lambda _value: self._show_speeds())
        self.quality = QComboBox()
        self.quality.setToolTip("1 separation (fastest, rough lower edge) to 5 the finest edge; "
                                "the straight speed at this thickness")
        for q in QUALITIES:
            self.quality.addItem(str(q), q)
        self.quality.setCurrentIndex(self.quality.findData(DEFAULT_QUALITY))
        self.mode = QComboBox()
        self.mode.setToolTip("quality: the model sets the speed, the program's F is only an upper bound; "
                             "feed: the program's F as programmed")
        for text, mode in MODES:
            self.mode.addItem(text, mode)
        self.apply = QPushButton("Apply")
        self.apply.setToolTip("Cut the loaded program with this material, thickness and quality")
        self.apply.clicked.connect(self.apply_job)
        self.programs_own = QPushButton("Program's own")
        self.programs_own.setToolTip("Back to what the program says: its (MATERIAL, ...) comment, or its F")
        self.programs_own.clicked.connect(self.program_job)
        self.refresh_button = QPushButton("Refresh")
        self.refresh_button.setToolTip("Ask the controller for its material library again")
        self.refresh_button.clicked.connect(self.refresh)
        self.calibrate = QPushButton("Calibrate…")
        self.calibrate.setToolTip("Calibrate a material: a speed ladder cut, and what its edges showed recorded")
        self.calibrate.clicked.connect(self.open_calibration)
        self.reply = QLabel("")
        self.reply.setWordWrap(True)
        self._lay_out()
        self._listing.connect(self._on_listing, Qt.ConnectionType.QueuedConnection)
        self._reply.connect(self._on_reply, Qt.ConnectionType.QueuedConnection)
        enable = enable_while_commanding(adapter, [self.material, self.thickness, self.quality, self.mode, self.apply,
                                                   self.programs_own], extra=self._job_may_change)
        adapter.status.connect(enable)
        adapter.status.connect(self._show_in_force)
        adapter.program.connect(self._program_changed)
        self._show_chart()
        self._show_in_force()

    def _lay_out(self) -> None:
        form = QFormLayout()
        form.addRow("In force", self.in_force)
        form.addRow("Material", self.material)
        form.addRow("Thickness", self.thickness)
        form.addRow("Quality", self.quality)
        form.addRow("Mode", self.mode)
        buttons = QHBoxLayout()
        for b in (self.apply, self.programs_own, self.refresh_button, self.calibrate):
            buttons.addWidget(b)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addWidget(self.reply)
        layout.addStretch(1)

    def _job_may_change(self) -> bool:
        """The controller takes a job for a loaded program, and not while the automatic cycle runs."""
        st = self.model.status
        return (st is not None and st.program is not None and bool(st.program.name)
                and st.cycle_phase == CyclePhase.NONE.name)

    # -- asking the controller ----------------------------------------------------------------
    def refresh(self) -> None:
        """Ask for the material library again (answered on the GUI thread)."""
        self.queries.ask(self.source.materials, self._listing)

    def close_worker(self) -> None:
        """Wait for a query under way and take no more: the window is closing (the calibration with it)."""
        self.queries.close()
        if self.calibration is not None:
            self.calibration.close()

    def open_calibration(self) -> None:
        """Show the guided calibration with this library; a calibration recorded asks for the library
        again, so that the material can be chosen at once."""
        if self.calibration is None:
            self.calibration = CalibrationDialog(self.adapter, self.commands, self)
            self.calibration.recorded.connect(lambda _reply: self.refresh())
            self.listed.connect(self.calibration.show_materials)
            if self.listing is not None:
                self.calibration.show_materials(self.listing)
        self.calibration.present()

    def showEvent(self, event: QShowEvent) -> None:  # noqa: N802 - Qt's override
        """Shown: the library is asked for again (a material calibrated meanwhile appears)."""
        super().showEvent(event)
        self.refresh()

    def _program_changed(self) -> None:
        """Another program loaded: the list is asked for again while the operator looks at it
        (otherwise when the panel is shown next)."""
        if self.isVisible():
            self.refresh()

    # -- commands -----------------------------------------------------------------------------
    def chosen(self) -> SetCut | None:
        """The job the controls say (None while no calibrated material is chosen)."""
        entry = self.entries.get(self.material.currentData() or "")
        if entry is None or not entry.thicknesses_mm:
            return None
        return SetCut(entry.id, self.thickness.value(), self.quality.currentData(), self.mode.currentData())

    def apply_job(self) -> None:
        """Send the job chosen; without a calibrated material, say so and send nothing."""
        job = self.chosen()
        if job is None:
            self._show_reply(False, "choose a calibrated material first")
            return
        self._send(job)

    def program_job(self) -> None:
        """Back to the program's own job (its comment, or its programmed F)."""
        self._send(SetCut(""))

    def _send(self, job: SetCut) -> None:
        future = self.commands.send(job)
        future.add_done_callback(lambda f: self._reply.emit(f.result()))

    def _on_reply(self, reply: Reply) -> None:
        self._show_reply(reply.ok, reply.reason)
        self.answered.emit(reply)

    def _show_reply(self, ok: bool, text: str) -> None:
        show_reply(self.reply, ok, text)

    # -- showing ------------------------------------------------------------------------------
    def _show_in_force(self) -> None:
        st = self.model.status
        cut = st.program.cut if st is not None and st.program is not None else ""
        self.in_force.setText(cut or PROGRAMMED_FEED)

    def _on_listing(self, answer: object) -> None:
        if isinstance(answer, Exception):
            self._show_reply(False, f"The controller did not answer: {answer}")
            return
        self._show_list(answer)

    def _show_list(self, listing: MaterialList) -> None:
        """Fill the material list, keeping the choice; a material without a chart is listed greyed."""
        keep = self.material.currentData()
        self.listing = listing
        self.entries = {e.id: e for e in listing.entries}
        self.material.blockSignals(True)
        self.material.clear()
        items: QStandardItemModel = self.material.model()
        for e in listing.entries:
            self.material.addItem(e.name if e.thicknesses_mm else f"{e.name} (not calibrated)", e.id)
            item = items.item(self.material.count() - 1)
            item.setToolTip(f"{e.id}: {e.kind} jet; {e.source}")
            item.setEnabled(bool(e.thicknesses_mm))
        calibrated = [e.id for e in listing.entries if e.thicknesses_mm]
        pick = keep if keep in calibrated else (calibrated[0] if calibrated else None)
        self.material.setCurrentIndex(self.material.findData(pick) if pick is not None else -1)
        self.material.blockSignals(False)
        if listing.error:
            self._show_reply(False, listing.error)
        elif not listing.entries:
            self._show_reply(False, f"no materials in {listing.directory}")
        self._show_chart()
        self.listed.emit(listing)

    def _show_chart(self) -> None:
        """The thickness limited to the chosen material's chart, then the speeds at it."""
        entry = self.entries.get(self.material.currentData() or "")
        rows = entry.thicknesses_mm if entry is not None else []
        self.thickness.blockSignals(True)
        if rows:
            self.thickness.setRange(rows[0], rows[-1])
            self.thickness.setToolTip(f"{rows[0]:g} to {rows[-1]:g} mm: the material's chart "
                                      "(nothing is extrapolated: calibrate another thickness)")
        else:
            self.thickness.setRange(0.0, 0.0)
            self.thickness.setToolTip("choose a calibrated material")
        self.thickness.blockSignals(False)
        self._show_speeds()

    def _show_speeds(self) -> None:
        """Each quality's straight speed at the thickness chosen (the number alone without a chart)."""
        entry = self.entries.get(self.material.currentData() or "")
        speeds = quality_speeds(entry, self.thickness.value()) if entry is not None and entry.thicknesses_mm else None
        for i, q in enumerate(QUALITIES):
            self.quality.setItemText(i, f"{q}: {speeds[i]:.0f} mm/min" if speeds else str(q))

