"""Asking a controller process: one typed command per query, one typed reply (ok, or refused with the reason)."""

from __future__ import annotations

from typing import Callable

import msgspec
import zenoh

from .messages import Reply, decode, encode


class CommandClient:
    """A synchronous handle on one process's command queryables (`key_for(verb)`), over a Zenoh session."""

    def __init__(
        self, session: zenoh.Session, key_for: Callable[[str], str], commands: dict[str, type[msgspec.Struct]],
        who: str, timeout_s: float = 60.0,
    ) -> None:
        self.session, self.key_for, self.who, self.timeout_s = session, key_for, who, timeout_s
        self.verbs = {kind: verb for verb, kind in commands.items()}

    def request(self, command: msgspec.Struct, timeout_s: float | None = None) -> Reply:
        """Send one command and wait for its reply (at most `timeout_s`, default the client's)."""
        verb = self.verbs[type(command)]
        limit = self.timeout_s if timeout_s is None else timeout_s
        replies = self.session.get(
            self.key_for(verb), payload=encode(command), encoding=zenoh.Encoding.APPLICATION_JSON, timeout=limit
        )
        for reply in replies:
            if reply.ok is not None:
                return decode(reply.ok.payload.to_bytes(), Reply)
            return Reply(False, f"{verb}: the {self.who} answered with an error: {reply.err.payload.to_string()}")
        return Reply(False, f"{verb}: no answer from the {self.who} within {limit:g} s")
