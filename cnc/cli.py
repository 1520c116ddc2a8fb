"""The `waterjet` command: one console script, one subcommand per tool."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from .config import DEFAULT_MACHINE, ConfigError, load_machine


def _machine_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--machine", "-m", default=DEFAULT_MACHINE, help=f"machine file (default {DEFAULT_MACHINE})")


def _cmd_up(args: argparse.Namespace) -> int:
    from .runtime.supervisor import Supervisor, SupervisorError

    config = load_machine(args.machine, {"zenoh.listen": args.listen} if args.listen else None)
    stop = {"requested": False}

    def on_signal(signum: int, _frame: object) -> None:
        logging.getLogger("waterjet").info("%s: stopping", signal.Signals(signum).name)
        stop["requested"] = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    sup = Supervisor(config, clock=args.clock)
    try:
        sup.start()
    except SupervisorError as exc:
        print(f"waterjet up: {exc}", file=sys.stderr)
        return 1
    print(
        f"waterjet up: machine {config.machine.name!r} running on the {args.clock} clock; "
        f"Zenoh at {', '.join(sup.access.network)}, status on {sup.keys.status}",
        flush=True,
    )
    print(f"waterjet up: {sup.access.notice}", flush=True)
    try:
        status = sup.run(lambda: stop["requested"])
    finally:
        sup.stop()
    if sup.failed:
        print(f"waterjet up: {sup.failed}", file=sys.stderr)
    return status


def _cmd_demo(args: argparse.Namespace) -> int:
    from .sim.demo import run_demo

    return run_demo(args.machine, clock=args.clock)


def _cmd_check(args: argparse.Namespace) -> int:
    from .check import check_program

    config = load_machine(args.machine)
    return check_program(args.program, config, args.tool_table, args.segments, sys.stdout, sys.stderr)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .sim.simulate import run_cli

    logging.getLogger("cnc").setLevel(logging.WARNING)  # the figures are the output
    return run_cli(args.program, args.machine, args.json, args.plot, sys.stdout, sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="waterjet", description="Waterjet CNC controller")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    up = sub.add_parser("up", help="start the controller processes and supervise them until SIGINT/SIGTERM")
    _machine_arg(up)
    up.add_argument("--clock", choices=("realtime", "virtual"), default="realtime", help="base-tick clock (default realtime)")
    up.add_argument("--listen", action="append", metavar="ENDPOINT", help="Zenoh endpoint to listen on (overrides the machine file; repeatable)")
    up.set_defaults(func=_cmd_up)

    check = sub.add_parser("check", help="validate a G-code program and summarise it (exit 0 valid, 1 not)")
    check.add_argument("program", help="G-code file")
    _machine_arg(check)
    check.add_argument("--tool-table", metavar="FILE.tbl", help="LinuxCNC-format tool table; overrides the machine's nozzle table")
    check.add_argument("--segments", metavar="OUT.jsonl", help="write every motion and dwell as one JSON object per line")
    check.set_defaults(func=_cmd_check)

    simulate = sub.add_parser(
        "simulate", help="run a program on the controller processes on the virtual clock; report cycle time, deviation, tracking"
    )
    simulate.add_argument("program", help="G-code file")
    _machine_arg(simulate)
    simulate.add_argument("--json", metavar="OUT", help="write the figures as JSON")
    simulate.add_argument("--plot", metavar="OUT.png", help="draw the XY contour and per-axis tracking (the paper's Figs. 10-12)")
    simulate.set_defaults(func=_cmd_simulate)

    plc_sim = sub.add_parser("plc-sim", help="the simulated external PLC (transport system, pump) as a Modbus RTU server")
    from plc_link import sim_cli

    sim_cli.add_arguments(plc_sim)
    plc_sim.set_defaults(func=sim_cli.run)

    router_p = sub.add_parser("router", help="a Zenoh router for a shop network (controllers and HMIs connect to it)")
    from . import router

    router.add_arguments(router_p)
    router_p.set_defaults(func=router.run)

    users_p = sub.add_parser("users", help="the machine's accounts: add, remove, list (who may log in, in which role)")
    from . import userscli

    userscli.add_arguments(users_p)
    users_p.set_defaults(func=userscli.run)

    certs_p = sub.add_parser("certs", help="the machine's TLS certificates: its CA, the routers', the stations'")
    from . import certscli

    certscli.add_arguments(certs_p)
    certs_p.set_defaults(func=certscli.run)

    watch_p = sub.add_parser("watch", help="observe a running controller: live status, alarms and procedures (read-only)")
    from . import watch

    watch.add_arguments(watch_p)
    watch_p.set_defaults(func=watch.run)

    log_p = sub.add_parser("log", help="the data logger: list, start and stop log runs, export one to MATLAB or CSV")
    from .logger import logcli

    logcli.add_arguments(log_p)
    log_p.set_defaults(func=logcli.run)

    hmi_p = sub.add_parser("hmi", help="the operator screen (Qt): connects to a controller over Zenoh")
    from hmi import app as hmi_app

    hmi_app.add_arguments(hmi_p)
    hmi_p.set_defaults(func=hmi_app.run)

    demo = sub.add_parser("demo", help="run the simulated machine end to end and exit 0 when it behaved")
    _machine_arg(demo)
    demo.add_argument("--clock", choices=("realtime", "virtual"), default="realtime")
    demo.set_defaults(func=_cmd_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    if hasattr(args, "machine") and not Path(args.machine).exists() and args.machine == DEFAULT_MACHINE:
        here = Path(__file__).resolve().parent.parent / DEFAULT_MACHINE
        if here.exists():
            args.machine = str(here)
    try:
        return args.func(args)
    except ConfigError as exc:
        print(f"waterjet {args.command}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
