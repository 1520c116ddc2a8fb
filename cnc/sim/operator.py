"""The scripted operator: what the demo, the fault injection, `waterjet simulate` and the tests do
at the simulated machine instead of a person, written once.

It commands through the supervisor's own clients (the private plane: the control logic's, or the
planner's where no logic runs), reads the shared-memory blocks, and plays the operator at the
transport station (its button) when the guided procedure asks. Every wait is bounded and says
what it waited for; a wait for the cycle's progress ends at once when the machine faults, saying why.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import msgspec

from ..bus.messages import Home, LoadProgram, Override, Reset, SetMode
from ..data.layout import LinkState, PlannerState, ServoState
from ..logic.states import MachineState, Mode
from ..runtime.supervisor import Supervisor


#: how often the scripted operator presses the transport button while the procedure waits for it:
#: within the press the simulated PLC holds (`PlantTimes.button_s`), so the button reads held, and
#: not at every poll of a wait, which would keep the simulator's process busy answering its pipe
PRESS_EVERY_S = 0.1


class ScriptError(RuntimeError):
    """The controller refused a command the script needed, or the machine faulted while the script
    waited for a cycle's progress; the message says which and why."""


def logic_block(sup: Supervisor) -> dict:
    """The control logic's block: mode, state, phase, cycles, procedure, alarms."""
    return sup.area.reader("logic").read_dict()


def ask(sup: Supervisor, msg: msgspec.Struct, what: str, retry_s: float = 20.0) -> None:
    """Send `msg` to the control logic until it is accepted within `retry_s` (a restarted logic
    may not answer yet, a cause that has just gone may still be seen by the next scan), else
    TimeoutError with the last reason; with `retry_s` 0, once: ScriptError with its reason."""
    if retry_s <= 0.0:
        reply = sup.logic.request(msg)
        if not reply.ok:
            raise ScriptError(f"{what} refused: {reply.reason}")
        return
    reasons: list[str] = []

    def accepted() -> bool:
        try:
            reply = sup.logic.request(msg)
        except Exception as exc:  # noqa: BLE001 - no logic yet: Zenoh's timeout or no route
            reasons.append(str(exc))
            return False
        reasons.append(reply.reason)
        return reply.ok
    try:
        sup.wait_until(accepted, retry_s, what)
    except TimeoutError as exc:
        raise TimeoutError(f"{exc}: {reasons[-1] if reasons else 'no reply'}") from None


def ask_planner(sup: Supervisor, msg: msgspec.Struct, what: str) -> None:
    """Send `msg` to the planner itself (a controller without the control logic); ScriptError unless accepted."""
    reply = sup.planner.request(msg)
    if not reply.ok:
        raise ScriptError(f"{what} refused: {reply.reason}")


def press_button_when_asked(sup: Supervisor, until: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Wait for `until()`, playing the operator at the transport station: press its button
    whenever the transport procedure waits for it.

    A cycle that faults meanwhile (the PLC link lost on a host too busy for its answers, a door)
    waits for a reset and never gets there: the wait ends at once with ScriptError naming what
    it waited for and why the machine stopped, rather than after `timeout_s` saying only that it
    timed out. The state is taken from the second scan after the wait began at the earliest, so
    that a block published before the command the caller has just sent (a reset) is not read
    as the answer to it."""
    first_scan = logic_block(sup)["scans"] + 2
    pressed_at = [-PRESS_EVERY_S]

    def step() -> bool:
        lo = logic_block(sup)
        if lo["procedure"] == "transport" and lo["procedure_state"] in ("running", "timed_out"):
            if time.monotonic() - pressed_at[0] >= PRESS_EVERY_S:
                sup.plc_sim.press_button()
                pressed_at[0] = time.monotonic()
        if until():
            return True
        if lo["state"] == MachineState.FAULT and lo["scans"] >= first_scan:
            raise ScriptError(f"the machine faulted while waiting for {what}: {lo['message'] or 'no reason given'}")
        return False
    sup.wait_until(step, timeout_s, what)


def reset_until_clear(sup: Supervisor, timeout_s: float = 30.0) -> None:
    """The PLC link up, then reset until nothing waits for one and the drives are on: a cause
    that has just gone (a released e-stop, a link that came up late on a busy host) may still be
    seen by the scan that serves the first reset, and a stop may still be running out."""
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, timeout_s, "the PLC link")

    def reset_done() -> bool:
        try:
            reply = sup.logic.request(Reset())
        except Exception:  # noqa: BLE001 - a restarted logic not answering yet
            return False
        if not reply.ok:
            return False
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            if not logic_block(sup)["blocking"] and sup.servo()["state"] == ServoState.HOLDING:
                return True
            time.sleep(0.01)
        return False
    sup.wait_until(reset_done, timeout_s, "the reset: drives on, no alarm waiting")


def ready_to_cut(sup: Supervisor, program: Path) -> None:
    """From any state: reset, drives on, homed, the program loaded, AUTO, READY."""
    reset_until_clear(sup)
    if sup.motion()["override"] != 1.0:
        ask(sup, Override(100.0), "the feed override back to 100 %")
    if sup.servo()["homed_mask"] != (1 << len(sup.config.axis_names)) - 1:
        ask(sup, SetMode(Mode.MANUAL.name), "MANUAL mode")
        ask(sup, Home(), "homing")
    sup.wait_until(lambda: logic_block(sup)["state"] == MachineState.READY
                   and sup.motion()["state"] == PlannerState.IDLE, 60.0, "READY, homed")
    ask(sup, LoadProgram(str(program)), "the program to load")
    ask(sup, SetMode(Mode.AUTO.name), "AUTO mode")
