"""Bugs injected into the controller's request handlers, on the simulated board only.

`Supervisor.set_sim(inject_bug="logic/hold,gateway/history")` makes those handlers raise, so that
the command service's bug policy (`cnc.bus.service`) is tested through the real processes, in the
middle of a cut as well as at rest. On any other board nothing is injected, whatever the block says.
"""

from __future__ import annotations

from typing import Callable

from ..config import MachineConfig
from .dataserver import SharedArea


def injected_bugs(area: SharedArea, config: MachineConfig) -> Callable[[], str] | None:
    """The `inject` of a process's command service: the `sim` block's `inject_bug`, read per
    request; None (nothing is ever injected) unless the board is the simulated one."""
    if config.board.kind != "sim":
        return None
    reader = area.reader("sim")
    return lambda: reader.read_dict()["inject_bug"]


class ServoStall:
    """A servo that sits out ticks on request, as a servo the host did not run in time would:
    `Supervisor.stall_servo(n)` bumps the `sim` block's `servo_stall_seq`, and the servo's loop
    then neither runs nor finishes its next n ticks (`sit_out`). The hardware server counts them
    missed (n at or above `[timing] watchdog_missed_ticks` trips the drive watchdog), and the
    servo's next tick finds the tick counter n ahead: n overruns."""

    def __init__(self, area: SharedArea) -> None:
        self._block, self._reader = area.blocks["sim"], area.reader("sim")
        self._block_seq = self._block.seq()
        self._stall_seq = self._reader.read_dict()["servo_stall_seq"]  # requests before this servo started are past
        self._left = 0

    def sit_out(self) -> bool:
        """Whether this tick is one to sit out."""
        if self._block.seq() != self._block_seq:
            values = self._reader.read_dict()
            self._block_seq = self._block.seq()
            if values["servo_stall_seq"] != self._stall_seq:
                self._stall_seq, self._left = values["servo_stall_seq"], int(values["servo_stall_ticks"])
        if self._left > 0:
            self._left -= 1
            return True
        return False


def servo_stall(area: SharedArea, config: MachineConfig) -> ServoStall | None:
    """The servo's stall injection; None (it never stalls on request) unless the board is the simulated one."""
    return ServoStall(area) if config.board.kind == "sim" else None
