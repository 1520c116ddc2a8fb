#!/usr/bin/env python3
"""Bus latency benchmark: controller publication to subscriber reception, alone and among 20 observers.

Starts the whole controller (hardware server, servo, planner, PLC link with the PLC simulator,
control logic, gateway) on the real-time clock, then measures, in subscriber processes of their
own (multiprocessing spawn, each with its own Zenoh client session, as an HMI or `waterjet
watch` would be), how long after publication each message arrives:

- status (`<root>/status`, 20 Hz): from its `stamp_ns`, the wall clock when the gateway
  published it, to the wall clock in the subscriber's callback (same host, same clock);
- position (`<root>/position`, 50 Hz), the same way, when the controller publishes it;
- alarm events (`<root>/event/alarm`): the bench sends refused CycleStart commands (MANUAL mode:
  message 37 "Wrong operation mode") at ALARM_RATE_HZ; each is stored in the history before it is
  published, so the figure includes the history's write (with its fsync).

First one subscriber measures alone; then 20 observer sessions subscribe to status, position and
alarms (decoding every message, as a watcher does) and one of them measures. Over each window
the servo's tick-to-speed-command latency and overruns are read from the controller's own
histograms, to show whether the observers' load reaches the control loop. Each figure is printed
beside its unloaded (one-subscriber) peer and their ratio.

    .venv/bin/python bench/bus_latency.py [--seconds 20] [--observers 20] [--alarms 200] [--json OUT]

Exits 1 when the controller fails or a subscriber does not come up, never because figures are high.
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from servo_timing import Latency, on_free_port, summarize  # noqa: E402

from cnc.bus import messages  # noqa: E402
from cnc.bus.keys import Keys  # noqa: E402
from cnc.bus.messages import AlarmEvent, CycleStart, Status, decode  # noqa: E402
from cnc.bus.session import connect_endpoints, open_client  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.data.layout import ClockKind, LinkState  # noqa: E402
from cnc.runtime.supervisor import Supervisor, SupervisorError  # noqa: E402
from plc_link.sim_model import PlantTimes  # noqa: E402

DEFAULT_MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"
ALARM_RATE_HZ = 20.0
SETTLE_S = 2.0  # after start-up, and after the subscribers come up, before a window opens
SUBSCRIBER_START_TIMEOUT_S = 60.0  # 20 spawned interpreters on 2 cores take a while
RESULT_TIMEOUT_S = 30.0


class BenchError(RuntimeError):
    """The controller or a subscriber failed during the run."""


# -- the subscriber processes ------------------------------------------------------------------


def kinds_of(keys: Keys) -> dict[str, type]:
    """The streams measured and observed: status, alarm events, and position when the schema has it."""
    kinds: dict[str, type] = {keys.status: Status, keys.event_alarm: AlarmEvent}
    position = getattr(messages, "Position", None)
    if position is not None and "stamp_ns" in position.__struct_fields__:
        kinds[keys.position] = position
    return kinds


def subscriber_main(endpoints: list[str], prefix: str, machine: str, ready: Any, stop: Any, results: Any,
                    index: int) -> None:
    """One observer session in its own process: decode every message; record, per key, each
    message's publication stamp and the wall clock at its reception; report them at `stop`."""
    keys = Keys(prefix, machine)
    kinds = kinds_of(keys)
    received: dict[str, list[tuple[int, int]]] = {key: [] for key in kinds}

    def on_sample(key: str, kind: type, sample: Any) -> None:
        recv_ns = time.time_ns()  # first: decoding is part of the observer's work, not of the latency
        msg = decode(sample.payload.to_bytes(), kind)
        received[key].append((msg.stamp_ns, recv_ns))

    try:
        session = open_client(endpoints)
        subs = [session.declare_subscriber(key, lambda s, key=key, kind=kind: on_sample(key, kind, s))
                for key, kind in kinds.items()]
        deadline = time.monotonic() + SUBSCRIBER_START_TIMEOUT_S
        while not received[keys.status] and time.monotonic() < deadline:
            time.sleep(0.01)  # subscribed for real once the first status came through the router
        ready.set()
        stop.wait()
        for sub in subs:
            sub.undeclare()
        session.close()
        results.put((index, {key: list(v) for key, v in received.items()}, ""))
    except Exception as exc:  # reported to the bench, which fails naming it
        results.put((index, {}, f"{type(exc).__name__}: {exc}"))
        ready.set()


# -- one measurement window --------------------------------------------------------------------


