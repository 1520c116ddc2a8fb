"""The watch window and the scope (QMotor's plot windows): live values of chosen variables, and any
number of plot windows, each with any variables against time or one against another, auto-scaling,
zoom and pan (pyqtgraph), on the run being recorded (live) or on a finished run."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QComboBox, QHBoxLayout, QLabel, QListWidget, QListWidgetItem, QPushButton, QSplitter, QTableWidget,
    QTableWidgetItem, QVBoxLayout, QWidget,
)

from cnc.bus.logexport import columns
from cnc.bus.messages import LogRunData

from .adapter import TuningAdapter
from .connection import Connection, NoAnswer

PENS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf")
TIME = "time"
LIVE = 0  # the scope's source: the run under way


def _checkable_list(names: list[str], checked: set[str], box: QListWidget | None = None) -> QListWidget:
    """A list of `names` with a check box each (`checked` ticked); refills `box` when given."""
    box = box if box is not None else QListWidget()
    box.clear()
    for name in names:
        item = QListWidgetItem(name)
        item.setFlags(item.flags() | Qt.ItemFlag.ItemIsUserCheckable)
        item.setCheckState(Qt.CheckState.Checked if name in checked else Qt.CheckState.Unchecked)
        box.addItem(item)
    return box


def _checked(box: QListWidget) -> list[str]:
    return [box.item(i).text() for i in range(box.count()) if box.item(i).checkState() == Qt.CheckState.Checked]


def _check(box: QListWidget, names: list[str]) -> None:
    for i in range(box.count()):
        box.item(i).setCheckState(Qt.CheckState.Checked if box.item(i).text() in names else Qt.CheckState.Unchecked)


class WatchPanel(QWidget):
    """The latest value of every ticked variable, about ten times a second."""

    def __init__(self, tuning: TuningAdapter, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.tuning = tuning.model
        self.choice = QListWidget()
        self.table = QTableWidget(0, 3)
        self.table.setHorizontalHeaderLabels(("Variable", "Value", "Unit"))
        self.table.verticalHeader().hide()
        self.table.horizontalHeader().setStretchLastSection(True)
        layout = QHBoxLayout(self)
        left = QVBoxLayout()
        left.addWidget(QLabel("<b>Watch</b>: tick variables"))
        left.addWidget(self.choice)
        layout.addLayout(left, 1)
        layout.addWidget(self.table, 2)
        self._names: list[str] = []
        tuning.logstate.connect(self._fill_choice)
        tuning.live.connect(self.refresh)
        self.choice.itemChanged.connect(self.refresh)
        self._fill_choice()

    def _fill_choice(self) -> None:
        names = [v.name for v in self.tuning.variables]
        if names == self._names:
            return
        kept = set(self.watched())
        self._names = names
        self.choice.blockSignals(True)
        _checkable_list(names, kept, self.choice)
        self.choice.blockSignals(False)
        self.refresh()

    def watch(self, names: list[str]) -> None:
        _check(self.choice, names)
        self.refresh()

    def watched(self) -> list[str]:
        return _checked(self.choice)

    def refresh(self) -> None:
        latest, units = self.tuning.latest, {v.name: v.unit for v in self.tuning.variables}
        names = self.watched()
        self.table.setRowCount(len(names))
        for row, name in enumerate(names):
            value = latest.get(name)
            for col, text in enumerate((name, "-" if value is None else f"{value:.6g}", units.get(name, ""))):
                item = self.table.item(row, col)
                if item is None:
                    self.table.setItem(row, col, QTableWidgetItem(text))
                elif item.text() != text:
                    item.setText(text)

    def values(self) -> dict[str, str]:
        return {self.table.item(r, 0).text(): self.table.item(r, 1).text() for r in range(self.table.rowCount())}


class PlotWindow(QWidget):
    """One plot: ticked variables against time, or against the variable chosen for X."""

    closed = Signal(object)

    def __init__(self, names: list[str], checked: list[str], parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.plot = pg.PlotWidget(background="w")
        self.plot.showGrid(x=True, y=True, alpha=0.3)
        self.plot.addLegend(offset=(10, 10))
        self.choice = _checkable_list(names, set(checked))
        self.choice.setMaximumWidth(220)
        self.x_axis = QComboBox()
        self.x_axis.addItems([TIME, *names])
        self.fit_button = QPushButton("Fit")
        self.fit_button.clicked.connect(self.fit)
        self.close_button = QPushButton("Close")
        self.close_button.clicked.connect(lambda: self.closed.emit(self))
        side = QVBoxLayout()
        side.addWidget(self.choice)
        row = QHBoxLayout()
        row.addWidget(QLabel("X"))
        row.addWidget(self.x_axis, 1)
        side.addLayout(row)
        row = QHBoxLayout()
        row.addWidget(self.fit_button)
        row.addWidget(self.close_button)
        side.addLayout(row)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.plot, 1)
        layout.addLayout(side)
        self.curves: dict[str, pg.PlotDataItem] = {}
        self.series: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def variables(self) -> list[str]:
        return _checked(self.choice)

    def show_data(self, series: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
        """Draw the ticked variables from `series` ({name: (t, v)}), against time or the X variable."""
        self.series = series
        x_name = self.x_axis.currentText()
        wanted = [n for n in self.variables() if n in series and n != x_name]
        for name in list(self.curves):
            if name not in wanted:
                self.plot.removeItem(self.curves.pop(name))
        for k, name in enumerate(wanted):
            t, v = series[name]
            if x_name == TIME:
                x, y = t, v
            elif x_name in series and len(series[x_name][0]):
                xt, xv = series[x_name]
                x, y = np.interp(t, xt, xv), v  # the X variable at the Y variable's sample times
            else:
                x, y = np.zeros(0), np.zeros(0)
            curve = self.curves.get(name)
            if curve is None:
                curve = self.curves[name] = self.plot.plot(name=name, pen=pg.mkPen(PENS[k % len(PENS)], width=1.5))
            curve.setData(x, y)
        self.plot.setLabel("bottom", "t [s]" if x_name == TIME else x_name)

    def fit(self) -> None:
        self.plot.enableAutoRange()

    def point_counts(self) -> dict[str, int]:
        return {name: len(curve.getData()[0]) if curve.getData()[0] is not None else 0 for name, curve in self.curves.items()}


class ScopePanel(QWidget):
    """Any number of plot windows on one source: the run being recorded (live) or a finished run."""

    def __init__(self, tuning: TuningAdapter, connection: Connection, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.tuning, self.connection = tuning.model, connection
        self.source = QComboBox()
        self.source.currentIndexChanged.connect(self.redraw)
        self.add = QPushButton("Add plot window")
        self.add.clicked.connect(lambda: self.add_window())
        self.status = QLabel()
        head = QHBoxLayout()
        head.addWidget(QLabel("Source"))
        head.addWidget(self.source)
        head.addWidget(self.add)
        head.addWidget(self.status, 1)
        self.split = QSplitter(Qt.Orientation.Vertical)
        layout = QVBoxLayout(self)
        layout.addLayout(head)
        layout.addWidget(self.split, 1)
        self.windows: list[PlotWindow] = []
        self.run_data: dict[int, LogRunData] = {}
        tuning.logstate.connect(self._fill_sources)
        tuning.live.connect(self._live)
        self._fill_sources()

    def _fill_sources(self) -> None:
        runs = [r.run for r in self.tuning.runs if r.state == "done"]
        current = self.source.currentData()
        items = [("live (the run being recorded)", LIVE)] + [(f"run {n}", n) for n in reversed(runs)]
        if [self.source.itemData(i) for i in range(self.source.count())] == [d for _, d in items]:
            return
        self.source.blockSignals(True)
        self.source.clear()
        for text, data in items:
            self.source.addItem(text, data)
        self.source.setCurrentIndex(max(0, self.source.findData(current if current is not None else LIVE)))
        self.source.blockSignals(False)

    def add_window(self, variables: list[str] | None = None) -> PlotWindow:
        names = [v.name for v in self.tuning.variables]
        window = PlotWindow(names, variables or [])
        window.choice.itemChanged.connect(self.redraw)
        window.x_axis.currentIndexChanged.connect(self.redraw)
        window.closed.connect(self._close_window)
        self.windows.append(window)
        self.split.addWidget(window)
        self.redraw()
        return window

    def _close_window(self, window: PlotWindow) -> None:
        self.windows.remove(window)
        window.setParent(None)
        window.deleteLater()

    def show_run(self, run: int) -> None:
        """Plot a finished run in every window (fetched once, then kept)."""
        self._fill_sources()
        index = self.source.findData(run)
        if index >= 0:
            self.source.setCurrentIndex(index)
        self.redraw()

    def _live(self) -> None:
        if self.source.currentData() in (LIVE, None):
            self.redraw()

    def redraw(self) -> None:
        run = self.source.currentData()
        if run in (LIVE, None):
            names = {n for w in self.windows for n in (*w.variables(), w.x_axis.currentText())}
            series = {n: self.tuning.live_series(n) for n in names if n != TIME}
            live = self.tuning.live_run
            self.status.setText(f"live: run {live}" if live else "live: no run is recording (start one in Log)")
        else:
            data = self.run_data.get(run)
            if data is None:
                try:
                    data = self.run_data[run] = self.connection.log_run(run)
                except NoAnswer as exc:
                    self.status.setText(f"run {run}: {exc}")
                    return
            series = columns(data)
            self.status.setText(f"run {run}: {', '.join(series)}")
        for window in self.windows:
            window.show_data(series)
