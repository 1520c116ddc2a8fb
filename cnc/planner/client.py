"""Asking the planner: one typed command per query, one typed reply (ok, or refused with the reason)."""

from __future__ import annotations

from typing import Callable

import msgspec
import zenoh

from ..bus.client import CommandClient
from ..bus.keys import Keys
from ..bus.messages import MOTION_COMMANDS, PLANNER_COMMANDS, Reply, Stamp


class PlannerClient(CommandClient):
    """The commander's handle on the planner process, over a Zenoh session. With `stamp`, motion
    commands without a stamp get the commander's (its token and current epoch) as they are sent."""

    def __init__(self, session: zenoh.Session, keys: Keys, timeout_s: float = 60.0,
                 stamp: Callable[[], Stamp] | None = None) -> None:
        super().__init__(session, keys.planner, PLANNER_COMMANDS, "planner", timeout_s)
        self.stamp = stamp

    def request(self, command: msgspec.Struct, timeout_s: float | None = None) -> Reply:
        if self.stamp is not None and isinstance(command, MOTION_COMMANDS) and command.stamp is None:
            command = msgspec.structs.replace(command, stamp=self.stamp())
        return super().request(command, timeout_s)