@dataclass(frozen=True)
class StreamLatency:
    """Publication-to-reception latency of one stream in one window, in microseconds."""

    messages: int
    p50_us: float
    p99_us: float
    max_us: float


@dataclass(frozen=True)
class Window:
    sessions: int  # subscriber sessions open during the window (one of them measures)
    seconds: float
    streams: dict[str, StreamLatency | None]  # by stream name (status, position, alarm)
    alarms_sent: int
    servo: Latency
    overruns: int


def stream_latency(pairs: list[tuple[int, int]], t0_ns: int, t1_ns: int) -> StreamLatency | None:
    """Figures of the messages published within [t0_ns, t1_ns); None when there were none."""
    lat = np.array([recv - stamp for stamp, recv in pairs if t0_ns <= stamp < t1_ns], dtype=np.float64) / 1e3
    if lat.size == 0:
        return None
    return StreamLatency(int(lat.size), float(np.percentile(lat, 50)), float(np.percentile(lat, 99)), float(lat.max()))


def check_healthy(sup: Supervisor) -> None:
    sup.poll()
    if sup.failed:
        raise BenchError(sup.failed)


def start_subscribers(sup: Supervisor, n: int) -> tuple[list[Any], Any, Any]:
    """`n` subscriber processes, all subscribed and receiving; returns (processes, stop event, results)."""
    ctx = multiprocessing.get_context("spawn")
    stop, results = ctx.Event(), ctx.Queue()
    endpoints = connect_endpoints(sup.config.zenoh.listen)
    readies, procs = [], []
    for i in range(n):
        ready = ctx.Event()
        p = ctx.Process(target=subscriber_main, name=f"bus-latency-sub{i}",
                        args=(endpoints, sup.keys.prefix, sup.keys.machine, ready, stop, results, i))
        p.start()
        readies.append(ready)
        procs.append(p)
    deadline = time.monotonic() + SUBSCRIBER_START_TIMEOUT_S
    for i, ready in enumerate(readies):
        while not ready.wait(0.05):
            check_healthy(sup)
            if not procs[i].is_alive() or time.monotonic() > deadline:
                stop.set()
                raise BenchError(f"subscriber {i} did not come up within {SUBSCRIBER_START_TIMEOUT_S:g} s "
                                 f"(exit code {procs[i].exitcode})")
    return procs, stop, results


def stop_subscribers(procs: list[Any], stop: Any, results: Any) -> dict[int, dict[str, list[tuple[int, int]]]]:
    """Stop them and collect what each received; BenchError naming a subscriber that failed."""
    stop.set()
    collected: dict[int, dict[str, list[tuple[int, int]]]] = {}
    for _ in procs:
        index, received, error = results.get(timeout=RESULT_TIMEOUT_S)
        if error:
            raise BenchError(f"subscriber {index} failed: {error}")
        collected[index] = received
    for p in procs:
        p.join(10.0)
    return collected


def send_alarms(sup: Supervisor, count: int, until: float) -> int:
    """Refused CycleStart commands at ALARM_RATE_HZ until `count` are sent or the window ends."""
    sent, next_t = 0, time.monotonic()
    while sent < count and time.monotonic() < until:
        reply = sup.logic.request(CycleStart())
        if reply.ok:
            raise BenchError("a CycleStart was accepted: the machine must be in MANUAL for the refusals")
        sent += 1
        next_t += 1.0 / ALARM_RATE_HZ
        while (delay := next_t - time.monotonic()) > 0:
            check_healthy(sup)
            time.sleep(min(delay, 0.01))
    return sent


def measure(sup: Supervisor, sessions: int, seconds: float, alarms: int) -> Window:
    """Open `sessions` subscriber sessions, let them settle, then one window: alarms sent during
    it, status and position streaming; figures from subscriber 0 and the servo's histogram."""
    procs, stop, results = start_subscribers(sup, sessions)
    try:
        time.sleep(SETTLE_S)
        check_healthy(sup)
        hist0, overruns0 = sup.timing("servo_timing")["hist"], sup.servo()["overruns"]
        t0_ns, start = time.time_ns(), time.monotonic()
        sent = send_alarms(sup, alarms, start + seconds)
        while time.monotonic() < start + seconds:
            check_healthy(sup)
            time.sleep(0.05)
        t1_ns = time.time_ns()
        hist1, overruns1 = sup.timing("servo_timing")["hist"], sup.servo()["overruns"]
        time.sleep(0.5)  # the last messages of the window are on their way
    finally:
        collected = stop_subscribers(procs, stop, results)
    keys = sup.keys
    names = {keys.status: "status", keys.position: "position", keys.event_alarm: "alarm"}
    measured = collected[0]
    streams = {names[key]: stream_latency(pairs, t0_ns, t1_ns) for key, pairs in measured.items()}
    for index, received in collected.items():
        if not received[keys.status]:
            raise BenchError(f"subscriber {index} received no status at all")
    return Window(sessions, (t1_ns - t0_ns) / 1e9, streams, sent, summarize(hist1 - hist0), int(overruns1 - overruns0))


