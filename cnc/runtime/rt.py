"""Real-time setup of a process: SCHED_FIFO, locked memory, garbage collector out of the loop.

Where the system does not permit it the process keeps running with a clear warning: the
controller still works (with more jitter), and `RtStatus` says what was granted.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

log = logging.getLogger(__name__)

_MCL_CURRENT, _MCL_FUTURE = 1, 2
_libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


@dataclass(frozen=True)
class RtStatus:
    fifo: bool
    mlocked: bool
    priority: int
    reason: str = ""

    @property
    def granted(self) -> bool:
        return self.fifo and self.mlocked


def enter_realtime(priority: int, name: str) -> RtStatus:
    """Ask for SCHED_FIFO at `priority` and mlockall; warn and fall back when refused."""
    reasons = []
    fifo = mlocked = False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        fifo = True
    except (PermissionError, OSError) as exc:
        reasons.append(f"SCHED_FIFO refused ({exc.strerror or exc})")
    if _libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:
        mlocked = True
    else:
        reasons.append(f"mlockall refused ({os.strerror(ctypes.get_errno())})")
    status = RtStatus(fifo, mlocked, priority if fifo else 0, "; ".join(reasons))
    if not status.granted:
        log.warning("%s: running without full real-time guarantees: %s", name, status.reason)
    return status


#: how far a lockstep process steps aside on the virtual clock (`step_aside_for_wall_time`)
VIRTUAL_NICE = 5


def step_aside_for_wall_time(clock: str) -> None:
    """On the virtual clock (`clock` "virtual"; nothing on the real-time clock, where the process
    asks for SCHED_FIFO): lower this process below the ones that keep wall-clock deadlines.

    There the hardware server, the servo, the planner and the control logic hand ticks to each
    other as fast as the CPUs allow, two of them polling between hand-offs (`cnc.hw.timers`), and
    machine time simply waits when the host is busy. The PLC link does not: it counts an answer
    missing after `[plc] timeout_ms` of wall time, and three missing are a lost link, a safe stop
    (its simulator already runs at nice -10 where the host permits, as a PLC with a CPU of its
    own). Nor do the gateway, the operator stations and the scripts, whose Zenoh requests have
    wall-clock timeouts. On a 2-CPU host running several controllers (tests two at a time,
    a simulation beside other work) the polling processes kept the link from its CPU for 300 ms:
    three demos at once all lost their links. At nice `VIRTUAL_NICE` they still get every CPU
    nobody else wants, and those processes come first."""
    if clock != "virtual":
        return
    try:
        os.nice(VIRTUAL_NICE)
    except OSError as exc:  # raising one's own nice value is always permitted; a sandbox may refuse it
        log.debug("step_aside_for_wall_time: %s", exc)


#: how far the PLC link steps up on the virtual clock, where it keeps wall-clock deadlines (`step_up_for_wall_time`)
WALL_TIME_NICE = -5


def step_up_for_wall_time(clock: str) -> None:
    """On the virtual clock (nothing elsewhere: on the real-time clock the process asks for
    SCHED_FIFO): raise this process above the ones that merely share the CPUs, where the host
    permits it (a process may lower its nice value only with CAP_SYS_NICE).

    The PLC link exchanges with a PLC in wall time and counts a stale input image, and three
    answers missing, as a lost link: a safe stop. Its simulator runs at nice -10 as a PLC with a
    CPU of its own, and the lockstep processes step aside (`step_aside_for_wall_time`); but at
    nice 0 the link itself shared the CPUs evenly with the operator stations, fifty observers'
    sessions and a test's other work: on a busy 2-CPU host its input image once went a second
    without a refresh while its simulator reported no stall, and homing stopped on a lost link.
    At nice `WALL_TIME_NICE` its few milliseconds of work per exchange come first."""
    if clock != "virtual":
        return
    try:
        os.nice(WALL_TIME_NICE)
    except OSError as exc:  # not permitted: it shares the CPUs like any process
        log.debug("step_up_for_wall_time: %s", exc)


def leave_realtime() -> None:
    """Put the calling thread back under the normal time-sharing scheduler.

    For long computations started from a real-time process (checking and planning a large
    program takes minutes): at SCHED_FIFO they would hold a CPU away from everything else on it,
    and once the kernel's real-time throttling steps in, from the servo too (a drive watchdog
    trip on a 2-CPU host). Threads inherit their creator's policy, so the thread itself asks.
    """
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError as exc:  # not real-time to begin with, or not permitted: nothing to give back
        log.debug("leave_realtime: %s", exc)


def keep_gc_out() -> None:
    """Collect once, move survivors to the permanent generation and stop automatic collection.

    The tick loops allocate no reference cycles, so nothing accumulates; what they do
    allocate is freed by reference counting, which never pauses the loop.
    """
    gc.collect()
    gc.freeze()
    gc.disable()


@contextmanager
def collector_paused() -> Iterator[None]:
    """Build a large, long-lived structure (a program of a million lines) without the cyclic
    garbage collector passing over it, then and later.

    Each pass over millions of new objects holds the interpreter for seconds: the planner's loop
    and the gateway's stood still long enough for the supervisor to kill them as hung. Inside,
    automatic collection is off; at the end every object alive is moved to the permanent
    generation, which later passes skip. Reference counting still frees the structure when it
    is dropped; only reference cycles made inside stay (a few hundred objects per program,
    measured, whatever its size).
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if was_enabled:
            gc.enable()


def give_back_memory() -> None:
    """Return the C heap's free memory to the system (glibc `malloc_trim`): after a large program's
    interpretation its temporaries are freed, but the allocator keeps the pages, and the planner's
    resident size would stay at the interpretation's peak. Nothing where the call is missing."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
