"""Asking the planner: one typed command per query, one typed reply (ok, or refused with the reason)."""

from __future__ import annotations

import msgspec
import zenoh

from ..bus.keys import Keys
from ..bus.messages import PLANNER_COMMANDS, Reply, decode, encode

_VERBS = {kind: verb for verb, kind in PLANNER_COMMANDS.items()}


class PlannerClient:
    """The commander's handle on the planner process, over a Zenoh session."""

    def __init__(self, session: zenoh.Session, keys: Keys, timeout_s: float = 60.0) -> None:
        self.session, self.keys, self.timeout_s = session, keys, timeout_s

    def request(self, command: msgspec.Struct) -> Reply:
        """Send one command (`LoadProgram`, `Start`, `Hold`, ...) and wait for its reply."""
        verb = _VERBS[type(command)]
        replies = self.session.get(
            self.keys.planner(verb), payload=encode(command), encoding=zenoh.Encoding.APPLICATION_JSON, timeout=self.timeout_s
        )
        for reply in replies:
            if reply.ok is not None:
                return decode(reply.ok.payload.to_bytes(), Reply)
            return Reply(False, f"{verb}: the planner answered with an error: {reply.err.payload.to_string()}")
        return Reply(False, f"{verb}: no answer from the planner within {self.timeout_s:g} s")
