"""The controller's processes, in one table: what each is, where it starts, in which order, how
it is scheduled and what happens when it is lost.

Everything the supervisor and the processes need to know about the set of processes is derived
from `PROCESSES`: the start stages, the restart policies, the heartbeat and shutdown slots, the
real-time priorities. A process's entry point is named as `module:function` and imported in the
child process that runs it; so the table names the PLC link's process without the controller's
runtime importing the PLC link (it builds on the controller, not the other way round).
"""

from __future__ import annotations

import importlib
import multiprocessing
from dataclasses import dataclass
from multiprocessing.context import BaseContext
from typing import Any, Callable

from ..config import MachineConfig
from ..data.layout import Proc


@dataclass(frozen=True)
class ProcessSpec:
    name: str
    slot: Proc  # its bit in the heartbeat, shutdown and membership words
    entry: str  # "module:function", called as function(runtime, ready_event) in the child
    stage: int  # start stage: a stage starts once the one before is ready; they stop in reverse
    restart: str  # when lost: "always", "faulted" (restarted into a latched fault), "never" (the controller ends)
    rt_rank: int | None  # SCHED_FIFO at [timing] realtime_priority minus this (on the real-time clock); None: normal

    def main(self) -> Callable[[Any, Any], None]:
        module, _, function = self.entry.partition(":")
        return getattr(importlib.import_module(module), function)


# The servo waits for ticks before the hardware server gives them; the PLC link reports its state
# before the control logic reads it (a link not yet started would be an alarm); within a stage the
# processes do not depend on each other. Priorities: the board's tick first, then the servo, the
# planner that feeds it, the logic's scan, the PLC link; the gateway and the logger never compete.
PROCESSES: tuple[ProcessSpec, ...] = (
    ProcessSpec("servo", Proc.SERVO, "cnc.runtime.procs:run_servo", 0, "faulted", 1),
    ProcessSpec("hardware", Proc.HARDWARE, "cnc.runtime.procs:run_hardware", 1, "never", 0),
    ProcessSpec("planner", Proc.PLANNER, "cnc.runtime.procs:run_planner", 2, "always", 2),
    ProcessSpec("plc_link", Proc.PLC_LINK, "plc_link.process:run_plc_link", 2, "always", 4),
    ProcessSpec("logic", Proc.LOGIC, "cnc.runtime.procs:run_logic", 3, "always", 3),
    ProcessSpec("gateway", Proc.GATEWAY, "cnc.runtime.procs:run_gateway", 3, "always", None),
    ProcessSpec("logger", Proc.LOGGER, "cnc.runtime.procs:run_logger", 3, "always", None),
)
BY_NAME = {p.name: p for p in PROCESSES}
START_ORDER = tuple(p.name for p in PROCESSES)
START_STAGES = tuple(tuple(p.name for p in PROCESSES if p.stage == s) for s in sorted({p.stage for p in PROCESSES}))


# What the processes import once they run (each entry imports its own process's module inside, so
# that the table stays free of them): the fork server imports all of it once (`process_context`).
PRELOAD = tuple(dict.fromkeys(
    [p.entry.partition(":")[0] for p in PROCESSES]
    + ["cnc.hw.clock", "cnc.hw.server", "cnc.servo", "cnc.planner.process", "cnc.logic.process", "cnc.gateway.process",
       "cnc.logger.process", "plc_link.sim_server",
       "scipy.optimize", "scipy.sparse"]  # the planner's LP solver (`programme.load_solver`): loaded once, shared
))


def process_context() -> BaseContext:
    """How the supervisor starts its processes (and the PLC simulator): forked from a fork server,
    a clean process started once that has imported what they all need (`PRELOAD`).

    A process started afresh ("spawn") pays a new interpreter and its imports, 0.2-0.35 s of CPU
    each, on every start and every restart: four start stages one after the other made 1.3 s of
    every controller start. A fork of the server starts in milliseconds and shares the imported
    modules' memory. The server holds no session, no shared memory and no thread of the
    controller's, so a fork of it is as clean as a spawned process. It inherits the supervisor's
    environment and working directory when the first process starts (nothing the controller
    reads from either changes after that) and lives as long as a process it forked does. The
    processes end with the supervisor, and with the server were it killed (`child.die_with`)."""
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(PRELOAD))
    return ctx


def realtime_priority(config: MachineConfig, name: str) -> int:
    """The SCHED_FIFO priority of process `name` on this machine (at least 1)."""
    rank = BY_NAME[name].rt_rank
    if rank is None:
        raise ValueError(f"the {name} process runs under normal scheduling")
    return max(1, config.timing.realtime_priority - rank)
