#!/usr/bin/env python3
"""How long the controller takes to start, to stop, and to bring back a lost process.

The supervisor forks its processes from a fork server that has imported what they need
(`cnc/runtime/table.py`, `process_context`). The peer, measured in the same run, is what it did
before: each process spawned afresh (a new interpreter and its imports). For each way, on the
virtual clock with the PLC simulator:

- start: `Supervisor.start()` of the whole controller, until the PLC link is up (what every
  `waterjet up` and every controller test pays);
- stop: `Supervisor.stop()`, in order, the shared memory freed;
- restart: from a kill -9 of the gateway (restart policy "always") to its replacement ready
  (the supervisor polled flat out meanwhile).

The first start of each way is not counted (the fork server's own start, the file caches).

    .venv/bin/python bench/startup.py [--runs 5] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import os
import signal
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.servo_timing import on_free_port  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.data.layout import LinkState  # noqa: E402
from cnc.runtime import supervisor as supervisor_module  # noqa: E402
from cnc.runtime.table import process_context  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
WAYS = {"fork server": process_context, "spawn (before)": lambda: multiprocessing.get_context("spawn")}


def one_run(machine: Path) -> dict[str, float]:
    """Start, restart the gateway once, stop: each wall time in seconds."""
    config = on_free_port(load_machine(machine))
    with tempfile.TemporaryDirectory(prefix="startup_bench_") as tmp:
        sup = supervisor_module.Supervisor(config, clock="virtual", history_path=Path(tmp) / "history.sqlite",
                                           log_level=logging.WARNING)
        t0 = time.perf_counter()
        sup.start()
        try:
            sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 30.0, "the PLC link")
            started = time.perf_counter() - t0
            lost = sup.children["gateway"].process.pid
            t0 = time.perf_counter()
            os.kill(lost, signal.SIGKILL)
            sup.wait_until(lambda: "gateway" in sup.children and sup.children["gateway"].process.pid != lost
                           and not sup.starting, 30.0, "the gateway back")
            restarted = time.perf_counter() - t0
        finally:
            t0 = time.perf_counter()
            sup.stop()
            stopped = time.perf_counter() - t0
    return {"start_s": started, "restart_s": restarted, "stop_s": stopped}


def measure(runs: int, machine: Path) -> dict[str, dict[str, float]]:
    out = {}
    for way, context in WAYS.items():
        supervisor_module.process_context = context  # what the supervisor starts its processes with
        one_run(machine)  # warm-up, not counted
        samples = [one_run(machine) for _ in range(runs)]
        out[way] = {key: statistics.median(s[key] for s in samples) for key in samples[0]}
    supervisor_module.process_context = process_context
    return out


def render(figures: dict[str, dict[str, float]], runs: int) -> str:
    ours, peer = figures["fork server"], figures["spawn (before)"]
    lines = [f"controller start, stop and restart, median of {runs} runs (virtual clock, PLC simulator)",
             f"{'figure':34s} {'fork server':>12s} {'spawn':>12s} {'ratio':>7s}"]
    for key, label in (("start_s", "start, to the PLC link up (s)"), ("restart_s", "gateway killed -> back (s)"),
                       ("stop_s", "stop, in order (s)")):
        lines.append(f"{label:34s} {ours[key]:12.3f} {peer[key]:12.3f} {ours[key] / peer[key]:7.2f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--machine", type=Path, default=REPO / "machines" / "waterjet.toml")
    ap.add_argument("--json", type=Path, metavar="OUT")
    args = ap.parse_args(argv)
    figures = measure(args.runs, args.machine)
    print(render(figures, args.runs))
    if args.json:
        args.json.write_text(json.dumps({"runs": args.runs, "figures": figures}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
