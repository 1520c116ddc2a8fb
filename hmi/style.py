"""The operator screen's colours and small shared widgets: alarm levels, indicator lamps, value fields."""

from __future__ import annotations

import time

from PySide6.QtCore import Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import QHBoxLayout, QLabel, QWidget

# Alarm levels in distinct colours (background, text), the same everywhere on the screen.
LEVEL_COLOURS: dict[str, tuple[str, str]] = {
    "fatal": ("#7a0d2e", "#ffffff"),
    "error": ("#c62828", "#ffffff"),
    "warning": ("#f2a900", "#1a1a1a"),
    "info": ("#2f6690", "#ffffff"),
}
OK, BAD, WARN, OFF = "#2e9e44", "#d32f2f", "#f2a900", "#5c6670"

SHEET = """
QWidget { font-size: 10pt; }
QGroupBox { font-weight: bold; border: 1px solid #9aa4ae; border-radius: 4px; margin-top: 1.2em; }
QGroupBox::title { subcontrol-origin: margin; left: 6px; padding: 0 3px; }
QPushButton { padding: 4px 10px; }
QPushButton:checked { background: #2f6690; color: white; }
QLabel#value { font-family: monospace; font-size: 11pt; }
QLabel#banner { font-size: 13pt; font-weight: bold; padding: 6px; }
QLabel#instruction { font-size: 15pt; font-weight: bold; padding: 8px; background: #fff4cc; color: #1a1a1a; }
QLabel#page_title { font-size: 14pt; font-weight: bold; }
"""


def level_colour(level: str) -> tuple[QColor, QColor]:
    """(background, text) of an alarm level; unknown levels look like info."""
    bg, fg = LEVEL_COLOURS.get(level, LEVEL_COLOURS["info"])
    return QColor(bg), QColor(fg)


def clock(stamp_ns: int) -> str:
    """A wall-clock stamp as the operator reads it: date and time to the second."""
    return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(stamp_ns / 1e9))


def duration(seconds: float) -> str:
    """Seconds as m:ss (h:mm:ss past an hour); '-' when unknown (negative)."""
    if seconds < 0:
        return "-"
    s = int(round(seconds))
    h, rest = divmod(s, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60}:{rest % 60:02d}"


class Lamp(QWidget):
    """An indicator lamp with its caption: a coloured disc and a short text that says the state."""

    def __init__(self, caption: str, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._disc = QLabel()
        self._disc.setFixedSize(14, 14)
        self._caption = caption
        self._text = QLabel(caption)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(6)
        layout.addWidget(self._disc)
        layout.addWidget(self._text, 1)
        self.set(OFF, "")

    def set(self, colour: str, state: str) -> None:
        """Light the disc in `colour` and show `caption: state`."""
        self._disc.setStyleSheet(f"background: {colour}; border-radius: 7px; border: 1px solid #333;")
        self._text.setText(f"{self._caption}: {state}" if state else self._caption)
        self.state = state

    @property
    def text(self) -> str:
        return self._text.text()


def value_label(text: str = "-") -> QLabel:
    """A label for a live value (monospace, selectable so an operator can copy it)."""
    label = QLabel(text)
    label.setObjectName("value")
    label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
    return label


def show_reply(label: QLabel, ok: bool, text: str) -> None:
    """A command's reply in its panel's line: green when taken, ✖ and the reason in red when refused."""
    label.setStyleSheet("color: #1b5e20;" if ok else "color: #b00020; font-weight: bold;")
    label.setText(text if ok else f"✖ {text}")
