"""The operator screen's main window: the window structure driven by the machine state.

The contour field sits in the centre and the status panels, the messages and the alarms on the
right on every page; below the contour, the page for the current screen (`model.Screen`): offline, manual, automatic, a running
procedure, or a fault. Changing mode, entering a procedure or a fault swaps that page, as the
paper's "window structure driven by machine state". A banner across the top says when the
controller is unreachable (commands disabled, reconnecting by itself), when the screen is
read-only, and when a message could not be read.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QAbstractSpinBox, QApplication, QHBoxLayout, QLabel, QLineEdit, QMainWindow, QPlainTextEdit, QScrollArea, QSplitter,
    QStackedWidget, QTabWidget, QVBoxLayout, QWidget,
)

from cnc.bus.messages import Reply
from cnc.bus.states import MachineState, Mode

from .adapter import ModelAdapter
from .alarms import ActiveAlarms, FaultsList, HistoryWindow, MessageArea, Search
from .commands import JOG_HELD, CommandRunner
from .contour import ContourView
from .controls import STOP_ALL_KEY, AutoPage, CommandBar, ControllerQueries, JogPad, KeyJog, ManualPage
from .sim_panel import SimPanel
from .model import Screen
from .panels import StatusPanels
from .procedure import ProcedureWindow
from .style import SHEET

BANNER_REFRESH_MS = 1000  # the banner is re-read this often (the offline reason and time move on)
BANNER_STYLES = {
    "offline": "background: #b71c1c; color: white;",
    "error": "background: #f2a900; color: #1a1a1a;",
    "read_only": "background: #37474f; color: white;",
}


class OfflinePage(QWidget):
    """Shown while no controller is heard from."""

    def __init__(self, where: str, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.label = QLabel(f"Waiting for the controller at {where}…\nThe screen reconnects by itself and catches up "
                            "on every alarm and message it missed.")
        self.label.setObjectName("page_title")
        self.label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.label.setWordWrap(True)
        layout = QVBoxLayout(self)
        layout.addWidget(self.label)


class FaultPage(QWidget):
    """FAULT or ESTOP: the active alarms and what is wrong now come first, with acknowledge and reset."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        title = QLabel("FAULT: remove the cause, then Reset")
        title.setObjectName("page_title")
        title.setStyleSheet("color: #b71c1c;")
        self.alarms = ActiveAlarms(adapter, commands)
        self.faults = FaultsList(adapter)
        self.faults.setMaximumHeight(110)
        layout = QVBoxLayout(self)
        layout.addWidget(title)
        layout.addWidget(QLabel("<b>Faults present</b>"))
        layout.addWidget(self.faults)
        layout.addWidget(QLabel("<b>Active alarms</b>"))
        layout.addWidget(self.alarms, 1)


