"""Program loading and the program text: a file dialog, the upload to the controller (checked and
interpreted there), errors shown with line and column and the faulty line highlighted, and the
block being cut highlighted while the program runs."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QColor, QTextCursor, QTextFormat
from PySide6.QtWidgets import (
    QFileDialog, QHBoxLayout, QLabel, QPlainTextEdit, QPushButton, QTextEdit, QVBoxLayout, QWidget,
)

from cnc.bus.messages import Reply, UploadProgram

from .adapter import ModelAdapter
from .commands import CommandRunner, enable_while_commanding
from .style import duration

PROGRAM_FILTER = "G-code (*.ngc *.nc *.tap *.gcode *.txt);;All files (*)"
ERROR_BG, CURRENT_BG = QColor("#ffb3b3"), QColor("#fff0a0")


class ProgramError(ValueError):
    """A program file the HMI cannot send (unreadable, not UTF-8 text); the text says where."""


def read_program(path: str | Path) -> str:
    """The file's text; ProgramError names the file and, for bytes that are not UTF-8, the line and column."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ProgramError(f"{p}: cannot read: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ProgramError(f"{p}:{line}:{column}: not UTF-8 text (byte 0x{data[exc.start]:02x}): a binary file?") from None


class ProgramPanel(QWidget):
    """The loaded program's name, size and planned time, its text, and a Load button.

    A failed upload keeps the file's text on screen with the error's line highlighted and the
    cursor at its column; a successful one shows the controller's copy once it arrives."""

    uploaded = Signal(object)  # the Reply of the last upload
    _after_upload = Signal(object)  # (name, text, Reply), from the command thread

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.commands = adapter.model, commands
        self.info = QLabel("No program loaded")
        self.load_button = QPushButton("Load program…")
        self.load_button.clicked.connect(self.choose_file)
        self.error = QLabel()
        self.error.setStyleSheet("color: #b00020; font-weight: bold;")
        self.error.setWordWrap(True)
        self.error.hide()
        self.text = QPlainTextEdit()
        self.text.setReadOnly(True)
        self.text.setLineWrapMode(QPlainTextEdit.LineWrapMode.NoWrap)
        self.text.setStyleSheet("font-family: monospace;")
        head = QHBoxLayout()
        head.addWidget(self.info, 1)
        head.addWidget(self.load_button)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addLayout(head)
        layout.addWidget(self.error)
        layout.addWidget(self.text, 1)
        self._shown_hash: str | None = None
        self._current_line = 0
        self.error_line = 0  # the line highlighted as wrong (0 none)
        self._after_upload.connect(self._on_uploaded, Qt.ConnectionType.QueuedConnection)
        adapter.program.connect(self._show_loaded)
        adapter.status.connect(self._follow)
        adapter.status.connect(self._retime)
        self._timed: tuple = ()  # (hash, planned_s) the info line shows
        enable_while_commanding(adapter, [self.load_button])
        self._show_loaded()

    # -- loading ------------------------------------------------------------------------------

    def choose_file(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Load a G-code program", "", PROGRAM_FILTER)
        if path:
            self.load_file(path)

    def load_file(self, path: str | Path) -> None:
        """Read the file and send it; a file that cannot be read is reported here and not sent."""
        try:
            text = read_program(path)
        except ProgramError as exc:
            self.info.setText(f"{Path(path).name} was not sent" + self._kept())
            self._show_error(str(exc), "", 0, 0)
            return
        name = Path(path).name
        self.info.setText(f"Sending {name} ({len(text.encode())} bytes)…")
        future = self.commands.send(UploadProgram(name, text), f"load {name}")
        future.add_done_callback(lambda f, n=name, t=text: self._after_upload.emit((n, t, f.result())))

    def _on_uploaded(self, result: tuple[str, str, Reply]) -> None:
        name, text, reply = result
        if reply.ok:
            self.error.hide()
            self.error_line = 0
            self.info.setText(f"{name}: {reply.reason or 'loaded'}; waiting for the controller's copy…")
            self._shown_hash = None
        else:
            diag = reply.errors[0] if reply.errors else None
            self.info.setText(f"{name} was not loaded" + self._kept())
            self._show_error(reply.reason, text, diag.line if diag else 0, diag.column if diag else 0)
        self.uploaded.emit(reply)

    def _show_error(self, reason: str, text: str, line: int, column: int) -> None:
        """Show why the program was refused; with its text, highlight the line and put the cursor at the column."""
        self.error.setText(reason)
        self.error.show()
        self.error_line = line
        self._shown_hash = None
        if text:
            self.text.setPlainText(text)
        if line > 0:
            block = self.text.document().findBlockByNumber(line - 1)
            cursor = QTextCursor(block)
            cursor.movePosition(QTextCursor.MoveOperation.Right, n=max(0, min(column - 1, block.length() - 1)))
            self.text.setTextCursor(cursor)
            self.text.centerCursor()
            self._highlight(line, ERROR_BG)

    # -- the controller's program ---------------------------------------------------------------

    def _show_loaded(self) -> None:
        prog = self.model.program
        if prog is None or not prog.name:
            return
        self.info.setText(f"{prog.name}: {prog.text.count(chr(10)) if prog.text else '?'} lines, "
                          f"{prog.segments} motions" + self._planned() + self._cut())
        if prog.hash == self._shown_hash or self.error_line:
            return
        self._shown_hash = prog.hash
        self.text.setPlainText(prog.text or f"({prog.name} was loaded from a file on the controller: no text to show)")
        self._current_line = 0

    def _retime(self) -> None:
        """The cycle time is planned again (after the load, or with another cutting job): the info
        line follows the status's, not the figure of the moment the program was loaded."""
        st = self.model.status
        p = st.program if st is not None else None
        if p is None or not p.name or self.error_line:
            return
        timed = (p.hash, p.planned_s, p.cut)
        if timed != self._timed:
            self._timed = timed
            self._show_loaded()

    def _kept(self) -> str:
        """What the controller still has loaded after a refusal."""
        prog = self.model.program
        return f"; the controller keeps {prog.name}" if prog is not None and prog.name else ""

    def _cut(self) -> str:
        st = self.model.status
        p = st.program if st is not None else None
        return f"; cutting job: {p.cut}" if p is not None and p.cut else ""

    def _planned(self) -> str:
        st = self.model.status
        p = st.program if st is not None else None
        if p is None or not p.name:
            return ""
        if p.planned_s < 0:
            return ", cycle time being planned"
        return f", planned cycle time {duration(p.planned_s)}" if p.planned_s > 0 else ""

    def _follow(self) -> None:
        """Highlight the block being cut (the status's line), scrolling it into view."""
        st = self.model.status
        p = st.program if st is not None else None
        if p is None or self.error_line or p.hash != self._shown_hash:
            return
        line = p.line if p.segment >= 0 else 0
        if line == self._current_line:
            return
        self._current_line = line
        if line > 0:
            self.text.setTextCursor(QTextCursor(self.text.document().findBlockByNumber(line - 1)))
            self.text.centerCursor()
            self._highlight(line, CURRENT_BG)
        else:
            self.text.setExtraSelections([])

    def _highlight(self, line: int, colour: QColor) -> None:
        selection = QTextEdit.ExtraSelection()
        selection.format.setBackground(colour)
        selection.format.setProperty(QTextFormat.Property.FullWidthSelection, True)
        selection.cursor = QTextCursor(self.text.document().findBlockByNumber(line - 1))
        self.text.setExtraSelections([selection])

    def highlighted_line(self) -> int:
        """The line highlighted (1-based; 0 none)."""
        selections = self.text.extraSelections()
        return selections[0].cursor.blockNumber() + 1 if selections else 0
