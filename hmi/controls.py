"""The operator's controls: the command bar every page shares (lock, mode, reset, stop, feed
override, history), the manual page (jog by buttons and keyboard, home, drives, pump, jet test,
go to, guided procedures) and the automatic page (program, cycle start, feed hold, resume, stop).

Every control sends a typed command through the `CommandRunner` and works only while this
station holds the command lock on a reachable controller; otherwise the controls are shown
greyed (read-only). The controller has the last word: a refusal comes back with its reason.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from PySide6.QtCore import QEvent, QObject, Qt, QTimer, Signal
from PySide6.QtGui import QKeyEvent
from PySide6.QtWidgets import (
    QButtonGroup, QComboBox, QDoubleSpinBox, QFormLayout, QGridLayout, QGroupBox, QHBoxLayout, QLabel, QPushButton,
    QSlider, QSpinBox, QTabWidget, QVBoxLayout, QWidget,
)

from cnc.bus.messages import (
    CycleStart, Drives, GoTo, InterruptedCut, Hold, Home, JetTest, Jog, JogRefresh, JogStop, LockRequest, Override, ProcedureStart, Pump,
    Recover, Reset, Resume, SetMode, Stop, StopAll,
)
from cnc.bus.states import Mode

from .adapter import ModelAdapter
from .commands import CommandRunner, enable_while_commanding
from .cutjob import CutJobPanel, MaterialSource
from .library import LibraryPanel, ProgramSource
from .mdi import MdiPanel
from .program import ProgramPanel

JOG_STEPS_MM = (None, 0.01, 0.1, 1.0, 10.0, 100.0)  # None: continuous while held
JOG_KEYS = {Qt.Key.Key_Left: ("x", -1), Qt.Key.Key_Right: ("x", 1), Qt.Key.Key_Down: ("y", -1), Qt.Key.Key_Up: ("y", 1)}
STOP_ALL_KEY = "Ctrl+Shift+Space"  # the stop-all control from the keyboard, on every page
OVERRIDE_SEND_DELAY_MS = 120  # the slider sends its value after this pause (not a command per pixel)
JOG_REFRESH_MS = 100  # a held jog key is refreshed this often: the controller stops a jog not refreshed in 250 ms


def _button(text: str, tip: str = "", checkable: bool = False) -> QPushButton:
    b = QPushButton(text)
    b.setToolTip(tip)
    b.setCheckable(checkable)
    return b


class CommandBar(QWidget):
    """Lock, mode, reset, stop, feed override and the history window: on every page."""

    history_requested = Signal()
    tuning_requested = Signal()

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.commands = adapter.model, commands
        self.lock_button = _button("Take command lock", "Become the station that commands the machine")
        self.lock_button.clicked.connect(self._toggle_lock)
        self.lock_label = QLabel()
        self.manual = _button("MANUAL", "Manual mode: jog, home, pump and jet by hand", checkable=True)
        self.auto = _button("AUTO", "Automatic mode: the automatic cycle", checkable=True)
        modes = QButtonGroup(self)
        modes.setExclusive(True)
        modes.addButton(self.manual)
        modes.addButton(self.auto)
        self.manual.clicked.connect(lambda: self.commands.send(SetMode(Mode.MANUAL.name)))
        self.auto.clicked.connect(lambda: self.commands.send(SetMode(Mode.AUTO.name)))
        self.reset = _button("Reset", "Reset the faults whose cause has gone and switch the drives on")
        self.reset.clicked.connect(lambda: self.commands.send(Reset()))
        self.stop = _button("STOP", "Stop the motion and the cycle (Esc)")
        self.stop.setStyleSheet("QPushButton { background: #c62828; color: white; font-weight: bold; }"
                                "QPushButton:disabled { background: #d9a0a0; }")
        self.stop.clicked.connect(lambda: self.commands.send(Stop()))
        # any station may stop everything, lock or not; a software stop, named so that nobody takes
        # it for the emergency stop (the hardwired e-stop circuit is that)
        self.stop_all = _button("Stop all (software)", "Close the jet, stop the axes on their braking distance and "
                                f"switch the drives off, from this station, lock or not ({STOP_ALL_KEY}). "
                                "Reset to go on. Not the emergency stop: that is the machine's hardwired e-stop button")
        self.stop_all.setStyleSheet("QPushButton { background: #ffd600; color: black; font-weight: bold; "
                                    "border: 3px solid black; padding: 4px 10px; }")
        self.stop_all.clicked.connect(lambda: self.commands.send(StopAll()))
        self.override = QSlider(Qt.Orientation.Horizontal)
        self.override.setRange(0, 200)
        self.override.setValue(100)
        self.override.setPageStep(10)
        self.override.setMinimumWidth(160)
        self.override_label = QLabel("100 %")
        self._override_timer = QTimer(self)
        self._override_timer.setSingleShot(True)
        self._override_timer.setInterval(OVERRIDE_SEND_DELAY_MS)
        self._override_timer.timeout.connect(self._send_override)
        self.override.valueChanged.connect(self._override_moved)
        self.history = _button("Message history…")
        self.history.clicked.connect(self.history_requested)
        self.tuning = _button("Tuning and logging…", "Control parameters, log variables, watch and scope")
        self.tuning.clicked.connect(self.tuning_requested)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        for w in (self.lock_button, self.lock_label):
            layout.addWidget(w)
        layout.addSpacing(16)
        for w in (self.manual, self.auto, self.reset, self.stop, self.stop_all):
            layout.addWidget(w)
        layout.addSpacing(16)
        layout.addWidget(QLabel("Feed override"))
        layout.addWidget(self.override)
        layout.addWidget(self.override_label)
        layout.addStretch(1)
        layout.addWidget(self.tuning)
        layout.addWidget(self.history)
        enable_while_commanding(adapter, [self.manual, self.auto, self.reset, self.stop, self.override])
        for signal in (adapter.lock, adapter.connection):
            signal.connect(self._show_lock)
        adapter.status.connect(self._show_status)
        self._show_lock()
        self._show_status()

    def _toggle_lock(self) -> None:
        self.commands.send(LockRequest(take=not self.model.holds_lock))

    def _show_lock(self) -> None:
        m = self.model
        self.lock_button.setEnabled(m.reachable)
        self.lock_button.setText("Release command lock" if m.holds_lock else "Take command lock")
        holder = m.lock_holder
        text = ("this station commands" if m.holds_lock else
                f"read-only: {holder} commands" if holder else "read-only: no station commands")
        self.lock_label.setText(f"Station {m.station}: {text}")

    def _show_status(self) -> None:
        st = self.model.status
        if st is None:
            return
        self.manual.setChecked(st.mode == Mode.MANUAL.name)
        self.auto.setChecked(st.mode == Mode.AUTO.name)
        if not self.override.isSliderDown() and not self._override_timer.isActive():
            self.override.blockSignals(True)
            self.override.setValue(int(round(st.feed_override * 100)))
            self.override.blockSignals(False)
            self.override_label.setText(f"{self.override.value()} %")

    def _override_moved(self, value: int) -> None:
        self.override_label.setText(f"{value} %")
        self._override_timer.start()

    def _send_override(self) -> None:
        self.commands.send(Override(float(self.override.value())))


class JogPad(QGroupBox):
    """Jog buttons (held: continuous; or a step per click) and the arrow keys (`key_event`). While a
    continuous jog is held the pad refreshes it every JOG_REFRESH_MS: the controller's dead-man stops
    a jog whose station stops refreshing it (this screen crashed, or lost its network)."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__("Jog (arrow keys)", parent)
        self.model, self.commands = adapter.model, commands
        self.step = QComboBox()
        for mm in JOG_STEPS_MM:
            self.step.addItem("continuous" if mm is None else f"{mm:g} mm", mm)
        self.speed = QSpinBox()
        self.speed.setRange(60, 60000)
        self.speed.setSingleStep(600)
        self.speed.setValue(3000)
        self.speed.setSuffix(" mm/min")
        grid = QGridLayout()
        self.buttons: dict[tuple[str, int], QPushButton] = {}
        for (axis, sign), (row, col) in {("y", 1): (0, 1), ("x", -1): (1, 0), ("x", 1): (1, 2), ("y", -1): (2, 1)}.items():
            b = _button(f"{axis.upper()}{'+' if sign > 0 else '−'}")
            b.setAutoRepeat(False)
            b.pressed.connect(lambda a=axis, s=sign: self.start(a, s))
            b.released.connect(lambda a=axis, s=sign: self.release(a, s))
            grid.addWidget(b, row, col)
            self.buttons[(axis, sign)] = b
        grid.setRowStretch(3, 1)
        form = QFormLayout()
        form.addRow("Step", self.step)
        form.addRow("Speed", self.speed)
        layout = QHBoxLayout(self)
        layout.addLayout(grid)
        layout.addLayout(form)
        layout.addStretch(1)
        self._jogging: tuple[str, int] | None = None
        self._refresh = QTimer(self)
        self._refresh.setInterval(JOG_REFRESH_MS)
        self._refresh.timeout.connect(lambda: self.commands.send(JogRefresh()))
        enable_while_commanding(adapter, [*self.buttons.values()])

    def start(self, axis: str, sign: int) -> None:
        """Begin a jog of `axis` in direction `sign`: continuous until `release`, or one step."""
        if not (self.model.holds_lock and self.model.reachable):
            return
        speed = self.speed.value() / 60.0
        step = self.step.currentData()
        if step is None:
            self._jogging = (axis, sign)
            self.commands.send(Jog(axis, velocity_mm_s=sign * speed))
            self._refresh.start()
        else:
            self.commands.send(Jog(axis, velocity_mm_s=speed, distance_mm=sign * step))

    def release(self, axis: str, sign: int) -> None:
        """End a continuous jog (a step ends by itself)."""
        if self._jogging == (axis, sign):
            self._jogging = None
            self._refresh.stop()
            self.commands.send(JogStop())

    def stop_all(self) -> None:
        """The window lost the keyboard or the page changed: a held jog must not run on."""
        if self._jogging is not None:
            self._jogging = None
            self._refresh.stop()
            self.commands.send(JogStop())

    def key_event(self, event: QKeyEvent) -> bool:
        """Arrow keys jog (press starts, release ends); True when the key was a jog key."""
        target = JOG_KEYS.get(Qt.Key(event.key()))
        if target is None:
            return False
        if not event.isAutoRepeat():
            if event.type() == QEvent.Type.KeyPress:
                self.start(*target)
            else:
                self.release(*target)
        return True


