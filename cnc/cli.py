"""The `waterjet` command: one console script, one subcommand per tool."""

from __future__ import annotations

import argparse
import importlib
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
    return check_program(args.program, config, args.tool_table, args.segments, sys.stdout, sys.stderr, args.json,
                         cut=_cut_setup(args))


def _cut_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("cutting job (cnc.cutmodel; default: the program's (MATERIAL, ...) comment, else its F)")
    g.add_argument("--material", metavar="ID", help="a material of the machine's library (waterjet materials)")
    g.add_argument("--thickness", type=float, metavar="MM", help="its thickness, mm")
    g.add_argument("--quality", type=int, choices=(1, 2, 3, 4, 5), help="edge quality, 1 (separation) to 5 (finest)")
    g.add_argument("--mode", choices=("quality", "feed"), default="quality",
                   help="quality: the model sets the speed, F is only an upper bound (default); feed: F as programmed")


def _cut_setup(args: argparse.Namespace):  # noqa: ANN202 - a CutSetup or None
    from .cutmodel import CutSetup

    if args.material is None:
        if args.thickness is not None or args.quality is not None:
            raise SystemExit("waterjet: --thickness and --quality need --material")
        return None
    if args.thickness is None or args.quality is None:
        raise SystemExit("waterjet: --material needs --thickness and --quality")
    return CutSetup(args.material, args.thickness, args.quality, args.mode)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .sim.simulate import run_cli

    logging.getLogger("cnc").setLevel(logging.WARNING)  # the figures are the output
    return run_cli(args.program, args.machine, args.json, args.plot, sys.stdout, sys.stderr, cut=_cut_setup(args))


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
    check.add_argument("--json", metavar="OUT", help="write the figures as JSON ('-': to stdout instead of the summary), "
                       "with the wall times of interpretation and planning")
    _cut_args(check)
    check.set_defaults(func=_cmd_check)

    simulate = sub.add_parser(
        "simulate", help="run a program on the controller processes on the virtual clock; report cycle time, deviation, tracking"
    )
    simulate.add_argument("program", help="G-code file")
    _machine_arg(simulate)
    simulate.add_argument("--json", metavar="OUT", help="write the figures as JSON")
    simulate.add_argument("--plot", metavar="OUT.png", help="draw the XY contour and per-axis tracking (the paper's Figs. 10-12)")
    _cut_args(simulate)
    simulate.set_defaults(func=_cmd_simulate)

    # commands whose module brings its own options and runner: name, help, module (imported here, lazily)
    for name, help_text, module_name in (
        ("plc-sim", "the simulated external PLC (transport system, pump) as a Modbus RTU server", "plc_link.sim_cli"),
        ("router", "a Zenoh router for a shop network (controllers and HMIs connect to it)", "cnc.router"),
        ("users", "the machine's accounts: add, remove, list (who may log in, in which role)", "cnc.userscli"),
        ("certs", "the machine's TLS certificates: its CA, the routers', the stations'", "cnc.certscli"),
        ("watch", "observe a running controller: live status, alarms and procedures (read-only)", "cnc.watch"),
        ("log", "the data logger: list, start and stop log runs, export one to MATLAB or CSV", "cnc.logger.logcli"),
        ("sim", "the simulated machine's inputs: list them, or change one (a door, the e-stop, the transport button...)",
         "cnc.simcli"),
        ("materials", "the material library: cut charts by thickness and quality, speed-ladder calibration",
         "cnc.materialscli"),
        ("control", "the axis control programs: list them, check one on the simulated plant, select one",
         "cnc.controlcli"),
        ("hmi", "the operator screen (Qt): connects to a controller over Zenoh", "hmi.app"),
    ):
        module = importlib.import_module(module_name)
        command = sub.add_parser(name, help=help_text)
        module.add_arguments(command)
        command.set_defaults(func=module.run)

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
