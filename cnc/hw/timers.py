"""Timer clients of the hardware server (QMotor 3.0's TimerServer).

A timer client runs at an integer divisor of the base rate. The hardware server posts the
client's `wake` semaphore on every tick that is a multiple of its divisor; the client does
its work and posts `done`. With the virtual clock the server waits for `done` (bounded) so
that each tick runs to completion and the simulation is deterministic; with the real-time
clock it never waits: a client that is late shows up as missed ticks.

With the virtual clock the hand-offs are the tick's cost: a process blocked on a semaphore is
woken by the kernel, and on a virtual machine with idle CPUs that takes some 40 us each way
(80 us a round trip measured on the 2-CPU CI host, against under 1 us for a process that polls).
So there each side polls for a short while (`spin_ns`) before it blocks: the server for `done`,
and a client woken every tick for its next `wake`. The real-time clock never polls: there a
client waits a whole period for its tick, and polling would only burn the CPU the others need.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from typing import Any

#: how long a virtual-clock hand-off polls before it blocks: longer than a tick's work in the
#: slowest process, so that in a run of ticks nobody sleeps, and short enough that a side which
#: waits for a long one (a replan, a paused clock) gives its CPU back at once
VIRTUAL_SPIN_NS = 200_000


@dataclass
class TimerClient:
    """A registration: name, divisor and the two semaphores shared with the client process."""

    name: str
    divisor: int
    wake: Any  # multiprocessing.Semaphore
    done: Any  # multiprocessing.Semaphore
    spin_ns: int = 0  # poll this long before blocking (the virtual clock only)

    @classmethod
    def new(cls, ctx: Any, name: str, divisor: int, spin_ns: int = 0) -> "TimerClient":
        if divisor < 1:
            raise ValueError(f"timer client {name!r}: divisor {divisor} must be >= 1")
        return cls(name, divisor, ctx.Semaphore(0), ctx.Semaphore(0), spin_ns)

    # client side ------------------------------------------------------------------------
    def wait_tick(self, timeout_s: float) -> bool:
        """Block until the next tick for this client; False on timeout (lets the client check for shutdown).
        A client woken every tick polls first (`spin_ns`): its next tick is a server's tick away."""
        if self.divisor == 1 and self.spin_ns and _poll(self.wake, self.spin_ns):
            return True
        return self.wake.acquire(True, timeout_s)

    def tick_done(self) -> None:
        self.done.release()

    # server side ------------------------------------------------------------------------
    def wait_done(self, timeout_s: float, poll: bool = True) -> bool:
        """The server waits for this client's tick to end (virtual clock); False on timeout. It polls
        first only when told (`poll`): for the last client woken in a tick, when the others are
        done; while two are at work, a polling server would take the CPU one of them needs on a
        2-CPU host."""
        if poll and self.spin_ns and _poll(self.done, self.spin_ns):
            return True
        return self.done.acquire(True, timeout_s)


def _poll(sem: Any, spin_ns: int) -> bool:
    """Take `sem` if it is posted within `spin_ns`, without sleeping; False if it is not."""
    acquire, now, give_way = sem.acquire, time.perf_counter_ns, os.sched_yield
    end = now() + spin_ns
    while True:
        if acquire(False):
            return True
        if now() > end:
            return False
        give_way()
