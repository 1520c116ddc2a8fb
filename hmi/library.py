"""The program library on the automatic page: the controller's program directory as a table (name,
size, lines, cut length, planned time, last run and its result), a preview of any program without
loading it (its text here, its path on the contour view while no cycle runs), load and delete.

The controller checks each stored program in the background; a program not yet checked shows
"checking…" and the list is asked again until none is. Queries run on a worker thread: the
screen never waits for the network.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Protocol

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QColor, QTextCursor, QTextFormat
from PySide6.QtWidgets import (
    QAbstractItemView, QHBoxLayout, QHeaderView, QLabel, QMessageBox, QPlainTextEdit, QPushButton, QSplitter,
    QTableWidget, QTableWidgetItem, QTextEdit, QVBoxLayout, QWidget,
)

from cnc.bus.messages import DeleteProgram, LoadProgram, ProgramEntry, ProgramInfo, ProgramList, Reply
from cnc.bus.states import ProgramCheck

from .adapter import ModelAdapter
from .commands import CommandRunner, enable_while_commanding
from .style import duration

log = logging.getLogger(__name__)

COLUMNS = ("Program", "Size", "Lines", "Cut length", "Planned time", "Last run", "Result")
PENDING_REFRESH_MS = 2000  # the list is asked again this often while programs are being checked
ERROR_BG = QColor("#ffb3b3")


class ProgramSource(Protocol):
    """What answers the library's queries (`hmi.connection.Connection` fits); blocking calls."""

    def programs(self) -> ProgramList: ...

    def preview(self, name: str) -> ProgramInfo: ...


