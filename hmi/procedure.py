"""The procedure window: a guided procedure's steps with their state, the instruction for the
manual action awaited, and the operator's buttons (confirm the step, "procedure stopped",
"end the procedure"). It is the page the screen shows while a procedure runs."""

from __future__ import annotations

from PySide6.QtGui import QColor, QFont
from PySide6.QtWidgets import (
    QHBoxLayout, QLabel, QListWidget, QListWidgetItem, QPushButton, QVBoxLayout, QWidget,
)

from cnc.bus.messages import ProcedureConfirm, ProcedureEnd, ProcedureState, ProcedureStop

from .adapter import ModelAdapter
from .commands import CommandRunner
from .style import BAD, OFF, OK, WARN

STEP_MARKS = {"pending": ("○", OFF), "awaited": ("▶", WARN), "done": ("✔", OK), "timed_out": ("✖", BAD)}
STATE_TEXT = {"running": "running", "done": "all steps done", "stopped": "PROCEDURE STOPPED",
              "timed_out": "a step timed out", "idle": "no procedure"}


class ProcedureWindow(QWidget):
    """Shows `model.procedure`; buttons send the procedure commands while this station commands."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.commands = adapter.model, commands
        self.title = QLabel()
        self.title.setObjectName("page_title")
        self.state = QLabel()
        self.steps = QListWidget()
        self.instruction = QLabel()
        self.instruction.setObjectName("instruction")
        self.instruction.setWordWrap(True)
        self.confirm = QPushButton("Step done: confirm")
        self.stop = QPushButton("Procedure stopped")
        self.stop.setToolTip("Abandon the procedure (the automatic cycle that asked for it stops)")
        self.end = QPushButton("End the procedure")
        self.end.setToolTip("Close the procedure once it is done or stopped")
        self.confirm.clicked.connect(lambda: self.commands.send(ProcedureConfirm()))
        self.stop.clicked.connect(lambda: self.commands.send(ProcedureStop()))
        self.end.clicked.connect(lambda: self.commands.send(ProcedureEnd()))
        head = QHBoxLayout()
        head.addWidget(self.title, 1)
        head.addWidget(self.state)
        buttons = QHBoxLayout()
        buttons.addWidget(self.confirm)
        buttons.addStretch(1)
        buttons.addWidget(self.stop)
        buttons.addWidget(self.end)
        layout = QVBoxLayout(self)
        layout.addLayout(head)
        layout.addWidget(self.steps, 1)
        layout.addWidget(self.instruction)
        layout.addLayout(buttons)
        for signal in (adapter.procedure, adapter.lock, adapter.connection):
            signal.connect(self.refresh)
        self.refresh()

    def refresh(self) -> None:
        p = self.model.procedure
        if p is None or not p.id:
            self.title.setText("No procedure runs")
            self.state.setText("")
            self.steps.clear()
            self.instruction.setText("")
        else:
            self.title.setText(p.title)
            self.state.setText(STATE_TEXT.get(p.state, p.state))
            self._fill_steps(p)
            self.instruction.setText(p.instruction or STATE_TEXT.get(p.state, ""))
        commanding = self.model.holds_lock and self.model.reachable and p is not None and bool(p.id)
        awaited = p.steps[p.step] if p is not None and 0 <= p.step < len(p.steps) else None
        running = p is not None and p.state == "running"
        self.confirm.setEnabled(commanding and awaited is not None and awaited.action == "confirm")
        self.stop.setEnabled(commanding and running)
        self.end.setEnabled(commanding and not running)

    def _fill_steps(self, p: ProcedureState) -> None:
        self.steps.clear()
        for k, step in enumerate(p.steps):
            mark, colour = STEP_MARKS.get(step.state, ("?", OFF))
            item = QListWidgetItem(f"{mark}  {k + 1}. {step.text}" + (f"  ({step.state.replace('_', ' ')})"
                                                                     if step.state != "pending" else ""))
            item.setForeground(QColor(colour))
            if k == p.step:
                font = QFont(item.font())
                font.setBold(True)
                item.setFont(font)
            self.steps.addItem(item)

    def step_lines(self) -> list[str]:
        """The listed steps as the operator reads them."""
        return [self.steps.item(i).text() for i in range(self.steps.count())]
