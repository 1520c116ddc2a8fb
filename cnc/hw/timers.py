"""Timer clients of the hardware server (QMotor 3.0's TimerServer).

A timer client runs at an integer divisor of the base rate. The hardware server posts the
client's `wake` semaphore on every tick that is a multiple of its divisor; the client does
its work and posts `done`. With the virtual clock the server waits for `done` (bounded) so
that each tick runs to completion and the simulation is deterministic; with the real-time
clock it never waits: a client that is late shows up as missed ticks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass
class TimerClient:
    """A registration: name, divisor and the two semaphores shared with the client process."""

    name: str
    divisor: int
    wake: Any  # multiprocessing.Semaphore
    done: Any  # multiprocessing.Semaphore

    @classmethod
    def new(cls, ctx: Any, name: str, divisor: int) -> "TimerClient":
        if divisor < 1:
            raise ValueError(f"timer client {name!r}: divisor {divisor} must be >= 1")
        return cls(name, divisor, ctx.Semaphore(0), ctx.Semaphore(0))

    # client side ------------------------------------------------------------------------
    def wait_tick(self, timeout_s: float) -> bool:
        """Block until the next tick for this client; False on timeout (lets the client check for shutdown)."""
        return self.wake.acquire(True, timeout_s)

    def tick_done(self) -> None:
        self.done.release()
