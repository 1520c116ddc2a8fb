"""The log-variable window (QMotor's): which variables to log and how (mode, divisor, times,
conditions), start and stop a run, the runs kept, and export of a run to MATLAB or CSV."""

from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QAbstractItemView, QCheckBox, QComboBox, QDoubleSpinBox, QFileDialog, QHBoxLayout, QHeaderView, QLabel, QLineEdit,
    QPushButton, QSpinBox, QSplitter, QTableWidget, QTableWidgetItem, QVBoxLayout, QWidget,
)

from cnc.bus.logexport import to_csv, to_mat
from cnc.bus.messages import LogSetting, LogStart, Reply

from .adapter import TuningAdapter
from .commands import CommandRunner
from .connection import Connection, NoAnswer

SETTING_COLUMNS = ("Log", "Variable", "Unit", "Mode", "Divisor", "Start s", "Duration s", "Window s", "Enable when",
                   "Disable when")
RUN_COLUMNS = ("Run", "State", "Started", "Duration s", "Samples", "Variables", "Title")
MODES = ("timed", "continuous", "triggered")


class LogPanel(QWidget):
    """Settings per variable above, the runs below; `plot_run(n)` asks the scope to show a run."""

    plot_run = Signal(int)

    def __init__(self, tuning: TuningAdapter, commands: CommandRunner, connection: Connection,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.tuning, self.commands, self.connection = tuning.model, commands, connection
        self.settings = QTableWidget(0, len(SETTING_COLUMNS))
        self.settings.setHorizontalHeaderLabels(SETTING_COLUMNS)
        self.settings.verticalHeader().hide()
        self.settings.horizontalHeader().setSectionResizeMode(8, QHeaderView.ResizeMode.Stretch)
        self.title = QLineEdit()
        self.title.setPlaceholderText("title of the run (optional)")
        self.start = QPushButton("Start logging")
        self.start.clicked.connect(self.start_run)
        self.stop = QPushButton("Stop logging")
        self.stop.clicked.connect(lambda: self.commands.call(self.connection.log_stop, "log stop"))
        self.runs = QTableWidget(0, len(RUN_COLUMNS))
        self.runs.setHorizontalHeaderLabels(RUN_COLUMNS)
        self.runs.verticalHeader().hide()
        self.runs.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.runs.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.runs.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.runs.horizontalHeader().setSectionResizeMode(5, QHeaderView.ResizeMode.Stretch)
        self.plot = QPushButton("Plot run")
        self.plot.clicked.connect(lambda: self.selected_run() and self.plot_run.emit(self.selected_run()))
        self.export_mat = QPushButton("Export to MATLAB…")
        self.export_mat.clicked.connect(lambda: self._export_dialog("mat"))
        self.export_csv = QPushButton("Export to CSV…")
        self.export_csv.clicked.connect(lambda: self._export_dialog("csv"))
        self.note = QLabel()
        self.note.setWordWrap(True)
        top = QWidget()
        top_layout = QVBoxLayout(top)
        top_layout.setContentsMargins(0, 0, 0, 0)
        top_layout.addWidget(QLabel("<b>Log variables</b>: tick the ones to record; the divisor is of the base tick"))
        top_layout.addWidget(self.settings)
        row = QHBoxLayout()
        for w in (self.title, self.start, self.stop):
            row.addWidget(w)
        top_layout.addLayout(row)
        bottom = QWidget()
        bottom_layout = QVBoxLayout(bottom)
        bottom_layout.setContentsMargins(0, 0, 0, 0)
        bottom_layout.addWidget(QLabel("<b>Runs</b>"))
        bottom_layout.addWidget(self.runs)
        row = QHBoxLayout()
        row.addWidget(self.note, 1)
        for w in (self.plot, self.export_mat, self.export_csv):
            row.addWidget(w)
        bottom_layout.addLayout(row)
        split = QSplitter(Qt.Orientation.Vertical)
        split.addWidget(top)
        split.addWidget(bottom)
        layout = QVBoxLayout(self)
        layout.addWidget(split)
        self._names: list[str] = []
        tuning.logstate.connect(self.refresh)
        commands.replied.connect(self._replied)
        self.refresh()

    # -- the settings -----------------------------------------------------------------------------

    def refresh(self) -> None:
        variables = self.tuning.variables
        if [v.name for v in variables] != self._names:
            self._fill_settings(variables)
        self._fill_runs()
        running = self.tuning.running
        self.start.setEnabled(not running and bool(variables))
        self.stop.setEnabled(bool(running))
        if running:
            self.start.setText(f"Logging (run {running})…")
        else:
            self.start.setText("Start logging")

    def _fill_settings(self, variables) -> None:  # noqa: ANN001 - list[LogVariable]
        self._names = [v.name for v in variables]
        self.settings.setRowCount(len(variables))
        for row, v in enumerate(variables):
            self.settings.setCellWidget(row, 0, QCheckBox())
            for col, text in ((1, v.name), (2, v.unit)):
                item = QTableWidgetItem(text)
                item.setFlags(Qt.ItemFlag.ItemIsEnabled)
                item.setToolTip(v.description)
                self.settings.setItem(row, col, item)
            mode = QComboBox()
            mode.addItems(MODES)
            self.settings.setCellWidget(row, 3, mode)
            divisor = QSpinBox()
            divisor.setRange(1, 100000)
            self.settings.setCellWidget(row, 4, divisor)
            for col, default in ((5, 0.0), (6, 10.0), (7, 10.0)):
                box = QDoubleSpinBox()
                box.setRange(0.0, 1e6)
                box.setDecimals(3)
                box.setValue(default)
                self.settings.setCellWidget(row, col, box)
            for col in (8, 9):
                self.settings.setCellWidget(row, col, QLineEdit())
        self.settings.resizeColumnsToContents()
        self.settings.horizontalHeader().setSectionResizeMode(8, QHeaderView.ResizeMode.Stretch)

    def choose(self, name: str, mode: str = "timed", divisor: int = 1, start_s: float = 0.0, duration_s: float = 10.0,
               window_s: float = 10.0, enable_when: str = "", disable_when: str = "") -> None:
        """Tick `name` and set its logging (what an engineer does in the table)."""
        row = self._names.index(name)
        w = self.settings.cellWidget
        w(row, 0).setChecked(True)
        w(row, 3).setCurrentText(mode)
        w(row, 4).setValue(divisor)
        for col, value in ((5, start_s), (6, duration_s), (7, window_s)):
            w(row, col).setValue(value)
        w(row, 8).setText(enable_when)
        w(row, 9).setText(disable_when)

    def chosen(self) -> list[LogSetting]:
        w = self.settings.cellWidget
        return [LogSetting(name, w(r, 3).currentText(), w(r, 4).value(), w(r, 5).value(), w(r, 6).value(),
                           w(r, 7).value(), w(r, 8).text().strip(), w(r, 9).text().strip())
                for r, name in enumerate(self._names) if w(r, 0).isChecked()]

    def start_run(self) -> None:
        chosen = self.chosen()
        if not chosen:
            self._show(Reply(False, "tick at least one variable to log"))
            return
        start = LogStart(chosen, self.title.text().strip())
        self.commands.call(lambda: self.connection.log_start(start), "log start")

    # -- the runs ---------------------------------------------------------------------------------

    def _fill_runs(self) -> None:
        runs = list(reversed(self.tuning.runs))
        selected = self.selected_run()
        self.runs.setRowCount(len(runs))
        for row, r in enumerate(runs):
            cells = (str(r.run), r.state, time.strftime("%H:%M:%S", time.localtime(r.started_ns / 1e9)),
                     f"{r.duration_s:.3f}", str(r.samples), ", ".join(r.variables), r.title)
            for col, text in enumerate(cells):
                self.runs.setItem(row, col, QTableWidgetItem(text))
            if r.run == selected:
                self.runs.selectRow(row)

    def selected_run(self) -> int:
        rows = self.runs.selectionModel().selectedRows() if self.runs.selectionModel() else []
        return int(self.runs.item(rows[0].row(), 0).text()) if rows else 0

    def select_run(self, run: int) -> None:
        for row in range(self.runs.rowCount()):
            if self.runs.item(row, 0).text() == str(run):
                self.runs.selectRow(row)

    def _export_dialog(self, fmt: str) -> None:
        run = self.selected_run()
        if not run:
            self._show(Reply(False, "select a run to export"))
            return
        kind = "MATLAB (*.mat)" if fmt == "mat" else "CSV (*.csv)"
        path, _ = QFileDialog.getSaveFileName(self, f"Export run {run}", f"run-{run}.{fmt}", kind)
        if path:
            self.export(run, Path(path), fmt)

    def export(self, run: int, path: Path, fmt: str) -> None:
        """Fetch run `run` and write it to `path` (off the GUI thread); the reply says where."""
        def work() -> Reply:
            try:
                data = self.connection.log_run(run)
            except NoAnswer as exc:
                return Reply(False, f"export run {run}: {exc}")
            written = [to_mat(data, path)] if fmt == "mat" else to_csv(data, path)
            return Reply(True, f"run {run} exported to {', '.join(str(p) for p in written)}")
        self.commands.call(work, f"export run {run}")

    def _replied(self, label: str, reply: Reply) -> None:
        if label.startswith(("log ", "export run")):
            self._show(reply)

    def _show(self, reply: Reply) -> None:
        self.note.setStyleSheet("color: #1b5e20;" if reply.ok else "color: #b71c1c; font-weight: bold;")
        self.note.setText(("✔ " if reply.ok else "✖ ") + reply.reason)
