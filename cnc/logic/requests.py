"""Requests from the control logic to the planner that never block a scan: sent now, answered
in a later scan."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import msgspec
import zenoh

from ..bus.keys import Keys
from ..bus.messages import PLANNER_COMMANDS, Reply, decode, encode

_VERBS = {kind: verb for verb, kind in PLANNER_COMMANDS.items()}
OnReply = Callable[[Reply], None]


@dataclass
class _Pending:
    verb: str
    replies: Any  # the get's reply channel
    on_reply: OnReply | None
    deadline: float
    limit_s: float


class PlannerLink:
    """The logic's handle on the planner: `send()` returns at once; `poll()` (every scan) hands
    each answer, or a refusal when none came in time, to its callback."""

    def __init__(self, session: zenoh.Session, keys: Keys, timeout_s: float = 120.0) -> None:
        self.session, self.keys, self.timeout_s = session, keys, timeout_s
        self.pending: list[_Pending] = []

    def send(self, command: msgspec.Struct, on_reply: OnReply | None = None, timeout_s: float | None = None) -> None:
        """Ask the planner; `timeout_s` (default the link's) bounds the wait for this answer."""
        verb = _VERBS[type(command)]
        limit = self.timeout_s if timeout_s is None else timeout_s
        replies = self.session.get(
            self.keys.planner(verb), payload=encode(command), encoding=zenoh.Encoding.APPLICATION_JSON, timeout=limit
        )
        self.pending.append(_Pending(verb, replies, on_reply, time.monotonic() + limit + 1.0, limit))

    @property
    def busy(self) -> bool:
        return bool(self.pending)

    def poll(self) -> None:
        still = []
        now = time.monotonic()
        for p in self.pending:
            reply = self._answer(p, now)
            if reply is None:
                still.append(p)
            elif p.on_reply is not None:
                p.on_reply(reply)
        self.pending = still

    def _answer(self, p: _Pending, now: float) -> Reply | None:
        try:
            r = p.replies.try_recv()
        except zenoh.ZError:  # the channel closed without a reply: nobody answers that key
            return Reply(False, f"{p.verb}: no answer from the planner (is it running?)")
        if r is None:
            return Reply(False, f"{p.verb}: no answer from the planner within {p.limit_s:g} s") if now > p.deadline else None
        if r.ok is not None:
            return decode(r.ok.payload.to_bytes(), Reply)
        return Reply(False, f"{p.verb}: the planner answered with an error: {r.err.payload.to_string()}")
