"""Clocks for the base tick: real-time (absolute deadlines) and virtual (as fast as the CPU allows).

The hardware server asks its clock for the next tick. The real-time clock sleeps until an
absolute deadline with `clock_nanosleep(TIMER_ABSTIME)`, so the period never drifts with
the time the loop itself takes; when it wakes a whole period late it counts the tick as
late and skips ahead instead of bursting to catch up. The virtual clock returns at once:
time is the tick count times the period, and timer clients are run to completion each tick
(`synchronous`), which makes a simulation deterministic.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import time

_CLOCK_MONOTONIC = 1
_TIMER_ABSTIME = 1


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


_libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
_nanosleep = _libc.clock_nanosleep
_nanosleep.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Timespec), ctypes.c_void_p]


class RealtimeClock:
    """Ticks at absolute deadlines on CLOCK_MONOTONIC."""

    synchronous = False

    def __init__(self, period_s: float) -> None:
        self.period_ns = int(round(period_s * 1e9))
        self.late_ticks = 0
        self._deadline = 0
        self._ts = _Timespec()
        self._ts_ref = ctypes.byref(self._ts)

    def start(self) -> None:
        self._deadline = time.monotonic_ns() + self.period_ns

    def wait(self) -> tuple[int, int]:
        """Sleep until the next deadline; return (deadline_ns, woke_ns)."""
        deadline = self._deadline
        self._ts.tv_sec, self._ts.tv_nsec = divmod(deadline, 1_000_000_000)
        while True:
            rc = _nanosleep(_CLOCK_MONOTONIC, _TIMER_ABSTIME, self._ts_ref, None)
            if rc != errno.EINTR:
                break
        woke = time.monotonic_ns()
        nxt = deadline + self.period_ns
        if woke >= nxt:
            missed = (woke - deadline) // self.period_ns
            self.late_ticks += missed
            nxt = deadline + (missed + 1) * self.period_ns
        self._deadline = nxt
        return deadline, woke


class VirtualClock:
    """Ticks immediately; time is tick count times period."""

    synchronous = True

    def __init__(self, period_s: float) -> None:
        self.period_ns = int(round(period_s * 1e9))
        self.late_ticks = 0
        self._now = 0

    def start(self) -> None:
        self._now = 0

    def wait(self) -> tuple[int, int]:
        self._now += self.period_ns
        return self._now, self._now


def make_clock(kind: str, period_s: float) -> RealtimeClock | VirtualClock:
    if kind == "realtime":
        return RealtimeClock(period_s)
    if kind == "virtual":
        return VirtualClock(period_s)
    raise ValueError(f"clock {kind!r} is not one of: realtime, virtual")
