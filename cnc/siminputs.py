"""The simulated machine's inputs an operator may change: their names, kinds and ranges.

What `cmd/sim`, `<root>/sim`, the screen's simulator panel and `waterjet sim` offer, and the check
of a change (name, kind, range) that the gateway makes before it asks the supervisor, which owns
the simulated environment, to make it (`cnc.sim.inputs`). A real board has none of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .config import MachineConfig

BUTTON, SWITCH, VALUE = "button", "switch", "value"
FRICTION_MAX = 100.0  # times the plant's own friction: far past what the servo can hold


@dataclass(frozen=True)
class InputSpec:
    """One input: what it is, and where it goes (the board's `sim` block or the PLC simulator)."""

    name: str
    kind: str
    doc: str
    board_field: str = ""  # the `sim` block's field (switches; friction: every axis)
    plc_fault: str = ""  # the PLC simulator's fault (`plc_link.sim_model.FAULTS`)
    unit: str = ""
    maximum: float = 1.0


INPUTS = (
    InputSpec("transport_button", BUTTON, "the transport station's button, pressed once (the procedure asks for it)"),
    InputSpec("doors_open", SWITCH, "a safety door open (the controller's door input)", board_field="doors_open"),
    InputSpec("estop", SWITCH, "the e-stop button pressed (the controller's e-stop input)", board_field="estop_pressed"),
    InputSpec("mains_off", SWITCH, "the machine mains off (the controller's mains input)", board_field="mains_off"),
    InputSpec("barrier_front", SWITCH, "the front light barrier interrupted (the PLC's input)", plc_fault="barrier_front"),
    InputSpec("barrier_rear", SWITCH, "the rear light barrier interrupted (the PLC's input)", plc_fault="barrier_rear"),
    InputSpec("pump_fault", SWITCH, "the high-pressure pump reports a fault and stops (the PLC's input)",
              plc_fault="pump_fault"),
    InputSpec("plc_link_cut", SWITCH, "the PLC's serial port stops answering (a cut cable)", plc_fault="link_dead"),
    InputSpec("friction", VALUE, "the axes' friction, times the plant's own: raise it to provoke a following error",
              board_field="friction_scale", unit="x", maximum=FRICTION_MAX),
)
BY_NAME = {spec.name: spec for spec in INPUTS}


class SimInputError(ValueError):
    """A change that cannot be made, with the reason an operator reads."""


def simulated_only(config: "MachineConfig") -> None:
    """SimInputError unless the machine's board is the simulated one (a real one has no such inputs)."""
    if config.board.kind != "sim":
        raise SimInputError(f"this machine's board is {config.board.kind!r}, not the simulated one: "
                            "it has no simulator inputs")


def check(name: str, value: float) -> InputSpec:
    """The input `name` if `value` is one it takes; SimInputError says why not."""
    spec = BY_NAME.get(name)
    if spec is None:
        raise SimInputError(f"no simulated input {name!r} (inputs: {', '.join(BY_NAME)})")
    if not 0.0 <= value <= spec.maximum:
        raise SimInputError(f"{name}: {value:g} is outside 0 to {spec.maximum:g}{' ' + spec.unit if spec.unit else ''}")
    if spec.kind in (BUTTON, SWITCH) and value not in (0.0, 1.0):
        raise SimInputError(f"{name} is a {spec.kind}: 0 or 1, not {value:g}")
    return spec
