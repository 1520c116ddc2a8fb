"""Asking the control logic (the machine's commander): one typed command, one typed reply."""

from __future__ import annotations

import zenoh

from ..bus.client import CommandClient
from ..bus.keys import Keys
from ..bus.messages import LOGIC_COMMANDS, Notice


class LogicClient(CommandClient):
    """A handle on the control-logic process's commands (`SetMode`, `CycleStart`, `Reset`, ...),
    and on its internal `notice` (an info entry for the alarm history)."""

    def __init__(self, session: zenoh.Session, keys: Keys, timeout_s: float = 60.0) -> None:
        super().__init__(session, keys.logic, {**LOGIC_COMMANDS, "notice": Notice}, "control logic", timeout_s)
