"""The control program in the tuning window (QMotor's): which law the servo runs, the machine's
choices with their parameters and log variables, the selection for the next start, and timed
runs of the control alone (hold, or a test trajectory, for a duration), as QMotor's start and
stop with a control duration. The list is asked for on a worker thread: the screen never waits.
"""

from __future__ import annotations

from typing import Protocol

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QComboBox, QDoubleSpinBox, QGroupBox, QHBoxLayout, QLabel, QListWidget, QPushButton, QVBoxLayout, QWidget,
)

from cnc.bus.messages import ControlProgramInfo, ControlProgramList, ControlRun, ControlSelect, Reply, Stop

from .adapter import ModelAdapter
from .commands import BackgroundQuery, CommandRunner, enable_while_commanding
from .style import show_reply

TRAJECTORIES = (("hold position", "hold"), ("position step", "step"), ("ramp", "ramp"), ("circle", "circle"),
                ("the paper's Fig. 10 contour", "fig10"))
DEFAULT_DURATION_S = 5.0


class ControlSource(Protocol):
    """What answers the control-program query (`hmi.connection.Connection` fits); a blocking call."""

    def control_programs(self) -> ControlProgramList: ...


def program_text(info: ControlProgramInfo) -> str:
    """One program, as the engineer reads it: what it is, its parameters and its log variables."""
    if info.error:
        return f"{info.name}: cannot be built: {info.error}"
    lines = [f"{info.name} ({info.class_name}): {info.description}"]
    for p in info.parameters:
        values = ", ".join(f"{v:g}" for v in p.values)
        lines.append(f"  {p.name} = {values} {p.unit}".rstrip() + f"  ({p.lo:g} to {p.hi:g}{', per axis' if p.per_axis else ''})"
                     + (f": {p.doc}" if p.doc else ""))
    if info.log_variables:
        lines.append("  logs " + ", ".join(info.log_variables))
    return "\n".join(lines)


class ControlPanel(QWidget):
    """The programs, the selection, the timed control runs."""

    listed = Signal(object)  # the ControlProgramList shown
    answered = Signal(object)  # the Reply to the last command sent from here
    _listing = Signal(object)
    _reply = Signal(object)

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, source: ControlSource,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.commands, self.source = adapter.model, commands, source
        self.queries = BackgroundQuery("hmi-control")
        self.listing: ControlProgramList | None = None
        self.state = QLabel("")
        self.state.setWordWrap(True)
        self.state.setStyleSheet("font-weight: bold;")
        self.programs = QListWidget()
        self.programs.currentRowChanged.connect(lambda _row: self._show_details())
        self.details = QLabel("")
        self.details.setWordWrap(True)
        self.details.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.select = QPushButton("Select for the next start")
        self.select.setToolTip("Check it on the simulated plant, then name it in the machine file: the controller runs "
                               "it from its next start (engineer, command lock, nothing running)")
        self.select.clicked.connect(self.select_program)
        self.refresh_button = QPushButton("Refresh")
        self.refresh_button.clicked.connect(self.refresh)
        self.trajectory = QComboBox()
        for text, kind in TRAJECTORIES:
            self.trajectory.addItem(text, kind)
        self.duration = QDoubleSpinBox()
        self.duration.setRange(0.1, 3600.0)
        self.duration.setDecimals(1)
        self.duration.setValue(DEFAULT_DURATION_S)
        self.duration.setSuffix(" s")
        self.start_run = QPushButton("Start control run")
        self.start_run.setToolTip("In MANUAL, homed: hold position or follow the trajectory from where the head stands "
                                  "for this long, the jet closed (start a log run beside it to record it)")
        self.start_run.clicked.connect(self.run_control)
        self.stop_run = QPushButton("Stop")
        self.stop_run.clicked.connect(lambda: self._send(Stop()))
        self.reply = QLabel("")
        self.reply.setWordWrap(True)
        self._lay_out()
        self._listing.connect(self._on_listing, Qt.ConnectionType.QueuedConnection)
        self._reply.connect(self._on_reply, Qt.ConnectionType.QueuedConnection)
        enable_while_commanding(adapter, [self.select, self.start_run, self.stop_run])

    def _lay_out(self) -> None:
        choose = QGroupBox("Control programs")
        box = QVBoxLayout(choose)
        box.addWidget(self.state)
        box.addWidget(self.programs, 1)
        box.addWidget(self.details)
        row = QHBoxLayout()
        row.addWidget(self.select)
        row.addWidget(self.refresh_button)
        row.addStretch(1)
        box.addLayout(row)
        run = QGroupBox("Control run")
        line = QHBoxLayout(run)
        line.addWidget(self.trajectory, 1)
        line.addWidget(self.duration)
        line.addWidget(self.start_run)
        line.addWidget(self.stop_run)
        layout = QVBoxLayout(self)
        layout.addWidget(choose, 1)
        layout.addWidget(run)
        layout.addWidget(self.reply)

    # -- asking ---------------------------------------------------------------------------------
    def refresh(self) -> None:
        """Ask for the programs again (answered on the GUI thread)."""
        self.queries.ask(self.source.control_programs, self._listing)

    def close_worker(self) -> None:
        self.queries.close()

    def select_program(self) -> None:
        item = self.programs.currentItem()
        if item is None:
            self._show_reply(False, "choose a program first")
            return
        future = self._send(ControlSelect(item.data(Qt.ItemDataRole.UserRole)))
        future.add_done_callback(lambda _f: self.refresh())

    def run_control(self) -> None:
        self._send(ControlRun(self.trajectory.currentData(), float(self.duration.value())))

    def _send(self, msg):  # noqa: ANN001, ANN202
        future = self.commands.send(msg)
        future.add_done_callback(lambda f: self._reply.emit(f.result()))
        return future

    # -- showing --------------------------------------------------------------------------------
    def _on_listing(self, answer: object) -> None:
        if isinstance(answer, Exception):
            self._show_reply(False, f"The controller did not answer: {answer}")
            return
        listing: ControlProgramList = answer
        self.listing = listing
        keep = self.programs.currentItem().data(Qt.ItemDataRole.UserRole) if self.programs.currentItem() else None
        self.programs.blockSignals(True)
        self.programs.clear()
        for info in listing.programs:
            marks = [m for m, on in (("running", info.name == listing.running),
                                     ("selected for the next start", info.name == listing.selected)) if on]
            text = info.name + (f"  ({', '.join(marks)})" if marks else "") + ("  - cannot be built" if info.error else "")
            self.programs.addItem(text)
            self.programs.item(self.programs.count() - 1).setData(Qt.ItemDataRole.UserRole, info.name)
        names = [info.name for info in listing.programs]
        self.programs.setCurrentRow(names.index(keep) if keep in names else names.index(listing.running))
        self.programs.blockSignals(False)
        self.state.setText(f"Running: {listing.running}" + (f"; from the next start: {listing.selected}"
                                                              if listing.selected != listing.running else ""))
        self._show_details()
        self.listed.emit(listing)

    def _show_details(self) -> None:
        row = self.programs.currentRow()
        if self.listing is None or not 0 <= row < len(self.listing.programs):
            self.details.setText("")
            return
        self.details.setText(program_text(self.listing.programs[row]))

    def _on_reply(self, reply: Reply) -> None:
        self._show_reply(reply.ok, reply.reason)
        self.answered.emit(reply)

    def _show_reply(self, ok: bool, text: str) -> None:
        show_reply(self.reply, ok, text)

    def showEvent(self, event) -> None:  # noqa: ANN001, N802 - Qt's override
        super().showEvent(event)
        self.refresh()
