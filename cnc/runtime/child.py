"""What every controller process is handed at start, and the common start-up of a child process."""

from __future__ import annotations

import ctypes
import faulthandler
import logging
import os
import select
import signal
import threading
from dataclasses import dataclass, field
from typing import Any

from ..config import MachineConfig
from ..hw.timers import TimerClient

_PR_SET_PDEATHSIG = 1  # linux/prctl.h
HANG_DUMP_SIGNAL = signal.SIGUSR2  # a child writes every thread's stack to stderr: sent before a hung one is killed


@dataclass
class Runtime:
    """Picklable description of one controller instance, passed to each spawned process."""

    config: MachineConfig
    clock: str  # "realtime" | "virtual"
    data_name: str
    fifo_name: str
    zenoh_connect: list[str]
    trace_name: str = ""
    timer_clients: dict[str, TimerClient] = field(default_factory=dict)
    log_level: int = logging.INFO
    plc_port: str = ""  # serial device of the PLC link: the machine file's, or the simulator's pty
    history_path: str = ""  # the alarm and message history (SQLite)
    zenoh_credentials: tuple[str, str] | None = None  # the controller user's, when access control is on
    supervisor_pid: int = 0  # the processes end with it (`die_with`)


def die_with(launcher_pid: int) -> None:
    """Have this process ended (SIGTERM) when the process that launched it dies, however it dies
    (kill -9, a crash): an orphaned controller process would go on ticking, holding the serial
    port and answering on Zenoh, with no supervisor to watch it. Linux only; elsewhere a no-op.

    The kernel's parent-death signal ends it with its parent (the launcher starts its processes
    from its main thread, whose end is the trigger). Forked by the fork server
    (`table.process_context`), the parent is that server, which lives as long as any process it
    forked: a thread then also waits on the launcher's pidfd, readable once it has ended. (Were
    the server killed, its processes end with it: the supervisor, which then sees them all gone,
    must not find the old ones still holding the board and the port.)"""
    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # it died before the request was in place
        os.kill(os.getpid(), signal.SIGTERM)
        return
    if parent == launcher_pid:
        return
    try:
        pidfd = os.pidfd_open(launcher_pid)
    except ProcessLookupError:  # gone already
        os.kill(os.getpid(), signal.SIGTERM)
        return
    except (OSError, AttributeError):
        return
    threading.Thread(target=_term_when_readable, args=(pidfd,), name="die-with-launcher", daemon=True).start()


def _term_when_readable(pidfd: int) -> None:
    select.select([pidfd], [], [])  # blocks without the interpreter lock until the launcher has ended
    os.kill(os.getpid(), signal.SIGTERM)


def child_setup(rt: Runtime, name: str) -> None:
    """Logging, ending with the supervisor, and leave Ctrl-C to the supervisor: it stops the
    processes in order."""
    die_with(rt.supervisor_pid or os.getppid())
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # written from the signal handler itself, so even a process stuck holding the interpreter
    # says where it was when the supervisor finds its heartbeat stopped
    faulthandler.register(HANG_DUMP_SIGNAL, all_threads=True)
    logging.basicConfig(
        level=rt.log_level, format=f"%(asctime)s {name}[{os.getpid()}] %(levelname)s %(message)s"
    )


def set_ready(ready: Any) -> None:
    if ready is not None:
        ready.set()
