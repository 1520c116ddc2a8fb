"""Entry points of the controller processes started by the supervisor.

Each process attaches to the shared memory, opens its Zenoh session and declares its
liveliness token before it enters its loop; the time-driven ones then ask for real-time
scheduling (with the real-time clock) and keep the garbage collector out of the loop, so
nothing on the tick path waits for the network, the disk or a collection.
"""

from __future__ import annotations

import logging
import os
import signal
from pathlib import Path

from ..bus.keys import Keys
from ..bus.session import open_client
from ..data.dataserver import SharedArea
from ..data.fifo import SetpointFifo
from ..data.injection import servo_stall
from ..data.layout import ClockKind, Proc, controller_layouts
from .rt import enter_realtime, keep_gc_out, step_aside_for_wall_time
from .table import realtime_priority
from .child import Runtime, child_setup, set_ready
from ..data.trace import TraceRing

log = logging.getLogger(__name__)


def _attach(rt: Runtime) -> SharedArea:
    return SharedArea.attach(rt.data_name, controller_layouts(len(rt.config.axis_names)))


def _token(rt: Runtime, name: str):
    session = open_client(rt.zenoh_connect, rt.zenoh_credentials)
    keys = Keys(rt.config.zenoh.key_prefix, rt.config.machine.name)
    return session, session.liveliness().declare_token(keys.alive(name))


def run_hardware(rt: Runtime, ready) -> None:
    from ..hw.clock import make_clock
    from ..hw.server import HardwareServer, make_board

    child_setup(rt, "hardware")
    step_aside_for_wall_time(rt.clock)  # before its threads start: they inherit it
    area = _attach(rt)
    board = make_board(rt.config)
    running: list = []  # the server, once it exists (the handler may come before, or during the end)

    def terminated(signum, frame) -> None:
        board.safe_state()  # first the outputs: speed 0, drives off, jet closed; then anything else
        for server in running:
            server.terminate()
        log.error("hardware server: terminated (signal %d): the board is in its safe state", signum)
        raise SystemExit(0)
    signal.signal(signal.SIGTERM, terminated)
    session, token = _token(rt, "hardware")
    clock = make_clock(rt.clock, rt.config.timing.period_s)
    kind = ClockKind.VIRTUAL
    if rt.clock == "realtime":
        status = enter_realtime(realtime_priority(rt.config, "hardware"), "hardware server")
        kind = ClockKind.REALTIME if status.granted else ClockKind.REALTIME_FALLBACK
    server = HardwareServer(rt.config, area, board, clock, list(rt.timer_clients.values()), kind)
    running.append(server)
    keep_gc_out()
    set_ready(ready)
    try:
        server.run()
    finally:
        board.close()
        token.undeclare()
        session.close()
        running.clear()
        del server  # its numpy views of the segment must go before the segment is closed
        area.close()


def run_servo(rt: Runtime, ready) -> None:
    from ..servo import Servo

    child_setup(rt, "servo")
    step_aside_for_wall_time(rt.clock)  # before its threads start: they inherit it
    area = _attach(rt)
    fifo = SetpointFifo.attach(rt.fifo_name)
    trace = TraceRing.attach(rt.trace_name) if rt.trace_name else None
    session, token = _token(rt, "servo")
    servo = Servo(rt.config, area, fifo, record_latency=rt.clock == "realtime", trace=trace)
    timer = rt.timer_clients["servo"]
    shutdown = area.blocks["supervisor"].array["shutdown"]
    stall = servo_stall(area, rt.config)  # fault injection, on the simulated board only
    my_bit = 1 << Proc.SERVO
    if rt.clock == "realtime":
        enter_realtime(realtime_priority(rt.config, "servo"), "servo")
    keep_gc_out()
    set_ready(ready)
    try:
        while True:
            woke = timer.wait_tick(0.25)
            if shutdown[0] & my_bit:  # read once a tick, after the wait: the supervisor's stop wakes it too
                break
            if woke:
                while timer.wake.acquire(False):
                    pass  # ticks missed while late: run once on the newest, the tick counter counts the overrun
                if stall is not None and stall.sit_out():
                    continue  # injected: this tick is neither run nor finished, as if the host were late
                servo.tick()
                timer.tick_done()
    finally:
        token.undeclare()
        session.close()
        servo.close()
        del servo, shutdown
        if trace is not None:
            trace.close()
        fifo.close()
        area.close()


