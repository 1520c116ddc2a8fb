"""`waterjet router`: a Zenoh router for the shop network that stations and controllers meet at."""

from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
import threading

import zenoh

from .bus.access import open_machine_router, plan_access
from .bus.session import open_router
from .config import ConfigError, MachineConfig, load_machine

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `waterjet router` (the CLI adds the subcommand and `set_defaults(func=run)`)."""
    parser.add_argument(
        "--listen", action="append", metavar="ENDPOINT",
        help=f"endpoint to listen on (repeatable; default {DEFAULT_LISTEN})",
    )
    parser.add_argument("--connect", action="append", metavar="ENDPOINT", help="router to connect to (repeatable)")
    parser.add_argument(
        "--machine", "-m", metavar="FILE",
        help="log stations in with this machine's accounts and apply its rules (the machine's shop router)",
    )


def run(args: argparse.Namespace) -> int:
    """Run the router until SIGINT/SIGTERM; 0 on a clean stop, 1 if Zenoh cannot open it."""
    listen = args.listen or [DEFAULT_LISTEN]
    cfg = _shop_config(load_machine(args.machine), listen, args.connect or []) if args.machine else None
    plan = plan_access(cfg, shop=True) if cfg is not None else None  # ConfigError when it has no accounts
    try:
        session = open_machine_router(cfg, plan, shop=True) if cfg is not None else open_router(listen, args.connect or [])
    except zenoh.ZError as exc:
        print(f"waterjet router: {exc}", file=sys.stderr)
        return 1
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda _signum, _frame: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        access = (f"access control of machine {cfg.machine.name!r} ({len(plan.accounts)} accounts)" if plan
                  else "no access control")
        print(f"waterjet router: {session.zid()} listening on {', '.join(listen)}; {access}", flush=True)
        if args.connect:
            print(f"waterjet router: connecting to {', '.join(args.connect)}", flush=True)
        while not stop.wait(1.0):  # a bounded wait keeps the main thread responsive to signals
            pass
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        session.close()
    print("waterjet router: stopped", flush=True)
    return 0


def _shop_config(cfg: MachineConfig, listen: list[str], connect: list[str]) -> MachineConfig:
    """The machine's config with the shop router's endpoints in place of the controller's."""
    return dataclasses.replace(cfg, zenoh=dataclasses.replace(cfg.zenoh, listen=listen, connect=connect))



def main(argv: list[str] | None = None) -> int:
    """`python -m cnc.router`: the same command before (or without) the `waterjet` CLI."""
    parser = argparse.ArgumentParser(prog="waterjet router", description=__doc__)
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run(args)
    except ConfigError as exc:
        print(f"waterjet router: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
