"""The simulated machine's inputs as an operator changes them: over Zenoh, from the screen, from a shell.

The supervisor owns the simulated environment: the `sim` block the hardware server hands to the
simulated board (e-stop, doors, mains, friction) and the handle on the PLC simulator (the
transport station's button, the light barriers, the pump, the serial link). `SimulatorInputs`
names those inputs, says what each may be set to, applies a change and reads them back; the
supervisor serves it on its internal keys (`Keys.supervisor("sim")`, `"sim/set"`), which only the
gateway reaches: an operator's `cmd/sim` passes the gateway's role and lock checks first
(`cnc.gateway.door`), and `<root>/sim` reads them.
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import msgspec
import zenoh

from ..bus.messages import Reply, SimInput, SimInputInfo, SimInputs, decode, encode

if TYPE_CHECKING:
    from ..config import MachineConfig
    from ..runtime.supervisor import Supervisor

log = logging.getLogger(__name__)

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


class SimulatorInputs:
    """The supervisor's simulated inputs: `listing()` and `apply(name, value)`."""

    def __init__(self, sup: "Supervisor") -> None:
        self.sup = sup
        self.plc_values = {spec.name: 0.0 for spec in INPUTS if spec.plc_fault}  # what was set (the PLC has no read-back)

    def listing(self) -> SimInputs:
        return SimInputs([SimInputInfo(spec.name, spec.kind, self._value(spec), spec.unit, 0.0, spec.maximum, spec.doc)
                          for spec in INPUTS])

    def apply(self, name: str, value: float) -> str:
        """Make the change; returns what changed, in words ("doors_open 0 -> 1")."""
        spec = check(name, value)
        before = self._value(spec)
        if spec.kind == BUTTON:
            if value:
                self._plc().press_button()
            return f"{name} pressed" if value else f"{name}: nothing to do for 0"
        if spec.plc_fault:
            self._plc().inject(spec.plc_fault, bool(value))
            self.plc_values[name] = value
        elif spec.board_field == "friction_scale":
            self.sup.set_sim(friction_scale=[value] * len(self.sup.config.axis_names))
        else:
            self.sup.set_sim(**{spec.board_field: int(value)})
        return f"{name} {before:g} -> {value:g}{' ' + spec.unit if spec.unit else ''}"

    def _value(self, spec: InputSpec) -> float:
        if spec.kind == BUTTON:
            return 0.0
        if spec.plc_fault:
            return self.plc_values[spec.name]
        value = self.sup.sim.get(spec.board_field)
        return float(value[0]) if spec.board_field == "friction_scale" else float(value)

    def _plc(self):
        plc = self.sup.plc_sim
        if plc is None:
            raise SimInputError("this controller runs no PLC simulator (its [plc] port names a real PLC, or it has no PLC)")
        return plc


def serve(sup: "Supervisor", session: zenoh.Session) -> Callable[[], None]:
    """Answer the gateway on the supervisor's internal keys, one query at a time on a worker
    thread (a change may wait for the PLC simulator: never on Zenoh's own threads, which route
    for the whole controller here); returns what undeclares them."""
    inputs = SimulatorInputs(sup)
    worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim-inputs")

    def answer(query: zenoh.Query, make: Callable[[], msgspec.Struct]) -> None:
        try:
            query.reply(query.key_expr, encode(make()), encoding=zenoh.Encoding.APPLICATION_JSON)
        finally:
            query.drop()

    def change(query: zenoh.Query) -> Reply:
        try:
            msg = decode(query.payload.to_bytes() if query.payload is not None else b"", SimInput)
            return Reply(True, inputs.apply(msg.input, float(msg.value)))
        except (SimInputError, msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:
            return Reply(False, str(exc))
        except (TimeoutError, OSError, EOFError) as exc:  # the PLC simulator did not answer
            return Reply(False, f"the PLC simulator did not take it: {exc}")

    queryables = [
        session.declare_queryable(sup.keys.supervisor("sim"), lambda q: worker.submit(answer, q, inputs.listing)),
        session.declare_queryable(sup.keys.supervisor("sim/set"), lambda q: worker.submit(answer, q, lambda: change(q))),
    ]

    def close() -> None:
        for q in queryables:
            q.undeclare()
        worker.shutdown(wait=True)
    return close