def run_planner(rt: Runtime, ready) -> None:
    import gc
    import sys

    from ..planner.process import Planner

    child_setup(rt, "planner")
    step_aside_for_wall_time(rt.clock)  # before its threads start: they inherit it
    area = _attach(rt)
    fifo = SetpointFifo.attach(rt.fifo_name)
    session = open_client(rt.zenoh_connect, rt.zenoh_credentials)
    planner = Planner(rt.config, area, fifo, session, rt.timer_clients["planner"])
    if rt.clock == "realtime":
        # below the servo, above the rest: setpoints must be there when the servo needs them
        enter_realtime(realtime_priority(rt.config, "planner"), "planner")
    gc.collect()
    gc.freeze()  # the planner allocates freely (numpy); collections stay short, the FIFO covers them
    sys.setswitchinterval(0.001)  # the refills get the interpreter within 1 ms of the planning thread
    set_ready(ready)
    try:
        planner.run()
    finally:
        planner.close()
        session.close()
        del planner
        fifo.close()
        area.close()


def program_dir(config, history_path: str) -> str:
    """`[gateway] program_dir` beside the machine file, or `programs/` beside the alarm history."""
    from ..config import beside

    if not config.gateway.program_dir:
        return str(Path(history_path).parent / "programs") if history_path else ""
    return str(beside(config, config.gateway.program_dir))


def run_gateway(rt: Runtime, ready) -> None:
    from ..gateway.process import Gateway

    child_setup(rt, "gateway")
    area = _attach(rt)
    fifo = SetpointFifo.attach(rt.fifo_name)
    session = open_client(rt.zenoh_connect, rt.zenoh_credentials)
    gateway = Gateway(rt.config, area, fifo, session, rt.clock, rt.history_path, program_dir(rt.config, rt.history_path))
    set_ready(ready)
    try:
        gateway.run()
    finally:
        gateway.close()
        session.close()
        del gateway
        fifo.close()
        area.close()


def run_logic(rt: Runtime, ready) -> None:
    from ..logic.process import Logic

    child_setup(rt, "logic")
    step_aside_for_wall_time(rt.clock)  # before its threads start: they inherit it
    area = _attach(rt)
    session = open_client(rt.zenoh_connect, rt.zenoh_credentials)
    logic = Logic(rt.config, area, session, rt.timer_clients["logic"], rt.history_path)
    if rt.clock == "realtime":
        # below the planner: the soft-PLC's 4 ms scan has slack, the FIFO refills have less
        enter_realtime(realtime_priority(rt.config, "logic"), "logic")
    import gc

    gc.collect()
    gc.freeze()  # collections stay short; the logic is not on the servo path and may allocate freely
    set_ready(ready)
    try:
        logic.run()
    finally:
        logic.close()
        session.close()
        del logic
        area.close()


def run_logger(rt: Runtime, ready) -> None:
    from ..logger.process import Logger

    child_setup(rt, "logger")
    os.nice(10)  # off the servo's path: everything else on the controller goes first
    area = _attach(rt)
    trace = TraceRing.attach(rt.trace_name)
    session = open_client(rt.zenoh_connect, rt.zenoh_credentials)
    runs_dir = Path(rt.history_path).parent / "runs" if rt.history_path else Path(rt.config.source).parent / "runs"
    logger = Logger(rt.config, area, trace, session, rt.timer_clients["logger"], runs_dir)
    set_ready(ready)
    try:
        logger.run()
    finally:
        logger.close()
        session.close()
        del logger
        trace.close()
        area.close()
