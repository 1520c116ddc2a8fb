"""The servo engineer's window: control parameters, log variables and watch on the left, the scope on
the right, so that gains are changed while the following error is watched (QMotor's main idea)."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QLabel, QSplitter, QTabWidget, QVBoxLayout, QWidget

from cnc.bus.messages import ControlLaw

from .adapter import ModelAdapter, TuningAdapter
from .commands import CommandRunner
from .connection import Connection
from .control_panel import ControlPanel
from .log_panel import LogPanel
from .params_panel import ParamsPanel
from .scope import ScopePanel, WatchPanel


class EngineeringWindow(QWidget):
    """Tabs Parameters, Log and Watch beside the scope; a separate window of the operator screen."""

    def __init__(self, adapter: ModelAdapter, tuning: TuningAdapter, commands: CommandRunner, connection: Connection,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle(f"Tuning and logging: station {adapter.model.station}")
        if parent is not None:
            self.setWindowFlag(Qt.WindowType.Window)
        self.params = ParamsPanel(adapter, tuning, commands, connection)
        self.log = LogPanel(tuning, commands, connection)
        self.watch = WatchPanel(tuning)
        self.scope = ScopePanel(tuning, connection)
        self.control = ControlPanel(adapter, commands, connection)
        self.log.plot_run.connect(self.scope.show_run)
        self.tabs = QTabWidget()
        self.tabs.addTab(self.params, "Control parameters")
        self.tabs.addTab(self.log, "Log variables")
        self.tabs.addTab(self.watch, "Watch")
        self.tabs.addTab(self.control, "Control program")
        split = QSplitter(Qt.Orientation.Horizontal)
        split.addWidget(self.tabs)
        split.addWidget(self.scope)
        split.setSizes([760, 840])
        self.law = QLabel()  # the control program and its CPU time per period, live (QMotor 2.0's control benchmark)
        self.law.setObjectName("tuning.control_law")
        self.law.setWordWrap(True)
        layout = QVBoxLayout(self)
        layout.addWidget(self.law, 0)
        layout.addWidget(split, 1)
        self.resize(1600, 900)
        self.model = adapter.model
        adapter.status.connect(self._show_law)
        self._show_law()

    def _show_law(self) -> None:
        status = self.model.status
        text = law_text(status.control) if status is not None and status.control is not None else ""
        if self.law.text() != text:
            self.law.setText(text)


def law_text(law: ControlLaw) -> str:
    """The control program and what it costs, in one line for the engineer."""
    if law.p50_us < 0:
        cost = f"not running (budget {law.budget_us:.0f} µs per period)"
    else:
        cost = (f"CPU per period p50 {law.p50_us:.0f} µs, p99 {law.p99_us:.0f} µs, max {law.max_us:.0f} µs "
                f"of a {law.budget_us:.0f} µs budget (last second)")
    text = f"Control program {law.program}: {cost}"
    if law.failures:
        text += f"; stopped {law.failures} time{'s' if law.failures != 1 else ''}, last: {law.failure}"
    return text
