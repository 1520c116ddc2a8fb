"""The command lock: one operator station at a time may command the machine; the others observe.

A station is a user (who logged in: the gateway reads it from the command key, which only that
user may query) and a station name, announced by a liveliness token per Zenoh session,
`hmi/<user>/<station>/<session id>`. The lock belongs to one such token: taken by command,
released by command, or lost when that token disappears (its host, network or program died). A
second session announcing the same user and station has a token of its own, so it cannot hide
the holder's loss. A station whose token Zenoh still shows but which stopped answering the
gateway's ping (a stuck link) is *silent*: it no longer counts, and counts again once it answers.
Pure state, no Zenoh: the gateway feeds it what it sees.
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass, field

from ..bus.messages import LockState
from ..bus.service import CommandRefused

_STATION = re.compile(r"[A-Za-z0-9_-]{1,64}\Z")


@dataclass(frozen=True)
class Token:
    """One session's announcement of a station."""

    user: str
    station: str
    session: str  # the Zenoh session's id ("" for a token without one)

    @staticmethod
    def parse(key: str, root: str) -> "Token | None":
        """The token of liveliness key `key` (`<root>/hmi/<user>/<station>[/<session>]`), or None."""
        parts = key[len(root) + 1:].split("/") if key.startswith(root + "/") else []
        if len(parts) not in (3, 4) or parts[0] != "hmi":
            return None
        return Token(parts[1], parts[2], parts[3] if len(parts) == 4 else "")

    @property
    def who(self) -> str:
        return f"{self.user}/{self.station}"


@dataclass
class OperatorLock:
    holder: Token | None = None
    since_ns: int = 0
    tokens: set[Token] = field(default_factory=set)
    silent: set[Token] = field(default_factory=set)  # tokens Zenoh shows whose station stopped answering
    seq: int = 0
    _mutex: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _changed: threading.Condition = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._changed = threading.Condition(self._mutex)

    @staticmethod
    def check_station(station: str) -> str:
        if not _STATION.match(station or ""):
            raise CommandRefused(f"station id {station!r} must be 1-64 letters, digits, '-' or '_' (query attachment 'station')")
        return station

    def take(self, user: str, station: str, session: str = "") -> None:
        """Give the lock to `user`'s `station`, announced by the token of `session` (which one, when
        several sessions announce that station; "" when only one does)."""
        with self._mutex:
            self.check_station(station)
            token = self._token_of(user, station, session)
            if self.holder is not None and (self.holder.user, self.holder.station) != (user, station):
                raise CommandRefused(f"station {self.holder.station!r} holds the command lock (user {self.holder.user!r}): "
                                  "it must release it first")
            if self.holder != token:
                self.holder, self.since_ns = token, time.time_ns()
                self.seq += 1

    def release(self, user: str, station: str) -> None:
        with self._mutex:
            if self.holder is None or (self.holder.user, self.holder.station) != (user, station):
                raise CommandRefused(f"station {station!r} (user {user!r}) does not hold the command lock" +
                                  (f" ({self.holder.who!r} does)" if self.holder else ""))
            self.holder, self.since_ns = None, time.time_ns()
            self.seq += 1

    def require(self, user: str, station: str) -> None:
        """Refuse a command from anyone but the holder."""
        with self._mutex:
            if not station:
                raise CommandRefused("read-only: the query carries no station id (attachment 'station')")
            if self.holder is None or (self.holder.user, self.holder.station) != (user, station):
                who = (f"station {self.holder.station!r} holds the command lock (user {self.holder.user!r})" if self.holder
                       else "nobody holds the command lock")
                raise CommandRefused(f"read-only: {who}; take it first (cmd/lock)")

    def holds(self, user: str, station: str) -> bool:
        with self._mutex:
            return self.holder is not None and (self.holder.user, self.holder.station) == (user, station)

    def token_alive(self, token: Token) -> None:
        """Zenoh shows `token` (a silent one stays silent: only an answer brings it back)."""
        with self._mutex:
            if token not in self.tokens:
                self.tokens.add(token)
                self.seq += 1
                self._changed.notify_all()

    def token_lost(self, token: Token) -> bool:
        """`token` went away; True when it held the lock (now released)."""
        with self._mutex:
            self.tokens.discard(token)
            self.silent.discard(token)
            self.seq += 1
            return self._release_if_held(token)

    def token_silent(self, token: Token) -> bool:
        """`token`'s station stopped answering though its token stays: it counts no more (not
        announced, not among the stations, cannot take the lock) until it answers again. True when it
        held the lock (now released)."""
        with self._mutex:
            if token in self.tokens:
                self.silent.add(token)
            self.seq += 1
            return self._release_if_held(token)

    def token_answers(self, token: Token) -> bool:
        """`token`'s station answered again: it counts as announced once more. True when it was silent."""
        with self._mutex:
            if token not in self.silent:
                return False
            self.silent.discard(token)
            self.seq += 1
            self._changed.notify_all()
            return True

    def silent_token(self, user: str, station: str, session: str = "") -> Token | None:
        """The silent token of `user`'s `station` (of `session`, when given), if there is one."""
        with self._mutex:
            return self._silent_of(user, station, session)

    def silent_tokens(self) -> list[Token]:
        with self._mutex:
            return list(self.silent)

    def announced(self, user: str, station: str) -> bool:
        with self._mutex:
            return self._announced(user, station)

    def wait_announced(self, user: str, station: str, timeout_s: float) -> bool:
        """Wait until `user`'s `station` is announced (its token reaching the subscriber), at most
        `timeout_s`; whether it is."""
        with self._changed:
            return self._changed.wait_for(lambda: self._announced(user, station), timeout_s)

    def state(self) -> LockState:
        with self._mutex:
            h = self.holder
            return LockState(h.station if h else "", self.since_ns, sorted({t.station for t in self.tokens - self.silent}),
                             self.seq, holder_user=h.user if h else "")

    def _announced(self, user: str, station: str) -> bool:
        return any((t.user, t.station) == (user, station) for t in self.tokens - self.silent)

    def _silent_of(self, user: str, station: str, session: str) -> Token | None:
        return next((t for t in self.silent if (t.user, t.station) == (user, station)
                     and (not session or t.session == session)), None)

    def _release_if_held(self, token: Token) -> bool:
        if self.holder == token:
            self.holder, self.since_ns = None, time.time_ns()
            return True
        return False

    def _token_of(self, user: str, station: str, session: str) -> Token:
        mine = [t for t in self.tokens - self.silent if (t.user, t.station) == (user, station)]
        if session:
            mine = [t for t in mine if t.session == session]
        if not mine and self._silent_of(user, station, session) is not None:
            raise CommandRefused(f"station {station!r} (user {user!r}) does not answer the controller's ping "
                                 "(its link may be stuck): it cannot take the lock until it does")
        if not mine:
            raise CommandRefused(f"station {station!r} (user {user!r}) has no liveliness token"
                              + (f" from session {session}" if session else "")
                              + ": declare it before taking the lock")
        if len(mine) > 1:
            raise CommandRefused(f"station {station!r} (user {user!r}) is announced by {len(mine)} sessions: "
                              "say which (query attachment 'session')")
        return mine[0]
