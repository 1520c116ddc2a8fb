#!/usr/bin/env python3
"""STOP's answer time while a large program is uploaded, interpreted and loaded (issue 18).

Starts the whole controller on the real-time clock. One operator station uploads a `--lines`
program (bench/gcode_speed.py's CAM polylines: the gateway checks and interprets it, then the
planner checks and plans it for the load); meanwhile a second session of the same station sends
STOP every `--period-ms` on the realtime lane and times each, from the query to its reply (wall
clock, the station's side). The same STOPs are timed on the idle controller first, as the peer.
Prints the percentiles of both, their ratio, the 50 ms target and the upload's own time.

    .venv/bin/python bench/stop_latency.py [--lines 1000000] [--period-ms 25] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.gcode_speed import million_line_program  # noqa: E402
from bench.servo_timing import on_free_port  # noqa: E402
from cnc.bus.keys import Keys  # noqa: E402
from cnc.bus.messages import Stop  # noqa: E402
from cnc.bus.operator import OperatorStation  # noqa: E402
from cnc.bus.session import open_client  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.data.layout import LinkState  # noqa: E402
from cnc.runtime.supervisor import Supervisor  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
TARGET_MS = 50.0
IDLE_STOPS = 200


def percentiles(samples: list[float]) -> dict[str, float]:
    s = sorted(samples)
    pick = lambda q: s[min(len(s) - 1, int(q * len(s)))]  # noqa: E731
    return {"n": len(s), "p50": pick(0.50), "p90": pick(0.90), "p99": pick(0.99), "max": s[-1]}


def stops(station: OperatorStation, until: threading.Event | None, count: int, period_s: float) -> list[float]:
    """Send STOP every `period_s` until `until` is set (or `count` times); each answer time in ms."""
    times: list[float] = []
    while (until is None and len(times) < count) or (until is not None and not until.is_set()):
        t0 = time.perf_counter()
        reply = station.request(Stop())
        times.append((time.perf_counter() - t0) * 1e3)
        if not reply.ok and "nothing to stop" not in reply.reason:
            raise RuntimeError(f"STOP refused: {reply.reason}")
        time.sleep(max(0.0, period_s - (time.perf_counter() - t0)))
    return times


def run(machine: str, lines: int, period_s: float) -> dict:
    text = million_line_program(lines)
    config = on_free_port(load_machine(machine))
    keys = Keys(config.zenoh.key_prefix, config.machine.name)
    with tempfile.TemporaryDirectory(prefix="stop_bench_") as tmp, \
            Supervisor(config, clock="realtime", history_path=Path(tmp) / "history.sqlite", log_level=logging.WARNING) as sup:
        sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 30.0, "the PLC link")
        endpoints = [ep.replace("0.0.0.0", "127.0.0.1") for ep in sup.access.network]
        loader_session, stopper_session = open_client(endpoints), open_client(endpoints)
        loader = OperatorStation(loader_session, keys, "bench", timeout_s=600.0)
        stopper = OperatorStation(stopper_session, keys, "bench", timeout_s=60.0)
        try:
            assert loader.take_lock().ok
            stopper.attachment = loader.attachment  # the same station: the one holding the lock
            idle = stops(stopper, None, IDLE_STOPS, period_s)
            done = threading.Event()
            outcome: dict = {}

            def load() -> None:
                t0 = time.perf_counter()
                outcome["reply"] = loader.upload("big.ngc", text)
                outcome["s"] = time.perf_counter() - t0
                done.set()

            thread = threading.Thread(target=load)
            thread.start()
            loaded = stops(stopper, done, 0, period_s)
            thread.join()
        finally:
            for s in (loader, stopper):
                s.close()
            loader_session.close()
            stopper_session.close()
    return {"lines": lines, "bytes": len(text), "idle": percentiles(idle), "loading": percentiles(loaded),
            "upload_s": outcome["s"], "upload_ok": outcome["reply"].ok, "upload_reason": outcome["reply"].reason}


def report(r: dict) -> list[str]:
    lines = [f"STOP answer time (ms, wall clock at the station) while a {r['lines']:,}-line program "
             f"({r['bytes'] / 1e6:.1f} MB) is uploaded, interpreted and loaded",
             f"{'':<34}{'n':>6}{'p50':>8}{'p90':>8}{'p99':>8}{'max':>8}"]
    for name in ("idle", "loading"):
        p = r[name]
        lines.append(f"{name:<34}{p['n']:>6}{p['p50']:>8.1f}{p['p90']:>8.1f}{p['p99']:>8.1f}{p['max']:>8.1f}")
    i, lo = r["idle"], r["loading"]
    lines.append(f"{'ratio loading / idle':<34}{'':>6}{lo['p50'] / i['p50']:>7.1f}x{lo['p90'] / i['p90']:>7.1f}x"
                 f"{lo['p99'] / i['p99']:>7.1f}x{lo['max'] / i['max']:>7.1f}x")
    lines.append(f"{'p99 against the 50 ms target':<34}{'':>6}{'':>8}{'':>8}{lo['p99'] / TARGET_MS:>7.2f}x")
    lines.append(f"upload + interpretation + load: {r['upload_s']:.1f} s, "
                 f"{'ok' if r['upload_ok'] else 'REFUSED: ' + r['upload_reason']}")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--lines", type=int, default=1_000_000)
    parser.add_argument("--period-ms", type=float, default=25.0, help="time between two STOPs (default 25)")
    parser.add_argument("--json", metavar="OUT")
    args = parser.parse_args(argv)
    r = run(args.machine, args.lines, args.period_ms / 1e3)
    print("\n".join(report(r)))
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1))
    return 0 if r["loading"]["p99"] <= TARGET_MS and r["upload_ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
