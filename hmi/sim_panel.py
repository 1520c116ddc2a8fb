"""The simulated machine's inputs on the screen: what `waterjet sim` and `cmd/sim` change, by clicking.

Shown only when the controller runs the simulated board (it answers `<root>/sim`): the transport
station's button, a safety door, the e-stop, the mains, the light barriers, the pump's fault,
the PLC's serial link and the axes' friction. Each click is an operator command (`SimInput`)
like any other, so it needs the command lock, and it is in the alarm history as an info entry.
"""

from __future__ import annotations

from PySide6.QtWidgets import QDoubleSpinBox, QGridLayout, QLabel, QPushButton, QWidget

from cnc.bus.messages import SimInput, SimInputInfo

from .adapter import ModelAdapter
from .commands import CommandRunner, enable_while_commanding

CAPTIONS = {  # what the operator reads on each control
    "transport_button": "Press the transport button", "doors_open": "Safety door open", "estop": "E-stop pressed",
    "mains_off": "Mains off", "barrier_front": "Front light barrier interrupted",
    "barrier_rear": "Rear light barrier interrupted", "pump_fault": "Pump fault", "plc_link_cut": "PLC link cut",
    "friction": "Axis friction (x)",
}


class SimPanel(QWidget):
    """One control per input of the simulated machine, built from the controller's own list."""

    def __init__(self, adapter: ModelAdapter, commands: CommandRunner, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.adapter, self.commands = adapter, commands
        self.controls: dict[str, QPushButton] = {}  # buttons and switches
        self.friction = QDoubleSpinBox()
        self._grid = QGridLayout(self)
        self._grid.setContentsMargins(6, 6, 6, 6)
        self._built = False
        self._enable = enable_while_commanding(adapter, [])
        adapter.sim.connect(self.refresh)
        self.refresh()

    def _build(self, inputs: list[SimInputInfo]) -> None:
        row = 0
        self._grid.addWidget(QLabel("<b>Simulated machine</b>: changes go to the simulator, as an operator command"),
                             row, 0, 1, 2)
        widgets: list[QWidget] = []
        for info in inputs:
            row += 1
            caption = CAPTIONS.get(info.name, info.name)
            if info.kind == "value":
                self.friction.setRange(info.minimum, info.maximum)
                self.friction.setDecimals(1)
                self.friction.setToolTip(info.doc)
                apply = QPushButton("Set")
                apply.setToolTip(info.doc)
                apply.clicked.connect(lambda _=False, name=info.name: self._send(name, self.friction.value()))
                self.controls[info.name] = apply
                self._grid.addWidget(QLabel(caption), row, 0)
                self._grid.addWidget(self.friction, row, 1)
                row += 1
                self._grid.addWidget(apply, row, 1)
                widgets += [self.friction, apply]
                continue
            button = QPushButton(caption)
            button.setToolTip(info.doc)
            if info.kind == "switch":
                button.setCheckable(True)
                button.clicked.connect(lambda checked, name=info.name: self._send(name, 1.0 if checked else 0.0))
            else:
                button.clicked.connect(lambda _=False, name=info.name: self._send(name, 1.0))
            self.controls[info.name] = button
            self._grid.addWidget(button, row, 0, 1, 2)
            widgets.append(button)
        self._grid.setRowStretch(row + 1, 1)
        self._enable = enable_while_commanding(self.adapter, widgets)
        self._built = True

    def refresh(self) -> None:
        inputs = self.adapter.model.sim_inputs
        if inputs is None:
            return
        if not self._built:
            self._build(inputs.inputs)
        for info in inputs.inputs:
            control = self.controls.get(info.name)
            if info.kind == "switch" and control is not None:
                control.setChecked(bool(info.value))
            elif info.kind == "value" and not self.friction.hasFocus():
                self.friction.setValue(info.value)

    def _send(self, name: str, value: float) -> None:
        self.commands.send(SimInput(name, value))
