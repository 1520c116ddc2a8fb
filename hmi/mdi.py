"""MDI on the manual page: G-code lines typed by hand, run with a button or Ctrl+Enter.

The controller checks the lines as a program (the refusal names the line and column: the line is
highlighted and the cursor put at the column), runs them in MANUAL on a homed machine within the
travel, and opens the jet only where they ask for it and the pump allows. Entries that ran are
kept in a short list to run again, as LinuxCNC's MDI history does.
"""

from __future__ import annotations

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QColor, QKeySequence, QShortcut, QTextCursor, QTextFormat
from PySide6.QtWidgets import QComboBox, QGroupBox, QHBoxLayout, QLabel, QPlainTextEdit, QPushButton, QTextEdit, QVBoxLayout, QWidget

from cnc.bus.messages import MAX_MDI_CHARS, Mdi, Reply

from .adapter import ModelAdapter
from .commands import CommandRunner, enable_while_commanding

RUN_KEY = "Ctrl+Return"
HISTORY_KEPT = 20  # entries that ran, newest first
ERROR_BG = QColor("#ffb3b3")


class MdiPanel(QGroupBox):
    """An editor for a few lines of G-code, Run, and the entries that ran before."""

    answered = Signal(object)  # the Reply of the last entry sent
    _reply = Signal(str, object)  # (text, Reply), from the command thread

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(f"MDI: type G-code lines ({RUN_KEY.replace('Return', 'Enter')} runs them)", parent)
        self.model, self.commands = adapter.model, commands
        self.editor = QPlainTextEdit()
        self.editor.setPlaceholderText("G0 X100 Y50\nG1 X150 F1200")
        self.editor.setStyleSheet("font-family: monospace;")
        self.editor.setMaximumHeight(90)
        self.editor.setTabChangesFocus(True)
        self.run = QPushButton("Run MDI")
        self.run.setToolTip("Run the lines in MANUAL on a homed machine; the jet opens only where they ask for it "
                            f"({RUN_KEY.replace('Return', 'Enter')})")
        self.run.clicked.connect(self.send)
        self.recent = QComboBox()
        self.recent.setToolTip("Entries that ran: choose one to edit or run it again")
        self.recent.addItem("Recent entries")
        self.recent.activated.connect(self._recall)
        self.error = QLabel()
        self.error.setStyleSheet("color: #b00020; font-weight: bold;")
        self.error.setWordWrap(True)
        self.error.hide()
        row = QHBoxLayout()
        row.addWidget(self.recent, 1)
        row.addWidget(self.run)
        layout = QVBoxLayout(self)
        layout.addWidget(self.editor)
        layout.addWidget(self.error)
        layout.addLayout(row)
        self.history: list[str] = []
        shortcut = QShortcut(QKeySequence(RUN_KEY), self.editor)
        shortcut.setContext(Qt.ShortcutContext.WidgetShortcut)
        shortcut.activated.connect(self.run.click)  # a disabled button ignores the click
        self._reply.connect(self._on_reply, Qt.ConnectionType.QueuedConnection)
        enable_while_commanding(adapter, [self.run])

    def send(self) -> None:
        """Send the editor's lines (nothing when it is empty, or too long to be lines typed by hand)."""
        text = self.editor.toPlainText().strip("\n")
        if not text.strip():
            return
        if len(text) > MAX_MDI_CHARS:
            self._show_error(f"MDI takes at most {MAX_MDI_CHARS} characters: load a program for more", 0, 0)
            return
        future = self.commands.send(Mdi(text))
        future.add_done_callback(lambda f, t=text: self._reply.emit(t, f.result()))

    def _on_reply(self, text: str, reply: Reply) -> None:
        if reply.ok:
            self.error.hide()
            self.editor.setExtraSelections([])
            if text in self.history:
                self.history.remove(text)
            self.history.insert(0, text)
            del self.history[HISTORY_KEPT:]
            self.recent.clear()
            self.recent.addItem("Recent entries")
            for entry in self.history:
                self.recent.addItem(" / ".join(line.strip() for line in entry.splitlines() if line.strip()), entry)
        else:
            diag = reply.errors[0] if reply.errors else None
            self._show_error(reply.reason, diag.line if diag else _line_of(reply.reason), diag.column if diag else 0)
        self.answered.emit(reply)

    def _recall(self, index: int) -> None:
        entry = self.recent.itemData(index)
        if entry:
            self.editor.setPlainText(entry)
            self.editor.setFocus()

    def _show_error(self, reason: str, line: int, column: int) -> None:
        """Why the lines were refused; the line highlighted and the cursor at the column when known."""
        self.error.setText(reason)
        self.error.show()
        if line <= 0 or line > self.editor.document().blockCount():
            self.editor.setExtraSelections([])
            return
        block = self.editor.document().findBlockByNumber(line - 1)
        cursor = QTextCursor(block)
        cursor.movePosition(QTextCursor.MoveOperation.Right, n=max(0, min(column - 1, block.length() - 1)))
        self.editor.setTextCursor(cursor)
        selection = QTextEdit.ExtraSelection()
        selection.format.setBackground(ERROR_BG)
        selection.format.setProperty(QTextFormat.Property.FullWidthSelection, True)
        selection.cursor = QTextCursor(block)
        self.editor.setExtraSelections([selection])

    def error_position(self) -> tuple[int, int]:
        """(line, column) of the cursor, 1-based: where a refusal put it."""
        cursor = self.editor.textCursor()
        return cursor.blockNumber() + 1, cursor.positionInBlock() + 1


def _line_of(reason: str) -> int:
    """The line a refusal without a diagnostic names ("... MDI:3: ..."), 0 when none."""
    head, _, rest = reason.partition("MDI:")
    number = rest.split(":", 1)[0]
    return int(number) if rest and number.isdigit() else 0
