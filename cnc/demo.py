"""`waterjet demo`: the simulated machine end to end, headless.

Starts the controller on the simulated board and a separate subscriber process that prints
the status it receives over Zenoh; enables the drives, homes the machine through the
planner, loads a small nest of leather parts (pierces, contours with arcs, lead-ins, a CAM
polyline), runs it with the jet switched in step with the motion, and checks that it ended
where the program ends, without servo fault, FIFO underrun or lost status; then shuts down
and checks that no shared memory is left behind.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import socket
import sys
import tempfile
import time
from pathlib import Path

from .bus.keys import Keys
from .bus.messages import Home, LoadProgram, Start, Status, decode
from .bus.session import open_client
from .config import load_machine
from .layout import PlannerState, RunResult, ServoState
from .supervisor import Supervisor, SupervisorError

POSITION_TOLERANCE_MM = 0.005


def demo_program() -> str:
    """Two leather parts and a polyline strap, cut with pierces and lead-ins, then park."""
    strap = "\n".join(
        f"G1 X{600 + 2.0 * k:.3f} Y{400 + 30.0 * math.sin(k / 8.0):.3f}" for k in range(1, 101)
    )
    return f"""(waterjet demo: two parts and a strap)
G21 G90 G17
G64 P0.05
F6000
G0 X210 Y150
M3                               (pierce)
G1 X220 Y150                     (lead-in)
G1 X380 Y150
G3 X400 Y170 R20
G1 X400 Y280
G3 X380 Y300 R20
G1 X220 Y300
G3 X200 Y280 R20
G1 X200 Y170
G3 X220 Y150 R20
M5
G0 X480 Y200
M3
G2 X480 Y200 I40 J0              (a round part)
M5
G0 X600 Y400
M3
{strap}
M5
G0 X50 Y50
M2
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def print_status(endpoint: str, prefix: str, machine: str, stop, ready, counter) -> None:
    """Subscriber process: print about one status message a second received over Zenoh."""
    import threading

    session = open_client([endpoint])
    got_one = threading.Event()

    def on_status(sample) -> None:
        st: Status = decode(sample.payload.to_bytes(), Status)
        with counter.get_lock():
            counter.value += 1
            n = counter.value
        got_one.set()
        if n % 20 == 1:
            pos = "  ".join(f"{a.name.upper()} {a.position_mm:8.2f}" for a in st.axes)
            prog = st.program
            where = f"line {prog.line:4d} {100 * prog.progress:5.1f}% ETA {prog.eta_s:5.1f}s" if prog and prog.segment >= 0 else ""
            print(
                f"[subscriber] #{st.seq:<4} {st.planner_state:<8} {pos}  F {st.feed_commanded_mm_s:6.1f} mm/s"
                f"  jet {'ON ' if st.jet_on else 'off'} {where}",
                flush=True,
            )

    sub = session.declare_subscriber(Keys(prefix, machine).status, on_status)
    if got_one.wait(15.0):
        ready.set()
    stop.wait(300.0)
    sub.undeclare()
    session.close()


def run_demo(machine_path: str, clock: str = "realtime") -> int:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    config = load_machine(machine_path, {"zenoh.listen": [endpoint]})
    ctx = multiprocessing.get_context("spawn")
    stop, ready, counter = ctx.Event(), ctx.Event(), ctx.Value("q", 0)
    print(f"demo: controller for {config.machine.name!r} on the {clock} clock, Zenoh at {endpoint}", flush=True)
    errors: list[str] = []
    names: set[str] = set()
    sup = Supervisor(config, clock=clock)
    with tempfile.TemporaryDirectory() as tmp:
        program = Path(tmp) / "demo_nest.ngc"
        program.write_text(demo_program())
        try:
            sup.start()
            names = {sup.area.shm.name, sup.fifo.shm.name, sup.trace.shm.name}
            subscriber = ctx.Process(
                target=print_status, args=(endpoint, config.zenoh.key_prefix, config.machine.name, stop, ready, counter)
            )
            subscriber.start()
            if not ready.wait(20.0):
                errors.append("the subscriber process received no status over Zenoh")
            errors += _run(sup, program)
            stop.set()
            subscriber.join(10.0)
            print(f"demo: the subscriber process received {counter.value} status messages over Zenoh", flush=True)
            if counter.value == 0:
                errors.append("no status message reached the subscriber")
        except (SupervisorError, TimeoutError) as exc:
            errors.append(str(exc))
        finally:
            stop.set()
            sup.stop()
    left = [n for n in names if os.path.exists(f"/dev/shm/{n}")]
    if left:
        errors.append(f"shared memory left behind: {', '.join(left)}")
    for e in errors:
        print(f"demo: FAILED: {e}", file=sys.stderr)
    if not errors:
        print("demo: OK: homed, the nest cut to its end, status seen over Zenoh, shared memory freed", flush=True)
    return 1 if errors else 0


def _run(sup: Supervisor, program: Path) -> list[str]:
    """Enable, home, load, start; wait for the end; what went wrong."""
    sup.enable()
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 5.0, "the servo to close the loop")
    for what, command in (("home", Home()), ("load", LoadProgram(str(program)))):
        reply = sup.planner.request(command)
        if not reply.ok:
            return [f"{what} refused: {reply.reason}"]
        sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE, 120.0, f"the planner to {what}")
        if sup.motion()["error"]:
            return [f"{what}: {sup.motion()['error']}"]
        if what == "home":
            print(f"demo: homed; X {sup.servo()['actual_mm'][0]:.3f} Y {sup.servo()['actual_mm'][1]:.3f}", flush=True)
    m = sup.motion()
    print(f"demo: loaded {m['program_name']}: {m['program_lines']} lines, {m['total_mm']:.0f} mm of path, "
          f"planned cycle time {m['planned_s']:.2f} s", flush=True)
    start = time.monotonic()
    reply = sup.planner.request(Start())
    if not reply.ok:
        return [f"start refused: {reply.reason}"]
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE, 300.0, "the program to end")
    m, s = sup.motion(), sup.servo()
    took = (m["run_end_tick"] - m["run_start_tick"]) * sup.config.timing.period_s
    print(
        f"demo: program ended ({RunResult(m['run_result']).name}) after {took:.2f} s machine time "
        f"({time.monotonic() - start:.1f} s wall); max following error "
        f"{max(s['max_following_error_mm']) * 1000:.1f} um; underruns {s['underruns']}, overruns {s['overruns']}; "
        f"lowest FIFO fill {m['fifo_min_fill']}",
        flush=True,
    )
    errors = []
    if m["run_result"] != RunResult.DONE:
        errors.append(f"the program did not run to its end: {RunResult(m['run_result']).name} {m['error']}")
    if s["fault"]:
        errors.append(f"servo fault {s['fault']}")
    if s["underruns"]:
        errors.append(f"{s['underruns']} FIFO underruns")
    sup.wait_until(lambda: all(abs(p - 50.0) <= POSITION_TOLERANCE_MM for p in sup.servo()["actual_mm"]), 5.0,
                   "the table to settle at the program's end X50 Y50")
    return errors
