"""The status panels: everything the paper's operator screen shows about the machine, live.

Operation and execution mode, homed; feed commanded, actual and override; axis positions and
status; the program's block, name, status, progress and ETA; jet; the PLC's automatic operation;
the auxiliary devices (high-pressure pump and its pressure, mains, safety circuit); emergency
stop, network alive, the reset a fault waits for. Each panel reads the model when the adapter
says its topic changed.
"""

from __future__ import annotations

from PySide6.QtWidgets import QGridLayout, QGroupBox, QLabel, QProgressBar, QVBoxLayout, QWidget

from cnc.bus.messages import Status
from cnc.bus.states import CyclePhase, LinkState, MachineState, PlannerState, RunResult

from .adapter import ModelAdapter
from .model import PlcState, plc_link_text
from .style import BAD, OFF, OK, WARN, Lamp, duration, value_label

RUNNING_STATES = tuple(s.name for s in (MachineState.RUNNING, MachineState.HOMING, MachineState.JOGGING, MachineState.MDI))
_PLANNER_AT_REST = tuple(s.name for s in (PlannerState.IDLE, PlannerState.HELD, PlannerState.PAUSED))
PLC_COLOURS = {PlcState.STOPPED: OFF, PlcState.STARTED: WARN, PlcState.RUNNING: OK}


class _Group(QGroupBox):
    """A titled group laid out in rows of one or two caption-value pairs (the panels must fit a
    screen's height without scrolling, so two short fields share a row)."""

    def __init__(self, title: str) -> None:
        super().__init__(title)
        self.grid = QGridLayout(self)
        self.grid.setContentsMargins(6, 4, 6, 4)
        self.grid.setVerticalSpacing(2)
        self.grid.setColumnStretch(1, 1)
        self.grid.setColumnStretch(3, 1)
        self.row = 0

    def add(self, *cells: tuple[str, QWidget] | QWidget) -> None:
        """One row: each cell a (caption, widget) pair or a widget alone; a lone cell spans the row."""
        col = 0
        for cell in cells:
            span = 4 if len(cells) == 1 else 2
            if isinstance(cell, tuple):
                self.grid.addWidget(QLabel(cell[0]), self.row, col)
                self.grid.addWidget(cell[1], self.row, col + 1, 1, span - 1)
            else:
                self.grid.addWidget(cell, self.row, col, 1, span)
            col += span
        self.row += 1


