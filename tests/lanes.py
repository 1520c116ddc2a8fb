"""`make test`'s two lanes: the tests that only compute run beside the others, at idle priority.

Most of the suite waits: on a controller's machine time (its processes hand ticks to each other),
on Zenoh, on process starts; one CPU of the two is idle on average. The modules marked `computes`
(interpreting, planning, the tick rig's safety matrix: the test process alone, its CPU the only
thing it waits for) run in a second pytest process at the same time, under SCHED_IDLE: the kernel
gives them only a CPU nobody else wants, so the controllers under test in the main lane, and
their PLC links' wall-clock timeouts, never wait for them (two workers sharing the CPUs evenly
lost PLC links: docs/benchmarks.md, "The test suite's time").

A test in that lane may wait seconds for a CPU, so it must not start processes or threads or
open Zenoh sessions (something else to wait for, in wall time): each of those raises `LaneError`
there, naming what it did. (Nor may it time itself: the guide keeps timing for bench/. The lane
takes Hypothesis's own wall-clock deadline and too-slow health check off.)
The lane's shared-memory segments carry their own prefix, so that neither lane counts the
other's as its own leftovers. A test of the main lane marked `alone` (the demo) runs last and
starts once the computes lane has ended.
"""

from __future__ import annotations

import os
import time
from typing import Any, NoReturn

MARK = "computes"
#: set by `make test` for the pytest process of the `computes` lane
LANE_ENV = "WATERJET_TEST_LANE"
#: a test of the main lane that needs the host to itself (the demo: the shipped PLC link's 100 ms
#: answers on the virtual clock, which the idle lane beside it cost twice in seven runs)
ALONE = "alone"
#: set by `make test` for the main lane: the computes lane's pid, whose end an `alone` test awaits
LANE_PID_ENV = "WATERJET_COMPUTES_LANE_PID"
#: the segments of the computes lane: wjcomp_<machine>_<random>_<what> (the controller's: wjcnc_...)
COMPUTES_SHM_PREFIX = "wjcomp"


class LaneError(RuntimeError):
    """A test of the `computes` lane did what only the main lane may do."""


def in_computes_lane() -> bool:
    return os.environ.get(LANE_ENV, "") == MARK


def other_lanes_segment(name: str) -> bool:
    """True for a /dev/shm entry the other lane may have made (not this process's to count)."""
    if in_computes_lane():
        return not name.startswith(COMPUTES_SHM_PREFIX + "_")
    return name.startswith(COMPUTES_SHM_PREFIX + "_")


def enter_computes_lane() -> None:
    """Idle priority for every thread of this process (nice 19 where SCHED_IDLE is not available)
    and the lane's segment prefix. `make test` starts the lane under `chrt --idle` already; this
    also covers a run started otherwise. Every thread: a policy set for the process applies to its
    calling thread only, and numpy's BLAS had started a worker thread at import, one that spins
    for work at normal priority: a PLC link beside it was starved (the demo's, once)."""
    for tid in (int(t) for t in os.listdir("/proc/self/task")):
        try:
            os.sched_setscheduler(tid, os.SCHED_IDLE, os.sched_param(0))
        except (AttributeError, OSError):
            os.setpriority(os.PRIO_PROCESS, tid, 19)
    from hypothesis import HealthCheck, settings

    from cnc.data import dataserver

    dataserver.SHM_PREFIX = COMPUTES_SHM_PREFIX
    # Hypothesis times its examples (a deadline) and their generation (a health check) in wall
    # time: here a test waits for a CPU at any moment, so neither may fail it
    settings.register_profile(MARK, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    settings.load_profile(MARK)


def refuse_waiting() -> None:
    """Once the tests are collected (importing modules may run a program: ctypes' library search),
    what this lane must not do raises `LaneError`."""
    import multiprocessing.process
    import subprocess
    import threading

    import zenoh

    from cnc.runtime.supervisor import Supervisor

    _refuse(Supervisor, "start", "started a controller")
    _refuse(multiprocessing.process.BaseProcess, "start", "started a process")
    _refuse(subprocess.Popen, "__init__", "started a program")
    _refuse(threading.Thread, "start", "started a thread")
    _refuse(zenoh, "open", "opened a Zenoh session")


def _refuse(owner: Any, name: str, did: str) -> None:
    def refused(*_args: Any, **_kwargs: Any) -> NoReturn:
        raise LaneError(
            f"the test {did} ({getattr(owner, '__name__', owner)}.{name}): its module is marked `{MARK}`, which "
            f"`make test` runs at idle priority beside the others, where it may wait seconds for a CPU; "
            f"a test that waits on anything but its own computation belongs in the main lane: take the mark off")
    setattr(owner, name, refused)


def last_the_alone(items: list) -> None:
    """The main lane's `alone` tests run last, when the computes lane has long ended."""
    items.sort(key=lambda item: item.get_closest_marker(ALONE) is not None)


def await_the_computes_lane() -> None:
    """Until the computes lane's process has ended (none: at once). It waits on that event only;
    pytest-timeout bounds it, as every test."""
    from cnc.interlock import process_gone  # an ended process, or a zombie not yet reaped

    pid = int(os.environ.get(LANE_PID_ENV, "0") or 0)
    while pid > 0 and not process_gone(pid):
        time.sleep(0.5)
