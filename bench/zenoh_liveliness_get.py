#!/usr/bin/env python3
"""How often a Zenoh liveliness query misses a token that is there, and what it takes.

The gateway's session has a liveliness subscriber with history on the operator stations' tokens
and, beside it, queries in flight (the lock holder's ping). CI once refused a station the lock:
the gateway had asked Zenoh for the station's token (a liveliness query) and got nothing, though
the token was declared all along. This bench reproduces it without the controller: a router, a
station client that declares a token, and a gateway-like client that asks
for that token N times, with or without a liveliness subscriber with history on its session and
a thread running queries beside it (pings that nobody answers, as a silent station's). A miss is a query that ends without the token.

The gateway no longer depends on such a query (`cnc.gateway.lock`: a silent station is kept; a
fresh token is waited for at the subscriber; `ParamDoor._alive` reads the heartbeat pid).

    .venv/bin/python bench/zenoh_liveliness_get.py [--queries 20000] [--json OUT]
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import zenoh  # noqa: E402

from cnc.bus.session import zenoh_config  # noqa: E402
from cnc.sim.demo import free_port  # noqa: E402

TOKEN = "bench/hmi/local/panel/s1"
PING = "bench/ping/local/panel/s1"  # nobody answers it: a silent station's ping, ended at once by the router

# (name, liveliness subscriber with history on the asking session, queries in flight beside, serialised)
VARIANTS = (
    ("query alone", False, False, False),
    ("beside queries in flight", False, True, False),
    ("beside a history subscriber", True, False, False),
    ("subscriber and queries in flight", True, True, False),
    ("both, queries serialised", True, True, True),
)


def run(queries: int, subscriber: bool, beside: bool, serialised: bool) -> dict:
    """Ask for the token `queries` times; count the misses and the subscriber's samples."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(zenoh_config("router", listen=[endpoint]))
    station = zenoh.open(zenoh_config("client", connect=[endpoint]))
    asker = zenoh.open(zenoh_config("client", connect=[endpoint]))
    token = station.liveliness().declare_token(TOKEN)
    samples: list[str] = []
    arrived = threading.Event()

    def on_token(sample) -> None:
        samples.append(str(sample.kind))
        arrived.set()

    sub = asker.liveliness().declare_subscriber("bench/hmi/**", on_token, history=True) if subscriber else None
    if sub is not None:
        arrived.wait(10.0)
    else:  # the token has reached the router once a query finds it
        while not any(r.ok is not None for r in asker.liveliness().get(TOKEN, timeout=1.0)):
            time.sleep(0.01)
    one_at_a_time = threading.Lock() if serialised else None
    stop = threading.Event()

    def pinger() -> None:
        while not stop.is_set():
            if one_at_a_time is not None:
                with one_at_a_time:
                    list(asker.get(PING, timeout=0.2))
            else:
                list(asker.get(PING, timeout=0.2))

    thread = threading.Thread(target=pinger, daemon=True) if beside else None
    if thread is not None:
        thread.start()
    misses, worst = 0, 0.0
    t0 = time.perf_counter()
    for _ in range(queries):
        if one_at_a_time is not None:
            one_at_a_time.acquire()
        t = time.perf_counter()
        found = sum(1 for r in asker.liveliness().get(TOKEN, timeout=1.0) if r.ok is not None)
        worst = max(worst, time.perf_counter() - t)
        if one_at_a_time is not None:
            one_at_a_time.release()
        misses += found == 0
    elapsed = time.perf_counter() - t0
    stop.set()
    if thread is not None:
        thread.join()
    if sub is not None:
        sub.undeclare()
    token.undeclare()
    for session in (asker, station, router):
        session.close()
    return {"queries": queries, "misses": misses, "worst_ms": worst * 1e3, "mean_ms": elapsed / queries * 1e3,
            "subscriber_samples": len(samples)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--queries", type=int, default=20000, help="liveliness queries per variant")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    rows = {}
    print(f"eclipse-zenoh {importlib.metadata.version('eclipse-zenoh')}: a liveliness query for a declared token, "
          f"{args.queries} times per variant")
    print(f"{'variant':36} {'misses':>7} {'per 1000':>9} {'mean ms':>8} {'worst ms':>9} {'sub samples':>12}")
    for name, subscriber, beside, serialised in VARIANTS:
        r = run(args.queries, subscriber, beside, serialised)
        rows[name] = r
        print(f"{name:36} {r['misses']:7d} {r['misses'] / r['queries'] * 1e3:9.2f} {r['mean_ms']:8.2f} "
              f"{r['worst_ms']:9.2f} {r['subscriber_samples']:12d}")
    print("(sub samples: what the history subscriber received; 1 is the token's declaration, more are query "
          "answers it was handed)")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