class StatusPanels(QWidget):
    """The right-hand column of status groups; `values` maps a field name to its label (tests read it)."""

    def __init__(self, adapter: ModelAdapter, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.adapter, self.model = adapter, adapter.model
        self.values: dict[str, QLabel] = {}
        self.lamps: dict[str, Lamp] = {}
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        layout.addWidget(self._machine_group())
        layout.addWidget(self._axes_group())
        layout.addWidget(self._program_group())
        layout.addWidget(self._devices_group())
        layout.addWidget(self._safety_group())
        layout.addStretch(1)
        for signal in (adapter.status, adapter.alarms, adapter.connection):
            signal.connect(self.refresh)
        self.refresh()

    # -- building -----------------------------------------------------------------------------

    def _value(self, name: str, caption: str) -> tuple[str, QLabel]:
        label = self.values[name] = value_label()
        return caption, label

    def _lamp(self, name: str, caption: str) -> Lamp:
        lamp = self.lamps[name] = Lamp(caption)
        return lamp

    def _machine_group(self) -> QGroupBox:
        box = _Group("Machine and feed")
        box.add(self._value("mode", "Mode"), self._value("execution", "Execution"))
        box.add(self._value("state", "State"), self._value("phase", "Phase"))
        box.add(self._value("cycles", "Cycles"), self._lamp("homed", "Homed"))
        box.add(self._value("feed_commanded", "Feed cmd."), self._value("feed_actual", "Actual"))
        box.add(self._value("feed_override", "Override"))
        return box

    def _axes_group(self) -> QGroupBox:
        box = QGroupBox("Axes")
        self._axes_grid = QGridLayout(box)
        self._axes_grid.setContentsMargins(6, 4, 6, 4)
        self._axes_grid.setVerticalSpacing(2)
        for col, head in enumerate(("", "Position mm", "Foll. err µm", "mm/s", "Homed / drive")):
            self._axes_grid.addWidget(QLabel(f"<b>{head}</b>"), 0, col)
        self._axis_rows: dict[str, list[QLabel]] = {}
        return box

    def _program_group(self) -> QGroupBox:
        box = _Group("Program")
        box.add(self._value("program", "Name"))
        box.add(self._value("program_status", "Status"), self._value("block", "Block"))
        self.progress = QProgressBar()
        self.progress.setRange(0, 1000)
        self.progress.setFormat("%p %")
        box.add(("Progress", self.progress))
        box.add(self._value("eta", "ETA / plan"), self._lamp("jet", "Jet"))
        return box

    def _devices_group(self) -> QGroupBox:
        box = _Group("PLC and auxiliary devices")
        box.add(self._lamp("plc_link", "PLC link"), self._lamp("plc_state", "PLC auto"))
        box.add(self._lamp("pump", "HP pump"), self._value("pressure", "bar"))
        box.add(self._lamp("mains", "Mains"), self._lamp("safety_circuit", "Safety circuit"))
        return box

    def _safety_group(self) -> QGroupBox:
        box = _Group("Safety and network")
        box.add(self._lamp("estop", "Emergency stop"), self._lamp("doors", "Doors"))
        box.add(self._lamp("network", "Network alive"), self._lamp("reset", "Reset fault"))
        box.add(self._lamp("timing", "Servo timing"))
        return box

    # -- refreshing ---------------------------------------------------------------------------

    def refresh(self) -> None:
        st = self.model.status
        if st is None:
            for label in self.values.values():
                label.setText("-")
            for lamp in self.lamps.values():
                lamp.set(OFF, "unknown")
            return
        v = self.values
        v["mode"].setText(st.mode)
        running = st.machine_state in RUNNING_STATES or st.planner_state not in _PLANNER_AT_REST
        v["execution"].setText("running" if running else "stopped")
        v["state"].setText(st.machine_state)
        v["phase"].setText(st.cycle_phase)
        target = "until stopped" if st.cycles_target == 0 and st.cycle_phase != CyclePhase.NONE.name else str(st.cycles_target)
        v["cycles"].setText(f"{st.cycles_done} of {target}")
        homed = bool(st.axes) and all(a.homed for a in st.axes)
        self.lamps["homed"].set(OK if homed else WARN, "yes" if homed else
                                "no" + (f" (homing {st.homing_axis.upper()})" if st.homing_axis else ""))
        v["feed_commanded"].setText(f"{st.feed_commanded_mm_s * 60:.0f} mm/min")
        v["feed_actual"].setText(f"{st.feed_actual_mm_s * 60:.0f} mm/min")
        v["feed_override"].setText(f"{st.feed_override * 100:.0f} %")
        self._refresh_axes(st)
        self._refresh_program(st)
        self._refresh_devices(st)
        self._refresh_safety(st)

    def _refresh_axes(self, st: Status) -> None:
        for a in st.axes:
            row = self._axis_rows.get(a.name)
            if row is None:
                r = len(self._axis_rows) + 1
                row = self._axis_rows[a.name] = [QLabel(f"<b>{a.name.upper()}</b>")] + [value_label() for _ in range(4)]
                for col, label in enumerate(row):
                    self._axes_grid.addWidget(label, r, col)
            flags = [f"{'yes' if a.homed else 'no'} / {'on' if a.drive_enabled else 'off'}"]
            if not a.drive_ready:
                flags.append("DRIVE FAULT")
            if a.limit_min or a.limit_max:
                flags.append("LIMIT " + ("-" if a.limit_min else "+"))
            row[1].setText(f"{a.position_mm:10.3f}")
            row[2].setText(f"{a.following_error_mm * 1000:7.1f}")
            row[3].setText(f"{a.velocity_mm_s:7.1f}")
            row[4].setText(", ".join(flags))
            self.values[f"axis_{a.name}"] = row[1]

    def _refresh_program(self, st: Status) -> None:
        p, v = st.program, self.values
        if p is None or not p.name:
            for name in ("program", "program_status", "block", "eta"):
                v[name].setText("-")
            self.progress.setValue(0)
        else:
            v["program"].setText(f"{p.name} ({p.lines} lines)")
            status = st.planner_state if st.planner_state != PlannerState.IDLE.name else (
                p.result if p.result != RunResult.NONE.name else "loaded")
            v["program_status"].setText(status + (f": {st.error}" if st.error and p.result == RunResult.FAULT.name else ""))
            v["block"].setText(f"N{p.line}" if p.segment >= 0 else "-")
            self.progress.setValue(int(round(1000 * max(0.0, min(1.0, p.progress)))))
            eta = duration(p.eta_s) if p.segment >= 0 else "-"
            v["eta"].setText(f"{eta} / {duration(p.planned_s)}")
        self.lamps["jet"].set(OK if st.jet_on else OFF, "ON (cutting)" if st.jet_on else "off")

    def _refresh_devices(self, st: Status) -> None:
        link_ok = st.plc_link == LinkState.OK.name
        self.lamps["plc_link"].set(OK if link_ok else BAD, plc_link_text(st))
        plc = self.model.plc_state()
        self.lamps["plc_state"].set(PLC_COLOURS[plc], plc.value)
        inputs = st.plc_inputs
        if inputs.get("pump_fault"):
            self.lamps["pump"].set(BAD, "FAULT")
        else:
            running = bool(inputs.get("pump_running", st.pump_on))
            self.lamps["pump"].set(OK if running else OFF, "running" if running else "off")
        self.values["pressure"].setText(f"{st.pump_pressure_bar:.0f} of {st.pump_set_bar:.0f}")
        self._input_lamp("mains", "mains_on", "on", "off")
        self._input_lamp("safety_circuit", "safety_circuit_ok", "closed", "OPEN")

    def _input_lamp(self, lamp: str, signal: str, yes: str, no: str) -> None:
        inputs = self.model.status.plc_inputs
        if signal not in inputs:
            self.lamps[lamp].set(OFF, "unknown (PLC link)")
        else:
            self.lamps[lamp].set(OK if inputs[signal] else BAD, yes if inputs[signal] else no)

    def _refresh_safety(self, st: Status) -> None:
        self.lamps["estop"].set(OK if st.estop_ok else BAD, "released" if st.estop_ok else "PRESSED")
        self.lamps["doors"].set(OK if st.doors_closed else BAD, "closed" if st.doors_closed else "OPEN")
        reachable = self.model.reachable
        alive = reachable and st.network_alive
        holder = st.operator or "no operator station"
        self.lamps["network"].set(OK if alive else (WARN if reachable else BAD),
                                  (f"yes ({holder})" if alive else f"no ({holder})") if reachable else "NO (controller unreachable)")
        needs = self.model.needs_reset()
        self.lamps["reset"].set(BAD if needs else OK, "reset needed" if needs else "none")
        late = {a.id: a for a in self.model.active_alarms if a.id in ("tick_overruns", "tick_overrun_rate") and a.active}
        told = f"{st.overruns} ticks late since start" if st.overruns else "every tick on time"
        self.lamps["timing"].set(BAD if "tick_overrun_rate" in late else WARN if late else OK,
                                 ("LATE NOW: " if late else "") + told)
