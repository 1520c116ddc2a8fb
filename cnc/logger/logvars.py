"""Log variables (QMotor's): what the data logger can record, and how each is read.

Two sources. The servo's trace ring gives one record per base tick, from which every tick's
position, setpoint, following error, velocity and speed command per axis, the FIFO fill, the
program segment and line, the jet and the tick latency are computed as numpy columns, and the
control program's registered log variables (`cnc.control`: `<axis>.<name>`, `control.<name>`). Signals
outside the servo (the PLC's input image: pump pressure, mains...; the feed override) are read
from their shared-memory blocks each time the logger wakes and held for the ticks of that wake:
they change at the PLC's 50 ms cycle, far slower than the logger wakes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..bus.messages import LogVariable
from ..config import MachineConfig
from ..control.loader import build as build_program
from ..data.dataserver import SharedArea
from ..data.fifo import SetpointFlag

_AXIS_VARIABLES = (
    ("position", "mm", "measured position"),
    ("setpoint", "mm", "commanded position (the setpoint the servo follows)"),
    ("following_error", "mm", "setpoint minus measured position"),
    ("velocity", "mm/s", "setpoint velocity"),
    ("speed_cmd", "V", "speed command to the drive"),
)
_TRACE_VARIABLES = (
    ("fifo_fill", "", "setpoints waiting in the FIFO"),
    ("segment", "", "program segment of the setpoint"),
    ("line", "", "program line of the setpoint"),
    ("jet", "", "the setpoint opens the jet (1) or not (0)"),
    ("tick_latency", "us", "how late the servo started the tick after its deadline (0 on the virtual clock)"),
    ("control_time", "us", "the control program's CPU time in the tick (its budget: [control] budget_share)"),
)


@dataclass(frozen=True)
class Variables:
    """The log variables of one machine, and how to compute them."""

    trace: list[LogVariable]  # computed from the servo's trace records
    block: list[LogVariable]  # sampled from shared-memory blocks at each wake

    @property
    def all(self) -> list[LogVariable]:
        return [*self.trace, *self.block]

    @property
    def names(self) -> list[str]:
        return [v.name for v in self.all]

    @property
    def units(self) -> dict[str, str]:
        return {v.name: v.unit for v in self.all}


def log_variables(config: MachineConfig) -> Variables:
    """Every variable the logger of this machine can record, named `<axis>.<quantity>` for axes."""
    trace = [LogVariable(f"{axis}.{name}", unit, f"{axis.upper()}: {text}")
             for axis in config.axis_names for name, unit, text in _AXIS_VARIABLES]
    trace += [LogVariable(name, unit, text) for name, unit, text in _TRACE_VARIABLES]
    trace += list(_control_variables(config))  # the control program's, in its trace record's order
    block = [LogVariable("feed_override", "", "feed override ratio in force (1 = 100 %)")]
    block += [LogVariable(f"plc.{v.id}", v.unit, v.description or f"PLC input {v.id}") for v in config.plc.inputs()]
    if any(v.id == "pump_pressure" for v in config.plc.inputs()):
        pressure = next(v for v in config.plc.inputs() if v.id == "pump_pressure")
        block.append(LogVariable("pump_pressure", pressure.unit, "high-pressure pump output pressure"))
    return Variables(trace, block)


def trace_columns(records: np.ndarray, config: MachineConfig) -> dict[str, np.ndarray]:
    """Every trace variable for these trace records, one float64 column each."""
    cols: dict[str, np.ndarray] = {}
    for i, axis in enumerate(config.axis_names):
        commanded, actual = records["commanded"][:, i], records["actual"][:, i]
        cols[f"{axis}.position"] = actual.astype(np.float64)
        cols[f"{axis}.setpoint"] = commanded.astype(np.float64)
        cols[f"{axis}.following_error"] = commanded - actual
        cols[f"{axis}.velocity"] = records["velocity"][:, i].astype(np.float64)
        cols[f"{axis}.speed_cmd"] = records["speed_cmd"][:, i].astype(np.float64)
    cols["fifo_fill"] = records["fifo_fill"].astype(np.float64)
    cols["segment"] = records["segment"].astype(np.float64)
    cols["line"] = records["line"].astype(np.float64)
    cols["jet"] = ((records["flags"] & int(SetpointFlag.JET_ON)) != 0).astype(np.float64)
    cols["tick_latency"] = records["latency_ns"] / 1000.0
    cols["control_time"] = records["control_ns"] / 1000.0
    if "control" in records.dtype.names:
        for k, variable in enumerate(_control_variables(config)):
            cols[variable.name] = records["control"][:, k].astype(np.float64)
    return cols


_CONTROL_VARIABLES: dict[tuple, tuple[LogVariable, ...]] = {}


def _control_variables(config: MachineConfig) -> tuple[LogVariable, ...]:
    """The control program's log variables, flattened as the servo's trace record carries them;
    made once per program and axes (the logger asks at every wake)."""
    key = (config.source, config.control.program, config.axis_names)
    known = _CONTROL_VARIABLES.get(key)
    if known is None:
        known = []
        for spec in build_program(config).log_variables:
            for k, name in enumerate(spec.names(config.axis_names)):
                whose = config.axis_names[k].upper() if spec.per_axis else f"control program [{k}]" if spec.size > 1 else ""
                known.append(LogVariable(name, spec.unit, f"{whose}: {spec.doc}" if whose else spec.doc or spec.name))
        known = _CONTROL_VARIABLES[key] = tuple(known)
    return known


class BlockSampler:
    """Reads the block variables' current values (one consistent read per block)."""

    def __init__(self, config: MachineConfig, area: SharedArea) -> None:
        self.plc, self.motion = area.reader("plc"), area.reader("motion")
        self.plc_ids = [v.id for v in config.plc.inputs()]
        self._plc_inputs = self.plc.layout.index["inputs"]
        self._override = self.motion.layout.index["override"]
        self._pressure = self.plc_ids.index("pump_pressure") if "pump_pressure" in self.plc_ids else -1

    def sample(self) -> dict[str, float]:
        values: dict[str, float] = {"feed_override": float(self.motion.read()[0][self._override])}
        inputs = self.plc.read()[0][self._plc_inputs]
        for k, name in enumerate(self.plc_ids):
            values[f"plc.{name}"] = float(inputs[k])
        if self._pressure >= 0:
            values["pump_pressure"] = float(inputs[self._pressure])
        return values