class ManualPage(QWidget):
    """MANUAL mode: jog, home, drives, pump, jet test, go to a position, MDI, start a guided procedure."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, vertical: bool = False,
                 parent: QWidget | None = None) -> None:
        """`vertical`: the machine buttons above the jog pad (a narrow place, beside a procedure)."""
        super().__init__(parent)
        self.model, self.commands = adapter.model, commands
        self.jog = JogPad(adapter, commands)
        send = self.commands.send
        self.home_all = _button("Home all axes")
        self.home_all.clicked.connect(lambda: send(Home()))
        self.home_x = _button("Home X")
        self.home_x.clicked.connect(lambda: send(Home(["x"])))
        self.home_y = _button("Home Y")
        self.home_y.clicked.connect(lambda: send(Home(["y"])))
        self.drives_on = _button("Drives on")
        self.drives_on.clicked.connect(lambda: send(Drives(True)))
        self.drives_off = _button("Drives off")
        self.drives_off.clicked.connect(lambda: send(Drives(False)))
        self.pump_on = _button("Pump on")
        self.pump_on.clicked.connect(lambda: send(Pump(True)))
        self.pump_off = _button("Pump off")
        self.pump_off.clicked.connect(lambda: send(Pump(False)))
        self.jet_on = _button("Jet test on", "Open the jet at standstill (pump at pressure)")
        self.jet_on.clicked.connect(lambda: send(JetTest(True)))
        self.jet_off = _button("Jet test off")
        self.jet_off.clicked.connect(lambda: send(JetTest(False)))
        self.goto_x, self.goto_y = self._coordinate(), self._coordinate()
        self.goto = _button("Go to")
        self.goto.clicked.connect(lambda: send(GoTo({"x": self.goto_x.value(), "y": self.goto_y.value()})))
        self.procedures = QComboBox()
        self.procedure_start = _button("Start procedure")
        self.procedure_start.clicked.connect(self._start_procedure)

        machine = QGroupBox("Machine")
        grid = QGridLayout(machine)
        for k, w in enumerate((self.home_all, self.home_x, self.home_y, self.drives_on, self.drives_off,
                               self.pump_on, self.pump_off, self.jet_on, self.jet_off)):
            grid.addWidget(w, k // 3, k % 3)
        move = QGroupBox("Go to position (mm)")
        row = QHBoxLayout(move)
        for label, w in (("X", self.goto_x), ("Y", self.goto_y)):
            row.addWidget(QLabel(label))
            row.addWidget(w)
        row.addWidget(self.goto)
        guided = QGroupBox("Guided procedures")
        g = QHBoxLayout(guided)
        g.addWidget(self.procedures, 1)
        g.addWidget(self.procedure_start)
        self.mdi: MdiPanel | None = None  # not in a narrow place beside a procedure
        if vertical:
            layout = QVBoxLayout(self)
            for w in (machine, self.jog, move, guided):
                layout.addWidget(w)
        else:
            right = QVBoxLayout()
            self.mdi = MdiPanel(adapter, commands)
            for w in (machine, move, self.mdi, guided):
                right.addWidget(w)
            right.addStretch(1)
            layout = QHBoxLayout(self)
            layout.addWidget(self.jog)
            layout.addLayout(right, 1)
        adapter.catalogue.connect(self._fill_procedures)
        self._fill_procedures()
        enable_while_commanding(adapter, [
            self.home_all, self.home_x, self.home_y, self.drives_on, self.drives_off, self.pump_on, self.pump_off,
            self.jet_on, self.jet_off, self.goto, self.procedure_start,
        ])

    @staticmethod
    def _coordinate() -> QDoubleSpinBox:
        box = QDoubleSpinBox()
        box.setRange(-100000.0, 100000.0)
        box.setDecimals(3)
        box.setSuffix(" mm")
        return box

    def _fill_procedures(self) -> None:
        self.procedures.clear()
        for p in self.model.catalogue:
            self.procedures.addItem(f"{p.title} ({len(p.steps)} steps)", p.id)

    def _start_procedure(self) -> None:
        procedure = self.procedures.currentData()
        if procedure:
            self.commands.send(ProcedureStart(procedure))


class ControllerQueries(ProgramSource, MaterialSource, Protocol):
    """What the automatic page asks the controller besides commands: its program and material
    libraries (`hmi.connection.Connection` fits)."""


class AutoPage(QWidget):
    """AUTO mode: the program (load, text, block being cut), the program library and the cutting job
    when the screen can ask for them, and the cycle's buttons (with continuing a cut, starting at a
    part or a line). The cutting job stands beside the cycle's buttons: the operator sees what the
    program will be cut with before cycle start."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, library: ControllerQueries | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.model, self.commands = adapter.model, commands
        self.program = ProgramPanel(adapter, commands)
        self.library = LibraryPanel(adapter, commands, library) if library is not None else None
        self.cut_job = CutJobPanel(adapter, commands, library) if library is not None else None
        self.tabs = QTabWidget()
        self.tabs.addTab(self.program, "Loaded program")
        if self.library is not None:
            self.tabs.addTab(self.library, "Program library")
            self.tabs.currentChanged.connect(lambda i: self.library.refresh() if self.tabs.widget(i) is self.library else None)
        self.cycles = QSpinBox()
        self.cycles.setRange(0, 9999)
        self.cycles.setValue(1)
        self.cycles.setSpecialValueText("until stopped")
        self.cycle_start = _button("Cycle start")
        self.cycle_start.setStyleSheet("QPushButton { background: #2e7d32; color: white; font-weight: bold; }"
                                       "QPushButton:disabled { background: #9fc5a1; }")
        self.cycle_start.clicked.connect(lambda: self.commands.send(CycleStart(self.cycles.value())))
        self.hold = _button("Feed hold")
        self.hold.clicked.connect(lambda: self.commands.send(Hold()))
        self.resume = _button("Resume")
        self.resume.clicked.connect(lambda: self.commands.send(Resume()))
        self.stop = _button("Stop cycle")
        self.stop.clicked.connect(lambda: self.commands.send(Stop()))
        # starting inside the program, the material in place: after a fault, a stop or a restart
        self.continue_cut = _button("Continue cut", "Continue the interrupted cut from where the jet stopped, a little "
                                    "back along it (the machine file's overlap); no transport: the material is in place")
        self.continue_cut.clicked.connect(lambda: self.commands.send(Recover("continue")))
        self.interrupted = QLabel()  # where "continue" takes up the cut, or that none is known
        self.interrupted.setObjectName("auto.interrupted")
        self.interrupted.setWordWrap(True)
        self.part = QSpinBox()
        self.part.setRange(1, 1_000_000)
        self.part.setPrefix("part ")
        self.start_part = _button("Start at", "Start the cycle at this part (its pierce), the material in place")
        self.start_part.clicked.connect(lambda: self.commands.send(Recover("part", self.part.value())))
        self.line = QSpinBox()
        self.line.setRange(1, 100_000_000)
        self.line.setPrefix("line ")
        self.start_line = _button("Run from", "Start the cycle at this program line, the material in place")
        self.start_line.clicked.connect(lambda: self.commands.send(Recover("line", self.line.value())))
        cycle = QGroupBox("Automatic cycle")
        buttons = QVBoxLayout(cycle)
        row = QHBoxLayout()
        row.addWidget(QLabel("Cycles"))
        row.addWidget(self.cycles)
        buttons.addLayout(row)
        for b in (self.cycle_start, self.hold, self.resume, self.stop):
            b.setMinimumHeight(34)
            buttons.addWidget(b)
        buttons.addSpacing(12)
        buttons.addWidget(self.continue_cut)
        buttons.addWidget(self.interrupted)
        for spin, button in ((self.part, self.start_part), (self.line, self.start_line)):
            row = QHBoxLayout()
            row.addWidget(button)
            row.addWidget(spin, 1)
            buttons.addLayout(row)
        buttons.addStretch(1)
        layout = QHBoxLayout(self)
        layout.addWidget(self.tabs, 1)
        if self.cut_job is not None:
            layout.addWidget(self.cut_job)
        layout.addWidget(cycle)
        enable_while_commanding(adapter, [self.cycle_start, self.hold, self.resume, self.stop,
                                          self.start_part, self.start_line])
        self._continue_enabled = enable_while_commanding(adapter, [self.continue_cut], lambda: self._interrupted() is not None)
        adapter.status.connect(self._show_interrupted)
        self._show_interrupted()

    def _interrupted(self) -> InterruptedCut | None:
        status = self.model.status
        return status.program.interrupted if status is not None and status.program is not None else None

    def _show_interrupted(self) -> None:
        """Where "Continue cut" would take up the loaded program's cut; the button only when it can."""
        point, status = self._interrupted(), self.model.status
        if status is None or status.program is None:
            text = ""
        elif point is None:
            text = "No interrupted cut of this program is known"
        else:
            text = f"Interrupted cut: line {point.line}, at X {point.x_mm:.3f}  Y {point.y_mm:.3f}"
        if self.interrupted.text() != text:
            self.interrupted.setText(text)
            self._continue_enabled()


class KeyJog(QObject):
    """An application-wide key filter: the arrow keys jog with the pad `pad()` names (None: the
    keys are not for jogging now); the window losing focus stops a held jog on every pad."""

    def __init__(self, pad: Callable[[], JogPad | None], pads: list[JogPad], parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.pad, self.pads = pad, pads

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt's override
        kind = event.type()
        if kind in (QEvent.Type.KeyPress, QEvent.Type.KeyRelease):
            pad = self.pad()
            return pad is not None and pad.key_event(event)
        if kind == QEvent.Type.WindowDeactivate:
            for pad in self.pads:
                pad.stop_all()
        return False
