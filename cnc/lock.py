"""The command lock: one operator station at a time may command the machine; the others observe.

A station takes the lock by command and releases it by command, or loses it when its
liveliness token disappears (its host, network or program died). Pure state, no Zenoh: the
gateway feeds it what it sees.
"""

from __future__ import annotations

import re
import threading
import time
from dataclasses import dataclass, field

from .bus.messages import LockState

_STATION = re.compile(r"[A-Za-z0-9_-]{1,64}\Z")


class LockRefused(Exception):
    """The station may not do this; the message says why."""


@dataclass
class OperatorLock:
    holder: str = ""
    since_ns: int = 0
    stations: set[str] = field(default_factory=set)
    seq: int = 0
    _mutex: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @staticmethod
    def check_station(station: str) -> str:
        if not _STATION.match(station or ""):
            raise LockRefused(f"station id {station!r} must be 1-64 letters, digits, '-' or '_' (query attachment 'station')")
        return station

    def take(self, station: str) -> None:
        with self._mutex:
            self.check_station(station)
            if station not in self.stations:
                raise LockRefused(f"station {station!r} has no liveliness token: declare it before taking the lock")
            if self.holder and self.holder != station:
                raise LockRefused(f"station {self.holder!r} holds the command lock: it must release it first")
            if self.holder != station:
                self.holder, self.since_ns = station, time.time_ns()
                self.seq += 1

    def release(self, station: str) -> None:
        with self._mutex:
            if self.holder != station:
                raise LockRefused(f"station {station!r} does not hold the command lock" +
                                  (f" ({self.holder!r} does)" if self.holder else ""))
            self.holder, self.since_ns = "", time.time_ns()
            self.seq += 1

    def require(self, station: str) -> None:
        """Refuse a command from anyone but the holder."""
        with self._mutex:
            if not station:
                raise LockRefused("read-only: the query carries no station id (attachment 'station')")
            if self.holder != station:
                who = f"station {self.holder!r} holds the command lock" if self.holder else "nobody holds the command lock"
                raise LockRefused(f"read-only: {who}; take it first (cmd/lock)")

    def station_alive(self, station: str) -> None:
        with self._mutex:
            if station not in self.stations:
                self.stations.add(station)
                self.seq += 1

    def station_lost(self, station: str) -> bool:
        """The station's token went away; True when it held the lock (now released)."""
        with self._mutex:
            self.stations.discard(station)
            self.seq += 1
            if self.holder == station:
                self.holder, self.since_ns = "", time.time_ns()
                return True
            return False

    def state(self) -> LockState:
        with self._mutex:
            return LockState(self.holder, self.since_ns, sorted(self.stations), self.seq)
