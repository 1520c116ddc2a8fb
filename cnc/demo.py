"""`waterjet demo`: the simulated machine end to end, headless.

Starts the controller on the simulated board, starts a separate subscriber process that
prints the status it receives over Zenoh, moves the table through a few points by feeding
setpoints into the FIFO, checks that every point was reached and that the subscriber saw
the motion, then shuts down and checks that no shared memory is left behind.
"""

from __future__ import annotations

import multiprocessing
import os
import socket
import sys
import time

from .bus.keys import Keys
from .bus.messages import Status, decode
from .bus.session import open_client
from .config import load_machine
from .ptp import move_setpoints
from .supervisor import Supervisor, SupervisorError
from .layout import ServoState

POINTS_MM = [(200.0, 150.0), (1400.0, 150.0), (1400.0, 1050.0), (200.0, 1050.0), (800.0, 600.0)]
POSITION_TOLERANCE_MM = 0.005


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def print_status(endpoint: str, prefix: str, machine: str, stop, ready, counter) -> None:
    """Subscriber process: print every 4th status message received over Zenoh."""
    import threading

    session = open_client([endpoint])
    got_one = threading.Event()

    def on_status(sample) -> None:
        st: Status = decode(sample.payload.to_bytes(), Status)
        with counter.get_lock():
            counter.value += 1
            n = counter.value
        got_one.set()
        if n % 4 == 1:
            pos = "  ".join(f"{a.name.upper()} {a.position_mm:9.3f}" for a in st.axes)
            fe = "  ".join(f"{a.following_error_mm * 1000:+7.1f}" for a in st.axes)
            print(
                f"[subscriber] status #{st.seq:<5} tick {st.tick:>7}  {st.servo_state:<8} {pos}  FE um {fe}"
                f"  fault {st.fault}",
                flush=True,
            )

    sub = session.declare_subscriber(Keys(prefix, machine).status, on_status)
    if got_one.wait(15.0):
        ready.set()
    stop.wait(120.0)
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
    sup = Supervisor(config, clock=clock)
    try:
        sup.start()
        names = {sup.area.shm.name, sup.fifo.shm.name}
        subscriber = ctx.Process(
            target=print_status, args=(endpoint, config.zenoh.key_prefix, config.machine.name, stop, ready, counter)
        )
        subscriber.start()
        if not ready.wait(20.0):
            errors.append("the subscriber process received no status over Zenoh")
        sup.enable()
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 5.0, "the servo to close the loop")
        for target in POINTS_MM:
            start = sup.servo()["commanded_mm"]
            setpoints = move_setpoints(config, start, target)
            print(f"demo: move to X {target[0]:g} Y {target[1]:g} ({len(setpoints)} setpoints)", flush=True)
            pushed = 0
            while pushed < len(setpoints):
                pushed += sup.fifo.push(setpoints[pushed:])
                sup.poll()
                time.sleep(0.02)
            sup.wait_motion_done(60.0)
            sup.wait_until(lambda: _settled(sup, target), 5.0, f"the table to settle at {target}")
            s = sup.servo()
            print(
                f"demo: reached X {s['actual_mm'][0]:.3f} Y {s['actual_mm'][1]:.3f}; "
                f"max following error {max(s['max_following_error_mm']) * 1000:.1f} um",
                flush=True,
            )
        s, h = sup.servo(), sup.hw()
        if s["fault"]:
            errors.append(f"servo fault {s['fault']}")
        print(
            f"demo: {h['tick']} ticks, overruns {s['overruns']}, underruns {s['underruns']}, "
            f"watchdog {'TRIPPED' if h['watchdog_tripped'] else 'ok'}",
            flush=True,
        )
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
    left = [n for n in names if os.path.exists(f"/dev/shm/{n}")] if "names" in locals() else []
    if left:
        errors.append(f"shared memory left behind: {', '.join(left)}")
    for e in errors:
        print(f"demo: FAILED: {e}", file=sys.stderr)
    if not errors:
        print("demo: OK: all points reached, status seen over Zenoh, shared memory freed", flush=True)
    return 1 if errors else 0


def _settled(sup: Supervisor, target: tuple[float, ...]) -> bool:
    actual = sup.servo()["actual_mm"]
    return all(abs(a - t) <= POSITION_TOLERANCE_MM for a, t in zip(actual, target))