# -- report ------------------------------------------------------------------------------------


def _ratio(loaded: float, alone: float) -> str:
    return f"{loaded / alone:6.2f}" if alone > 0 else "     -"


def report(alone: Window, loaded: Window, clock: str) -> str:
    """The table: each figure of the loaded window beside its one-subscriber peer and the ratio."""
    head = f"{'':34s}{'1 subscriber':>14s}{f'{loaded.sessions} sessions':>14s}{'ratio':>8s}"
    lines = [f"bus latency, publication to reception (wall clock, same host), {alone.seconds:.0f} s windows, "
             f"{clock} clock", head]

    def row(label: str, a: float, b: float, fmt: str = "{:14.0f}") -> None:
        lines.append(f"{label:34s}{fmt.format(a)}{fmt.format(b)}{_ratio(b, a):>8s}")

    for name in ("status", "position", "alarm"):
        a, b = alone.streams.get(name), loaded.streams.get(name)
        if a is None or b is None:
            lines.append(f"{name:34s}{'not published':>14s}")
            continue
        what = f"{name} (incl. history write)" if name == "alarm" else name
        row(f"{what} p50 us", a.p50_us, b.p50_us)
        row(f"{'':{len(name)}s} p99 us", a.p99_us, b.p99_us)
        row(f"{'':{len(name)}s} max us", a.max_us, b.max_us)
        row(f"{'':{len(name)}s} messages", a.messages, b.messages)
    row("alarms sent (refused CycleStart)", alone.alarms_sent, loaded.alarms_sent)
    sa, sb = alone.servo, loaded.servo
    row("servo tick-to-speed-cmd p50 us", sa.p50_us, sb.p50_us)
    row("                        p99 us", sa.p99_us, sb.p99_us)
    row("                        p99.9 us", sa.p999_us, sb.p999_us)
    row("                        max us", sa.max_us, sb.max_us)
    row("servo overruns", alone.overruns, loaded.overruns)
    return "\n".join(lines)


def run(machine: str, seconds: float, observers: int, alarms: int) -> tuple[Window, Window, str]:
    config = on_free_port(load_machine(machine))
    with tempfile.TemporaryDirectory() as tmp:
        sup = Supervisor(config, clock="realtime", history_path=Path(tmp) / "history.sqlite", log_level=logging.WARNING,
                         plc_sim_times=PlantTimes(feed_s=1.0, gripper_s=0.3, unload_s=1.0))
        with sup:
            sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 30.0, "the PLC link")
            time.sleep(SETTLE_S)
            check_healthy(sup)
            alone = measure(sup, 1, seconds, alarms)
            loaded = measure(sup, observers, seconds, alarms)
            clock = ClockKind(sup.hw()["clock_kind"]).name.lower()
    return alone, loaded, clock


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(DEFAULT_MACHINE), help="machine file")
    parser.add_argument("--seconds", type=float, default=20.0, help="length of each measurement window (default 20)")
    parser.add_argument("--observers", type=int, default=20, help="subscriber sessions in the loaded window (default 20)")
    parser.add_argument("--alarms", type=int, default=200, help=f"alarm events per window, sent at {ALARM_RATE_HZ:g} Hz")
    parser.add_argument("--json", metavar="OUT", help="write the figures as JSON")
    args = parser.parse_args(argv)
    if args.observers < 1 or args.seconds <= 0:
        parser.error(f"--observers must be at least 1 and --seconds positive, got {args.observers} and {args.seconds:g}")
    logging.basicConfig(level=logging.WARNING, format="%(name)s %(levelname)s %(message)s")
    try:
        alone, loaded, clock = run(args.machine, args.seconds, args.observers, args.alarms)
    except (BenchError, SupervisorError, TimeoutError) as exc:
        print(f"bus_latency: {exc}", file=sys.stderr)
        return 1
    print(report(alone, loaded, clock))
    if args.json:
        Path(args.json).write_text(json.dumps({"clock": clock, "alone": asdict(alone), "loaded": asdict(loaded)}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
