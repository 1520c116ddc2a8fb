"""Alarms on the operator screen: the active list (acknowledge, reset), the faults list, the message
area and the message-history window (time, code, level, text; filtered, searchable, kept live).

The history comes from the controller's SQLite history (the connection's catch-up reads it, the
live events extend it); every entry keeps its level's colour wherever it is shown.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from PySide6.QtCore import QAbstractTableModel, QModelIndex, QPersistentModelIndex, Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QAbstractItemView, QCheckBox, QHBoxLayout, QHeaderView, QLabel, QLineEdit, QListWidget, QListWidgetItem, QPushButton,
    QTableView, QTableWidget, QTableWidgetItem, QVBoxLayout, QWidget,
)

from cnc.bus.messages import Acknowledge, AlarmEvent, HistoryPage, Reset
from cnc.bus.states import ALARM_CODE_MAX, AlarmLevel

from .adapter import ModelAdapter
from .commands import CommandRunner, enable_while_commanding
from .style import LEVEL_COLOURS, clock, level_colour

log = logging.getLogger(__name__)

LEVELS = tuple(level.text for level in sorted(AlarmLevel, reverse=True))  # the worst first
Search = Callable[[str, list[str], "list[int] | None"], HistoryPage]  # text, levels, codes -> newest matching
MESSAGES_SHOWN = 200  # newest history entries in the message area
SEARCH_DELAY_MS = 200  # typing in the search field re-filters after this pause


class ActiveAlarms(QWidget):
    """The alarms raised and not reset, oldest first, in their level's colour; acknowledge (the
    selected alarm, or all) and reset. The buttons work only while this station holds the lock."""

    COLUMNS = ("Level", "Code", "Text", "Detail", "Raised", "Condition", "Ack.")

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.commands = adapter.model, commands
        self.table = QTableWidget(0, len(self.COLUMNS))
        self.table.setHorizontalHeaderLabels(self.COLUMNS)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.table.verticalHeader().hide()
        self.table.horizontalHeader().setSectionResizeMode(2, QHeaderView.ResizeMode.Stretch)
        self.acknowledge = QPushButton("Acknowledge")
        self.acknowledge.setToolTip("Acknowledge the selected alarm, or all when none is selected")
        self.reset = QPushButton("Reset")
        self.reset.setToolTip("Reset the alarms whose cause has gone, and switch the drives on")
        self.acknowledge.clicked.connect(self._acknowledge)
        self.reset.clicked.connect(lambda: self.commands.send(Reset()))
        buttons = QHBoxLayout()
        self.summary = QLabel()
        buttons.addWidget(self.summary, 1)
        buttons.addWidget(self.acknowledge)
        buttons.addWidget(self.reset)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.table)
        layout.addLayout(buttons)
        adapter.alarms.connect(self.refresh)
        enable_while_commanding(adapter, [self.acknowledge, self.reset])
        self.refresh()

    def refresh(self) -> None:
        alarms = self.model.active_alarms
        self.table.setRowCount(len(alarms))
        for row, a in enumerate(alarms):
            cells = (a.level.upper(), str(a.code), a.text, a.detail, clock(a.raised_ns),
                     "present" if a.active else "cleared, reset needed", "yes" if a.acknowledged else "no")
            bg, fg = level_colour(a.level)
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setBackground(bg)
                item.setForeground(fg)
                item.setData(Qt.ItemDataRole.UserRole, a.code)
                self.table.setItem(row, col, item)
        self.table.resizeColumnsToContents()
        self.table.horizontalHeader().setSectionResizeMode(2, QHeaderView.ResizeMode.Stretch)
        self.summary.setText(f"{len(alarms)} active alarm(s)" if alarms else "No active alarms")

    def rows(self) -> list[list[str]]:
        """The table as text (what the operator reads)."""
        return [[self.table.item(r, c).text() for c in range(self.table.columnCount())] for r in range(self.table.rowCount())]

    def _acknowledge(self) -> None:
        selected = self.table.selectedItems()
        code = selected[0].data(Qt.ItemDataRole.UserRole) if selected else None
        self.commands.send(Acknowledge(code))


class FaultsList(QListWidget):
    """What is wrong right now (conditions from the status and the error alarms still present)."""

    def __init__(self, adapter: ModelAdapter, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model = adapter.model
        adapter.status.connect(self.refresh)
        adapter.alarms.connect(self.refresh)
        self.refresh()

    def refresh(self) -> None:
        faults = self.model.faults()
        if faults == self.entries():
            return
        self.clear()
        bg, fg = level_colour("error")
        for text in faults:
            item = QListWidgetItem(text)
            item.setBackground(bg)
            item.setForeground(fg)
            self.addItem(item)

    def entries(self) -> list[str]:
        return [self.item(i).text() for i in range(self.count())]


class MessageArea(QListWidget):
    """The newest messages and alarm events, newest on top, each in its level's colour."""

    def __init__(self, adapter: ModelAdapter, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model = adapter.model
        self._shown = -1
        adapter.history.connect(self.refresh)
        self.refresh()

    def refresh(self) -> None:
        newest = self.model.last_seq
        if newest == self._shown:
            return
        self._shown = newest
        self.clear()
        for e in self.model.history_view()[:MESSAGES_SHOWN]:
            item = QListWidgetItem(f"{clock(e.stamp_ns)}  {e.code:5d}  {e.level.upper():<7} {e.action:<12} {e.text}"
                                   + (f": {e.detail}" if e.detail else ""))
            bg, fg = level_colour(e.level)
            item.setBackground(bg)
            item.setForeground(fg)
            item.setData(Qt.ItemDataRole.UserRole, e.seq)
            self.addItem(item)

    def entries(self) -> list[str]:
        return [self.item(i).text() for i in range(self.count())]


class HistoryTable(QAbstractTableModel):
    """The message history as a Qt table model (rows from `rows()`; newest first)."""

    COLUMNS = ("Time", "Seq", "Code", "Level", "Action", "Text", "Detail", "Source")

    def __init__(self) -> None:
        super().__init__()
        self.entries: list[AlarmEvent] = []

    def set_entries(self, entries: list[AlarmEvent]) -> None:
        self.beginResetModel()
        self.entries = entries
        self.endResetModel()

    def rowCount(self, parent: QModelIndex | QPersistentModelIndex = QModelIndex()) -> int:  # noqa: B008 - Qt's signature
        return 0 if parent.isValid() else len(self.entries)

    def columnCount(self, parent: QModelIndex | QPersistentModelIndex = QModelIndex()) -> int:  # noqa: B008
        return 0 if parent.isValid() else len(self.COLUMNS)

    def cell(self, row: int, column: int) -> str:
        e = self.entries[row]
        return (clock(e.stamp_ns), str(e.seq), str(e.code), e.level.upper(), e.action, e.text, e.detail, e.source)[column]

    def data(self, index: QModelIndex | QPersistentModelIndex, role: int = Qt.ItemDataRole.DisplayRole) -> object:
        if not index.isValid():
            return None
        if role == Qt.ItemDataRole.DisplayRole:
            return self.cell(index.row(), index.column())
        if role in (Qt.ItemDataRole.BackgroundRole, Qt.ItemDataRole.ForegroundRole):
            bg, fg = level_colour(self.entries[index.row()].level)
            return bg if role == Qt.ItemDataRole.BackgroundRole else fg
        if role == Qt.ItemDataRole.ToolTipRole:
            e = self.entries[index.row()]
            return "\n".join(x for x in (e.text, e.detail, f"cause: {e.cause}" if e.cause else "",
                                         f"remedy: {e.remedy}" if e.remedy else "") if x)
        return None

    def headerData(self, section: int, orientation: Qt.Orientation, role: int = Qt.ItemDataRole.DisplayRole) -> object:
        if orientation == Qt.Orientation.Horizontal and role == Qt.ItemDataRole.DisplayRole:
            return self.COLUMNS[section]
        return None


def parse_codes(text: str) -> list[int] | None:
    """A code filter as typed ("5, 37 2292"): the codes, or None for no filter. ValueError names the
    word that is not a code (not digits, or past the codes' range)."""
    words = text.replace(",", " ").split()
    if not words:
        return None
    codes = []
    for w in words:
        if not (w.isascii() and w.isdigit()) or not 1 <= int(w) <= ALARM_CODE_MAX:
            raise ValueError(f"code filter: {w!r} is not an alarm code (1 to {ALARM_CODE_MAX})")
        codes.append(int(w))
    return codes


class HistoryWindow(QWidget):
    """The message history: search text, level boxes and codes filter the newest entries of the
    controller's history (the screen keeps the last HISTORY_KEPT); new entries appear as they come,
    the filter applying to them too. "Search the controller" runs the same filter over the whole
    history on the controller (older entries included) through `search`."""

    _found = Signal(object)  # a HistoryPage, or the text of why the search failed (from the worker)

    def __init__(self, adapter: ModelAdapter, search: Search | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._search = search
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hmi-history-search")
        self.searched = False  # the table shows a search of the controller, not the entries held
        self.setWindowTitle("Message history")
        self.model = adapter.model
        self.search = QLineEdit()
        self.search.setPlaceholderText("search text, detail, id or code")
        self.codes = QLineEdit()
        self.codes.setPlaceholderText("codes, e.g. 5, 37")
        self.codes.setMaximumWidth(160)
        self.level_boxes = {lv: QCheckBox(lv) for lv in LEVELS}
        filters = QHBoxLayout()
        filters.addWidget(QLabel("Search"))
        filters.addWidget(self.search, 1)
        filters.addWidget(QLabel("Codes"))
        filters.addWidget(self.codes)
        for lv, box in self.level_boxes.items():
            box.setChecked(True)
            bg, fg = LEVEL_COLOURS[lv]
            box.setStyleSheet(f"QCheckBox {{ background: {bg}; color: {fg}; padding: 2px 6px; }}")
            box.toggled.connect(self._filter_changed)
            filters.addWidget(box)
        self.table_model = HistoryTable()
        self.table = QTableView()
        self.table.setModel(self.table_model)
        self.table.verticalHeader().hide()
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        header = self.table.horizontalHeader()
        header.setResizeContentsPrecision(200)  # sized from the first rows: 20k rows must not be measured
        for column in range(len(HistoryTable.COLUMNS)):
            header.setSectionResizeMode(column, QHeaderView.ResizeMode.Stretch if column in (5, 6)
                                        else QHeaderView.ResizeMode.ResizeToContents)
        self.count = QLabel()
        self.search_button = QPushButton("Search the controller's whole history")
        self.search_button.setEnabled(search is not None)
        self.search_button.clicked.connect(self.search_controller)
        foot = QHBoxLayout()
        foot.addWidget(self.count, 1)
        foot.addWidget(self.search_button)
        layout = QVBoxLayout(self)
        layout.addLayout(filters)
        layout.addWidget(self.table)
        layout.addLayout(foot)
        self._found.connect(self._show_found, Qt.ConnectionType.QueuedConnection)
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(SEARCH_DELAY_MS)
        self._timer.timeout.connect(self.refresh)
        self.search.textChanged.connect(self._filter_changed)
        self.codes.textChanged.connect(self._filter_changed)
        adapter.history.connect(self._live)
        self.resize(1000, 500)
        self.refresh()

    def _filter_changed(self) -> None:
        self.searched = False
        self._timer.start()

    def _live(self) -> None:
        if not self.searched:  # a search's answer stays until the filter changes
            self.refresh()

    def _filter(self) -> tuple[str, list[str], list[int] | None] | None:
        """(text, levels, codes) as typed; None (and the reason shown) when the codes are not codes."""
        try:
            codes = parse_codes(self.codes.text())
        except ValueError as exc:
            self.codes.setStyleSheet("background: #ffd0d0;")
            self.count.setText(str(exc))
            return None
        self.codes.setStyleSheet("")
        return self.search.text(), [lv for lv, box in self.level_boxes.items() if box.isChecked()], codes

    def search_controller(self) -> None:
        """Run the filter on the controller's whole history (off the GUI thread)."""
        query = self._filter()
        if query is None or self._search is None:
            return
        self.count.setText("Searching the controller's history…")
        self.search_button.setEnabled(False)
        self._executor.submit(self._run_search, *query)

    def _run_search(self, text: str, levels: list[str], codes: list[int] | None) -> None:
        try:
            self._found.emit(self._search(text, levels, codes))
        except Exception as exc:  # no answer, or the controller refused the query: the operator sees why
            log.info("history search failed: %s", exc)
            self._found.emit(f"the search failed: {exc}")

    def _show_found(self, found: HistoryPage | str) -> None:
        self.search_button.setEnabled(self._search is not None)
        if isinstance(found, str):
            self.count.setText(found)
            return
        self.searched = True
        self.table_model.set_entries(found.entries)
        more = " (the newest; narrow the search for older ones)" if found.more else ""
        self.count.setText(f"{len(found.entries)} entries found in the controller's whole history{more}")

    def refresh(self) -> None:
        """Re-filter the entries held now (the search field's pause timer calls this too)."""
        query = self._filter()
        if query is None:
            return
        self.searched = False
        entries = self.model.history_view(*query)
        self.table_model.set_entries(entries)
        held = self.model.last_seq
        self.count.setText(f"{len(entries)} of the entries held shown (newest {held})")

    def set_filter(self, text: str = "", levels: list[str] | None = None, codes: str = "") -> None:
        """Set the filter fields (what an operator types) and apply them at once."""
        self.search.setText(text)
        self.codes.setText(codes)
        for lv, box in self.level_boxes.items():
            box.blockSignals(True)
            box.setChecked(levels is None or lv in levels)
            box.blockSignals(False)
        self._timer.stop()
        self.refresh()

    def shutdown(self) -> None:
        """Close the window for good: a search under way is dropped."""
        self._executor.shutdown(wait=False, cancel_futures=True)
        self.close()

    def rows(self) -> list[list[str]]:
        m = self.table_model
        return [[m.cell(r, c) for c in range(len(m.COLUMNS))] for r in range(m.rowCount())]
