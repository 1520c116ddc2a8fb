"""Asking the planner: one typed command per query, one typed reply (ok, or refused with the reason)."""

from __future__ import annotations

import zenoh

from ..bus.client import CommandClient
from ..bus.keys import Keys
from ..bus.messages import PLANNER_COMMANDS


class PlannerClient(CommandClient):
    """The commander's handle on the planner process, over a Zenoh session."""

    def __init__(self, session: zenoh.Session, keys: Keys, timeout_s: float = 60.0) -> None:
        super().__init__(session, keys.planner, PLANNER_COMMANDS, "planner", timeout_s)
