"""What the control logic sees each scan (one snapshot of the blocks, as named signals) and the
PLC output image it writes."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ..config import MachineConfig
from ..data.dataserver import SharedArea
from ..hw.board import DigitalIn, DigitalOut
from ..interlock import StopCause
from ..data.layout import LinkState, ServoState

# the bits as plain ints: an int and'ed with an IntFlag member goes through enum's Python code,
# some microseconds each, and the logic tests these several times a scan
_DIN = {"estop_ok": int(DigitalIn.ESTOP_OK), "doors_closed": int(DigitalIn.DOORS_CLOSED), "mains_on": int(DigitalIn.MAINS_ON)}
_PLC_LINK_STALE = int(StopCause.PLC_LINK)
_JET_VALVE = int(DigitalOut.JET_VALVE)
MACHINE_SIGNALS = ("plc_link", "pump_pressure", "homed", "drives_on", "jet_on", "state", "mode", "moving")


@dataclass
class Snapshot:
    """One consistent read of every block the logic decides on."""

    hw: dict[str, Any]
    servo: dict[str, Any]
    motion: dict[str, Any]
    plc: dict[str, Any]

    @property
    def link_ok(self) -> bool:
        """The PLC's inputs can be trusted: the link is up and the tick finds them fresh (a hung
        PLC-link process leaves its last OK image behind: its input sequence stops advancing)."""
        return self.plc["state"] == LinkState.OK and not self.servo["stop_causes"] & _PLC_LINK_STALE

    @property
    def jet_on(self) -> bool:
        return bool(self.hw["digital_out"] & _JET_VALVE)


class SignalReader:
    """Reads the blocks and names what it finds: `din.<input>`, `plc.<id>`, and the machine's own
    signals (MACHINE_SIGNALS) that procedures and interlocks use."""

    def __init__(self, config: MachineConfig, area: SharedArea) -> None:
        self.config = config
        self.readers = {name: area.reader(name) for name in ("hw", "servo", "motion", "plc")}
        self.inputs = config.plc.inputs()
        self.all_homed = (1 << len(config.axis_names)) - 1
        self.has_pressure = any(v.id == "pump_pressure" for v in self.inputs)
        # each PLC input's signal name and kind, made once: `signals` runs every scan
        self._plc_signals = [(f"plc.{v.id}", v.type == "bool") for v in self.inputs]
        self._din_signals = [(f"din.{k}", bit) for k, bit in _DIN.items()]

    def known(self) -> set[str]:
        """Every signal name a condition may use."""
        return {f"din.{k}" for k in _DIN} | {f"plc.{v.id}" for v in self.inputs} | set(MACHINE_SIGNALS)

    def snapshot(self) -> Snapshot:
        r = self.readers
        return Snapshot(r["hw"].read_dict(), r["servo"].read_dict(), r["motion"].read_dict(), r["plc"].read_dict())

    def plc_value(self, snap: Snapshot, var_id: str, default: float = 0.0) -> float:
        """Engineering value of a PLC input; `default` while the link is not OK (stale values are not trusted)."""
        if not snap.link_ok:
            return default
        for k, v in enumerate(self.inputs):
            if v.id == var_id:
                return float(snap.plc["inputs"][k])
        return default

    def signals(self, snap: Snapshot, state: str, mode: str) -> dict[str, object]:
        din = snap.hw["digital_in"]
        out: dict[str, object] = {name: bool(din & bit) for name, bit in self._din_signals}
        link_ok = snap.link_ok
        if link_ok:  # a lost link leaves the PLC's signals unknown: they read false, never stale
            for (name, is_bool), value in zip(self._plc_signals, snap.plc["inputs"]):
                out[name] = bool(value) if is_bool else float(value)
        servo_state = snap.servo["state"]
        out.update(
            plc_link=link_ok,
            homed=snap.servo["homed_mask"] & self.all_homed == self.all_homed,
            drives_on=servo_state in (ServoState.HOLDING, ServoState.TRACKING),
            moving=servo_state == ServoState.TRACKING,
            jet_on=snap.jet_on,
            state=state,
            mode=mode,
        )
        if self.has_pressure and link_ok:
            out["pump_pressure"] = out["plc.pump_pressure"]
        return out


class PlcOutputs:
    """The PLC's output image, owned by the logic: values by id, published when they change."""

    def __init__(self, config: MachineConfig, area: SharedArea) -> None:
        self.vars = config.plc.outputs()
        self.index = {v.id: k for k, v in enumerate(self.vars)}
        self.values = [0.0] * len(self.vars)
        self.writer = area.writer("plc_out")
        self.writer.load_current()
        self.dirty = True

    def has(self, var_id: str) -> bool:
        return var_id in self.index

    def set(self, var_id: str, value: float) -> None:
        """Set one output (ids the machine file does not map are ignored: the PLC has no such signal)."""
        k = self.index.get(var_id)
        if k is not None and self.values[k] != float(value):
            self.values[k] = float(value)
            self.dirty = True

    def get(self, var_id: str) -> float:
        k = self.index.get(var_id)
        return self.values[k] if k is not None else 0.0

    def image_carrying_changes(self) -> int:
        """The image_seq of the output image that carries the values set so far (the next one
        published, when some are not published yet)."""
        return self.writer.get("image_seq") + (1 if self.dirty else 0)

    def publish(self) -> None:
        if not self.dirty:
            return
        outputs = list(self.writer.get("outputs"))
        outputs[: len(self.values)] = self.values
        self.writer.set("outputs", outputs)
        self.writer.set("image_seq", self.writer.get("image_seq") + 1)
        self.writer.publish()
        self.dirty = False
