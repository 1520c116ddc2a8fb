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
