"""The control-parameter window (QMotor's): every parameter with its range, the value in force and
the machine file's; edit a value and press Enter to change it online; save them into the file."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (
    QAbstractItemView, QHBoxLayout, QHeaderView, QLabel, QPushButton, QTableWidget, QTableWidgetItem, QVBoxLayout,
    QWidget,
)

from cnc.bus.messages import Reply

from .adapter import ModelAdapter, TuningAdapter
from .commands import CommandRunner
from .connection import Connection

COLUMNS = ("Parameter", "Value", "Unit", "Range", "Machine file", "Changeable", "Takes effect at", "Description")
EDITED = QColor("#fff4cc")  # the value in force differs from the machine file's


class ParamsPanel(QWidget):
    """The parameter table; only the Value column is editable, and only while this station commands."""

    def __init__(self, adapter: ModelAdapter, tuning: TuningAdapter, commands: CommandRunner, connection: Connection,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.tuning, self.commands, self.connection = adapter.model, tuning.model, commands, connection
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().hide()
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.horizontalHeader().setSectionResizeMode(len(COLUMNS) - 1, QHeaderView.ResizeMode.Stretch)
        self.table.itemChanged.connect(self._edited)
        self.save = QPushButton("Save into the machine file")
        self.save.clicked.connect(lambda: self.commands.call(self.connection.save_params, "save parameters"))
        self.note = QLabel()
        self.note.setWordWrap(True)
        foot = QHBoxLayout()
        foot.addWidget(self.note, 1)
        foot.addWidget(self.save)
        layout = QVBoxLayout(self)
        layout.addWidget(self.table)
        layout.addLayout(foot)
        self._filling = False
        tuning.params.connect(self.refresh)
        for signal in (adapter.lock, adapter.connection):
            signal.connect(self._enable)
        commands.replied.connect(self._replied)
        self.refresh()

    def refresh(self) -> None:
        params = self.tuning.params
        self._filling = True
        self.table.setRowCount(len(params))
        editable = self._commanding()
        for row, p in enumerate(params):
            cells = (p.name, f"{p.value:g}", p.unit, f"{p.min:g} .. {p.max:g}", f"{p.file_value:g}",
                     "any time" if p.changeable == "always" else "no program running", p.effect, p.description)
            for col, text in enumerate(cells):
                item = self.table.item(row, col)
                if item is None:
                    item = QTableWidgetItem()
                    self.table.setItem(row, col, item)
                if item.text() != text:
                    item.setText(text)
                flags = Qt.ItemFlag.ItemIsSelectable | Qt.ItemFlag.ItemIsEnabled
                if col == 1 and editable:
                    flags |= Qt.ItemFlag.ItemIsEditable
                item.setFlags(flags)
                item.setData(Qt.ItemDataRole.UserRole, p.name)
                item.setBackground(EDITED if p.value != p.file_value else QColor(Qt.GlobalColor.white))
        self.table.resizeColumnsToContents()
        self.table.horizontalHeader().setSectionResizeMode(len(COLUMNS) - 1, QHeaderView.ResizeMode.Stretch)
        self._filling = False
        self._enable()

    def _commanding(self) -> bool:
        return self.model.holds_lock and self.model.reachable

    def _enable(self) -> None:
        self.save.setEnabled(self._commanding() and any(p.value != p.file_value for p in self.tuning.params))
        if not self._commanding():
            self.note.setText("Read-only: take the command lock to change parameters.")

    def set_value(self, name: str, text: str) -> None:
        """Change `name` to the number in `text` (what pressing Enter in its Value cell does)."""
        try:
            value = float(text.replace(",", "."))
        except ValueError:
            self._show(Reply(False, f"{name}: {text!r} is not a number"))
            self.refresh()
            return
        self.commands.call(lambda: self.connection.set_param(name, value), f"set {name}")

    def _edited(self, item: QTableWidgetItem) -> None:
        if self._filling or item.column() != 1:
            return
        self.set_value(item.data(Qt.ItemDataRole.UserRole), item.text())

    def _replied(self, label: str, reply: Reply) -> None:
        if label.startswith(("set ", "save parameters")):
            self._show(reply)
            if not reply.ok:
                self.refresh()  # the value in force, not the refused one

    def _show(self, reply: Reply) -> None:
        self.note.setStyleSheet("color: #1b5e20;" if reply.ok else "color: #b71c1c; font-weight: bold;")
        self.note.setText(("✔ " if reply.ok else "✖ ") + reply.reason)

    def value_of(self, name: str) -> str:
        for row in range(self.table.rowCount()):
            if self.table.item(row, 0).text() == name:
                return self.table.item(row, 1).text()
        raise KeyError(name)
