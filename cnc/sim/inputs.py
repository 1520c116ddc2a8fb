"""The simulated machine's inputs as an operator changes them: over Zenoh, from the screen, from a shell.

The supervisor owns the simulated environment: the `sim` block the hardware server hands to the
simulated board (e-stop, doors, mains, friction) and the handle on the PLC simulator (the
transport station's button, the light barriers, the pump, the serial link). `SimulatorInputs`
applies a change (`cnc.siminputs` names the inputs and checks it) and reads them back; the
supervisor serves it through its command service on internal keys (`Keys.supervisor("sim")`,
`"sim/set"`), which only the gateway reaches: an operator's `cmd/sim` passes the gateway's
role and lock checks first (`cnc.gateway.door`), and `<root>/sim` reads them.
"""

from __future__ import annotations

import logging
from typing import Any, Callable, Protocol

import zenoh

from ..bus.messages import Reply, SimInput, SimInputInfo, SimInputs
from ..bus.service import CommandRefused, CommandService, Request, Route, report_to_logic
from ..siminputs import BUTTON, INPUTS, InputSpec, SimInputError, check



class SimOwner(Protocol):
    """What of the supervisor this needs (`cnc.runtime.supervisor.Supervisor` fits)."""

    config: Any
    keys: Any
    sim: Any  # the `sim` block's writer
    plc_sim: Any  # the PLC simulator's handle, or None

    def set_sim(self, **values: Any) -> None: ...

log = logging.getLogger(__name__)

class SimulatorInputs:
    """The supervisor's simulated inputs: `listing()` and `apply(name, value)`."""

    def __init__(self, sup: "SimOwner") -> None:
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


def serve(sup: "SimOwner", session: zenoh.Session) -> Callable[[], None]:
    """Answer the gateway on the supervisor's internal keys, through a command service of its own
    (a worker thread: a change may wait for the PLC simulator, never on Zenoh's threads, which
    route for the whole controller here); returns what stops it."""
    inputs = SimulatorInputs(sup)

    def change(request: Request) -> Reply:
        msg: SimInput = request.message
        try:
            return Reply(True, inputs.apply(msg.input, float(msg.value)))
        except SimInputError as exc:
            raise CommandRefused(str(exc)) from None
        except (TimeoutError, OSError, EOFError) as exc:  # the PLC simulator did not answer
            raise CommandRefused(f"the PLC simulator did not take it: {exc}") from None

    service = CommandService(session, sup.keys, "supervisor", report_to_logic(session, sup.keys, "supervisor"),
                             threaded=True)
    service.serve(
        Route("sim", sup.keys.supervisor("sim"), lambda _request: inputs.listing(), read=True, lane="query"),
        Route("sim/set", sup.keys.supervisor("sim/set"), change, SimInput, lane="cmd"),
    )
    return service.close