class LibraryPanel(QWidget):
    """The program directory's table, its buttons and the preview of the program selected."""

    listed = Signal(object)  # the ProgramList shown
    previewed = Signal(object)  # the ProgramInfo of a preview (the window draws its path)
    _answer = Signal(str, object)  # ("list" | "preview", answer or the exception), from the worker

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, source: ProgramSource,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.commands, self.source = adapter.model, commands, source
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hmi-library")
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.verticalHeader().hide()
        self.table.horizontalHeader().setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        self.table.doubleClicked.connect(lambda _index: self.preview_selected())
        self.refresh_button = QPushButton("Refresh")
        self.refresh_button.clicked.connect(self.refresh)
        self.preview_button = QPushButton("Preview")
        self.preview_button.setToolTip("Show the program's text and path without loading it")
        self.preview_button.clicked.connect(self.preview_selected)
        self.load_button = QPushButton("Load")
        self.load_button.clicked.connect(self.load_selected)
        self.delete_button = QPushButton("Delete…")
        self.delete_button.clicked.connect(self.delete_selected)
        self.info = QLabel("")
        self.info.setWordWrap(True)
        self.text = QPlainTextEdit()
        self.text.setReadOnly(True)
        self.text.setLineWrapMode(QPlainTextEdit.LineWrapMode.NoWrap)
        self.text.setStyleSheet("font-family: monospace;")
        buttons = QHBoxLayout()
        for b in (self.refresh_button, self.preview_button, self.load_button, self.delete_button):
            buttons.addWidget(b)
        buttons.addStretch(1)
        top = QWidget()
        upper = QVBoxLayout(top)
        upper.setContentsMargins(0, 0, 0, 0)
        upper.addLayout(buttons)
        upper.addWidget(self.table, 1)
        bottom = QWidget()
        lower = QVBoxLayout(bottom)
        lower.setContentsMargins(0, 0, 0, 0)
        lower.addWidget(self.info)
        lower.addWidget(self.text, 1)
        split = QSplitter(Qt.Orientation.Vertical)
        split.addWidget(top)
        split.addWidget(bottom)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(split)
        self.listing: ProgramList | None = None
        self.preview: ProgramInfo | None = None
        self.confirm: Callable[[str], bool] = self._ask_delete
        self._pending = QTimer(self)
        self._pending.setSingleShot(True)
        self._pending.setInterval(PENDING_REFRESH_MS)
        self._pending.timeout.connect(self.refresh)
        self._answer.connect(self._on_answer, Qt.ConnectionType.QueuedConnection)
        commands.replied.connect(self._after_command)
        enable_while_commanding(adapter, [self.load_button, self.delete_button])

    def close_worker(self) -> None:
        self._pending.stop()
        self._worker.shutdown(wait=True)

    # -- asking the controller ----------------------------------------------------------------
    def refresh(self) -> None:
        """Ask for the list again (answered on the GUI thread)."""
        self._ask("list", self.source.programs)

    def preview_selected(self) -> None:
        name = self.selected()
        if name:
            self.info.setText(f"Opening {name}…")
            self._ask("preview", lambda: self.source.preview(name))

    def _ask(self, what: str, query: Callable[[], object]) -> None:
        def run() -> None:
            try:
                answer = query()
            except Exception as exc:  # no answer, or an error the controller sent: shown, never raised
                answer = exc
            self._answer.emit(what, answer)
        self._worker.submit(run)

    def _on_answer(self, what: str, answer: object) -> None:
        if isinstance(answer, Exception):
            self.info.setText(f"The controller did not answer: {answer}")
            return
        if what == "list":
            self._show_list(answer)
        else:
            self._show_preview(answer)

    # -- commands -----------------------------------------------------------------------------
    def load_selected(self) -> None:
        name = self.selected()
        if name:
            self.commands.send(LoadProgram(name), f"load {name}")

    def delete_selected(self) -> None:
        name = self.selected()
        if name and self.confirm(name):
            self.commands.send(DeleteProgram(name))

    def _ask_delete(self, name: str) -> bool:
        answer = QMessageBox.question(self, "Delete program", f"Delete {name} from the controller's program directory?")
        return answer == QMessageBox.StandardButton.Yes

    def _after_command(self, label: str, reply: Reply) -> None:
        """A load, an upload or a delete changes what the list says: ask again."""
        if label.startswith(("load ", "Load program", "Delete program")):
            self.refresh()

    # -- showing ------------------------------------------------------------------------------
    def selected(self) -> str:
        rows = self.table.selectionModel().selectedRows()
        return self.table.item(rows[0].row(), 0).data(Qt.ItemDataRole.UserRole) if rows else ""

    def select(self, name: str) -> bool:
        """Select the row of `name`; False when it is not listed."""
        for row in range(self.table.rowCount()):
            if self.table.item(row, 0).data(Qt.ItemDataRole.UserRole) == name:
                self.table.selectRow(row)
                return True
        return False

    def _show_list(self, listing: ProgramList) -> None:
        keep = self.selected()
        self.listing = listing
        self.table.setRowCount(len(listing.entries))
        for row, e in enumerate(listing.entries):
            for col, text in enumerate(_cells(e)):
                item = QTableWidgetItem(text)
                if col == 0:
                    item.setData(Qt.ItemDataRole.UserRole, e.name)
                    item.setToolTip(e.error or f"{e.name}: {e.bytes} bytes")
                    if e.loaded:
                        font = item.font()
                        font.setBold(True)
                        item.setFont(font)
                if col > 0:
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                if e.summary == ProgramCheck.REFUSED:
                    item.setForeground(QColor("#b00020"))
                self.table.setItem(row, col, item)
        if keep:
            self.select(keep)
        if not self.preview:
            self.info.setText(f"{len(listing.entries)} programs in {listing.directory}")
        if any(e.summary == ProgramCheck.PENDING for e in listing.entries):
            self._pending.start()
        self.listed.emit(listing)

    def _show_preview(self, info: ProgramInfo) -> None:
        self.preview = info
        self.text.setPlainText(info.text)
        planned = f", planned cycle time {duration(info.planned_s)}" if info.planned_s >= 0 else ""
        if info.errors:
            d = info.errors[0]
            self.info.setText(f"Preview of {info.name} (not loaded): refused at line {d.line}, column {d.column}: {d.message}")
            block = self.text.document().findBlockByNumber(d.line - 1)
            cursor = QTextCursor(block)
            cursor.movePosition(QTextCursor.MoveOperation.Right, n=max(0, min(d.column - 1, block.length() - 1)))
            self.text.setTextCursor(cursor)
            self.text.centerCursor()
            selection = QTextEdit.ExtraSelection()
            selection.format.setBackground(ERROR_BG)
            selection.format.setProperty(QTextFormat.Property.FullWidthSelection, True)
            selection.cursor = QTextCursor(block)
            self.text.setExtraSelections([selection])
        else:
            self.text.setExtraSelections([])
            self.info.setText(f"Preview of {info.name} (not loaded): {info.lines} lines, {info.bytes} bytes{planned}")
        self.previewed.emit(info)


def _cells(e: ProgramEntry) -> tuple[str, ...]:
    """One row of the table: what is known of the program, '…' while it is being checked."""
    checking = e.summary == ProgramCheck.PENDING
    known = lambda value, text: "checking…" if checking else ("-" if value < 0 else text)  # noqa: E731
    name = e.name + ("  (loaded)" if e.loaded else "")
    size = f"{e.bytes / 1024:.1f} KiB" if e.bytes >= 1024 else f"{e.bytes} B"
    if e.summary == ProgramCheck.REFUSED:
        lines, cut, planned = "refused", "-", "-"
    else:
        lines = known(e.lines, f"{e.lines}")
        cut = known(e.cut_length_mm, f"{e.cut_length_mm / 1000:.2f} m")
        planned = known(e.planned_s, duration(e.planned_s))
    last = time.strftime("%Y-%m-%d %H:%M", time.localtime(e.last_run_end_ns / 1e9)) if e.last_run_end_ns else "never"
    result = {"DONE": "done", "ABORTED": "stopped", "FAULT": "fault"}.get(e.last_result, e.last_result.lower())
    return name, size, lines, cut, planned, last, result
