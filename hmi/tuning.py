"""The servo engineer's window: control parameters, log variables and watch on the left, the scope on
the right, so that gains are changed while the following error is watched (QMotor's main idea)."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QSplitter, QTabWidget, QVBoxLayout, QWidget

from .adapter import ModelAdapter, TuningAdapter
from .commands import CommandRunner
from .connection import Connection
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
        self.log.plot_run.connect(self.scope.show_run)
        self.tabs = QTabWidget()
        self.tabs.addTab(self.params, "Control parameters")
        self.tabs.addTab(self.log, "Log variables")
        self.tabs.addTab(self.watch, "Watch")
        split = QSplitter(Qt.Orientation.Horizontal)
        split.addWidget(self.tabs)
        split.addWidget(self.scope)
        split.setSizes([760, 840])
        layout = QVBoxLayout(self)
        layout.addWidget(split)
        self.resize(1600, 900)