class ProcedurePage(QWidget):
    """A procedure runs: its window, and beside it in MANUAL mode the manual controls its steps may
    ask for (home, pump on, jet test); in AUTO the steps are actions at the machine."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model = adapter.model
        self.procedure = ProcedureWindow(adapter, commands)
        self.manual = ManualPage(adapter, commands, vertical=True)
        self._manual_area = QScrollArea()  # narrower than the manual page's natural width: it scrolls
        self._manual_area.setWidget(self.manual)
        self._manual_area.setWidgetResizable(True)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.procedure, 3)
        layout.addWidget(self._manual_area, 2)
        adapter.status.connect(self._show_manual)
        self._show_manual()

    def _show_manual(self) -> None:
        st = self.model.status
        self._manual_area.setVisible(st is not None and st.mode == Mode.MANUAL.name)


class MainWindow(QMainWindow):
    """The whole operator screen for one controller (`where` names its endpoint for the banner)."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, where: str = "the controller",
                 open_error: Callable[[], str] | None = None, search_history: Search | None = None,
                 engineering: Callable[[QWidget], QWidget] | None = None, library: ControllerQueries | None = None,
                 parent: QWidget | None = None) -> None:
        """`open_error()` says why the controller cannot be reached ("" when unknown);
        `search_history` searches the controller's whole history (the history window's button);
        `library` answers the program library's queries (its tab is left out without it);
        `engineering(parent)` builds the tuning and logging window (its button is hidden without it)."""
        super().__init__(parent)
        self.adapter, self.model, self.commands, self.where = adapter, adapter.model, commands, where
        self._open_error = open_error or (lambda: "")
        self.setWindowTitle(f"Waterjet CNC: station {self.model.station}")
        self.setStyleSheet(SHEET)
        self.banner = QLabel()
        self.banner.setObjectName("banner")
        self.banner.setWordWrap(True)
        self.bar = CommandBar(adapter, commands)
        self.contour = ContourView()
        self.panels = StatusPanels(adapter)
        scroll = QScrollArea()
        scroll.setWidget(self.panels)
        scroll.setWidgetResizable(True)
        scroll.setMinimumWidth(440)
        self.pages: dict[Screen, QWidget] = {
            Screen.OFFLINE: OfflinePage(where), Screen.MANUAL: ManualPage(adapter, commands),
            Screen.AUTO: AutoPage(adapter, commands, library), Screen.PROCEDURE: ProcedurePage(adapter, commands),
            Screen.FAULT: FaultPage(adapter, commands),
        }
        self.stack = QStackedWidget()
        for page in self.pages.values():
            self.stack.addWidget(page)
        self.messages = MessageArea(adapter)
        self.alarms = ActiveAlarms(adapter, commands)
        self.faults = FaultsList(adapter)
        self.tabs = QTabWidget()
        self.tabs.addTab(self.messages, "Messages")
        self.tabs.addTab(self.alarms, "Active alarms")
        self.tabs.addTab(self.faults, "Faults")
        self.simulator = SimPanel(adapter, commands)  # a tab only for a simulated machine
        self._sim_tab = self.tabs.addTab(self.simulator, "Simulator")
        self.tabs.setTabVisible(self._sim_tab, False)
        adapter.sim.connect(lambda: self.tabs.setTabVisible(self._sim_tab, adapter.model.sim_inputs is not None))
        self.history = HistoryWindow(adapter, search_history, parent=self)  # owned by the window, shown apart
        self.history.setWindowFlag(Qt.WindowType.Window)
        self.bar.history_requested.connect(self.show_history)
        self.engineering = engineering(self) if engineering is not None else None
        self.bar.tuning.setVisible(self.engineering is not None)
        self.bar.tuning_requested.connect(self.show_engineering)

        self._lay_out(scroll)
        self.command_line = QLabel()
        self.statusBar().addWidget(self.command_line, 1)

        self._offline_since = time.time()
        self._travel: dict[str, tuple[float, float]] = {}
        self._wire()
        self._show_screen()
        self._show_banner()
        self._show_travel()
        self._show_program()
        self.resize(1600, 1000)

    def _lay_out(self, panels: QWidget) -> None:
        """Banner and command bar on top; the contour above the page for the screen on the left;
        the status panels above the messages and alarms on the right."""
        left = QSplitter(Qt.Orientation.Vertical)  # the contour above the page for the screen
        left.addWidget(self.contour)
        left.addWidget(self.stack)
        left.setStretchFactor(0, 3)
        left.setStretchFactor(1, 2)
        left.setSizes([540, 400])
        right = QSplitter(Qt.Orientation.Vertical)  # the status panels above the messages and alarms
        right.addWidget(panels)
        right.addWidget(self.tabs)
        right.setStretchFactor(0, 2)
        right.setStretchFactor(1, 1)
        right.setSizes([510, 430])
        body = QSplitter(Qt.Orientation.Horizontal)
        body.addWidget(left)
        body.addWidget(right)
        body.setStretchFactor(0, 1)
        body.setSizes([1110, 480])
        central = QWidget()
        layout = QVBoxLayout(central)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addWidget(self.banner)
        layout.addWidget(self.bar)
        layout.addWidget(body, 1)
        self.setCentralWidget(central)

    def _wire(self) -> None:
        """Keys (arrows jog, Esc stops), the banner's clock, and the model's signals to the views."""
        self._pads = [self.pages[Screen.MANUAL].jog, self.pages[Screen.PROCEDURE].manual.jog]
        self._key_jog = KeyJog(self._active_pad, self._pads, self)
        QApplication.instance().installEventFilter(self._key_jog)
        self._stop_key = QShortcut(QKeySequence(Qt.Key.Key_Escape), self)  # STOP from the keyboard, on any page
        self._stop_key.setContext(Qt.ShortcutContext.ApplicationShortcut)
        self._stop_key.activated.connect(self.bar.stop.click)  # a disabled button ignores the click
        self._stop_all_key = QShortcut(QKeySequence(STOP_ALL_KEY), self)  # stop all: lock or not
        self._stop_all_key.setContext(Qt.ShortcutContext.ApplicationShortcut)
        self._stop_all_key.activated.connect(self.bar.stop_all.click)
        self._banner_timer = QTimer(self)
        self._banner_timer.setInterval(BANNER_REFRESH_MS)
        self._banner_timer.timeout.connect(self._show_banner)
        self._banner_timer.start()
        self.adapter.screen.connect(self._show_screen)
        self.adapter.connection.connect(self._connection_changed)
        for signal in (self.adapter.connection, self.adapter.lock, self.adapter.error):
            signal.connect(self._show_banner)
        self.adapter.program.connect(self._show_program)
        auto = self.pages[Screen.AUTO]
        if auto.library is not None:  # a preview is drawn on the contour; the loaded program again when it is left
            auto.library.previewed.connect(self._show_preview)
            auto.tabs.currentChanged.connect(lambda i: self._show_program() if auto.tabs.widget(i) is auto.program else None)
        self.adapter.position.connect(self._show_position)
        self.adapter.status.connect(self._show_travel)
        self.adapter.status.connect(self._show_progress)  # a run's end comes with the status, not a position
        self.commands.replied.connect(self._show_reply)

    # -- the page and the banner -------------------------------------------------------------

    @property
    def current_screen(self) -> Screen:
        return next(s for s, page in self.pages.items() if page is self.stack.currentWidget())

    def _active_pad(self) -> JogPad | None:
        """The jog pad the arrow keys drive now: the one on the page shown, while this window is active."""
        if not self.isActiveWindow() or isinstance(QApplication.focusWidget(), (QPlainTextEdit, QLineEdit, QAbstractSpinBox)):
            return None  # the arrow keys move the cursor in what is being typed (MDI, a number): they do not jog
        page = self.stack.currentWidget()
        if page is self.pages[Screen.MANUAL]:
            return page.jog
        if page is self.pages[Screen.PROCEDURE] and page.manual.isVisibleTo(page):
            return page.manual.jog
        return None

    def _show_screen(self) -> None:
        page = self.pages[self.model.screen]
        for pad in self._pads:
            if not page.isAncestorOf(pad):
                pad.stop_all()
        self.stack.setCurrentWidget(page)

    def _connection_changed(self) -> None:
        if not self.model.reachable:
            self._offline_since = time.time()

    def _show_banner(self) -> None:
        m = self.model
        if not m.reachable:
            why = self._open_error()
            text = (f"CONTROLLER UNREACHABLE at {self.where} since {time.strftime('%H:%M:%S', time.localtime(self._offline_since))}"
                    f"{': ' + why if why else ''}. Reconnecting automatically; commands are disabled.")
            style = "offline"
        elif m.error:
            text, style = f"Cannot read a message from the controller: {m.error}", "error"
        elif not m.holds_lock:
            who = f"station {m.lock_holder!r} holds the command lock" if m.lock_holder else "no station holds the command lock"
            text, style = f"Read-only: {who}. Take the lock to command the machine.", "read_only"
        else:
            self.banner.hide()
            return
        if text != self.banner.text():
            self.banner.setText(text)
        if self.banner.styleSheet() != BANNER_STYLES[style]:
            self.banner.setStyleSheet(BANNER_STYLES[style])
        self.banner.show()

    @property
    def banner_text(self) -> str:
        return self.banner.text() if self.banner.isVisibleTo(self) else ""

    def _show_reply(self, label: str, reply: Reply) -> None:
        if label == JOG_HELD:
            return  # ten a second while a jog key is held: the jog's own reply says what happened
        if reply.ok:
            self.command_line.setStyleSheet("color: #1b5e20;")
            self.command_line.setText(f"✔ {label}" + (f": {reply.reason}" if reply.reason else ""))
        else:
            self.command_line.setStyleSheet("color: #b71c1c; font-weight: bold;")
            self.command_line.setText(f"✖ {label} refused: {reply.reason}")

    def show_engineering(self) -> None:
        if self.engineering is not None:
            self.engineering.show()
            self.engineering.raise_()

    def show_history(self) -> None:
        self.history.show()
        self.history.raise_()

    # -- the contour field ---------------------------------------------------------------------

    def _show_program(self) -> None:
        prog = self.model.program
        if prog is not None and prog.path is not None:
            self.contour.set_path(prog.path)
            self.contour.fit()
            self._show_position()

    def _show_preview(self, info) -> None:  # noqa: ANN001 - a ProgramInfo
        """A stored program's path on the contour view, unless a program runs: the head and the cut
        follow the loaded one then (the preview's text stays in the library)."""
        st = self.model.status
        if info.path is None or (st is not None and st.machine_state in (MachineState.RUNNING.name, MachineState.HOLD.name)):
            return
        self.contour.set_path(info.path)
        self.contour.fit()

    def _show_position(self) -> None:
        pos = self.model.position
        if pos is not None and len(pos.position_mm) >= 2:
            self.contour.set_head(pos.position_mm[0], pos.position_mm[1])
        self._show_progress()

    def _show_progress(self) -> None:
        self.contour.set_progress(self.model.segment_states())

    def _show_travel(self) -> None:
        travel = self.model.travel_mm
        if travel != self._travel and "x" in travel and "y" in travel:
            self._travel = dict(travel)
            self.contour.set_travel(*travel["x"], *travel["y"])
            if self.model.program is None or self.model.program.path is None:
                self.contour.fit()

    def closeEvent(self, event) -> None:  # noqa: ANN001, N802 - Qt's override
        for pad in self._pads:
            pad.stop_all()
        QApplication.instance().removeEventFilter(self._key_jog)
        self.history.shutdown()
        auto = self.pages[Screen.AUTO]
        for panel in (auto.library, auto.cut_job):  # their queries' workers end before the widgets go
            if panel is not None:
                panel.close_worker()
        if self.engineering is not None:
            control = getattr(self.engineering, "control", None)
            if control is not None:  # its query's worker ends before the widgets go
                control.close_worker()
            self.engineering.close()
        super().closeEvent(event)
