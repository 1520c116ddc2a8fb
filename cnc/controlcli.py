"""`waterjet control`: the machine's control programs from a shell (`cnc.control`).

    waterjet control                              the programs: the machine's (*), the shipped ones
    waterjet control check cross_coupled          build it and run it on the simulated plant
    waterjet control check my_law.py:MyLaw --trajectory fig10
    waterjet control select friction_ff           check it, then name it in the machine file

`check` builds the program (its module, its class, its registrations, `[control.parameters]`)
and runs it for `[control] check_periods` periods (at least the trajectory's own length) on the
simulated plant, beside the PI-P on the same trajectory: its following and contour errors, and
its computation time per period against its budget (QMotor 2.0's control benchmark). `select`
does the same, then writes `[control] program` into the machine file (checked as a machine file
before it replaces it; the old one is kept as `.bak`); the controller runs it from its next start.
"""

from __future__ import annotations

import argparse
import sys

from .config import DEFAULT_MACHINE, ConfigError, machine_for_command
from .control.loader import SHIPPED, build
from .control.pip import PIP
from .control.program import ControlProgram, ControlProgramError
from .control.trial import TRAJECTORIES, TrialResult, run as run_trial
from .params import check_literals, save_literals, toml_string


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--machine", default=DEFAULT_MACHINE, help="machine file")
    sub = parser.add_subparsers(dest="action")
    sub.add_parser("list", help="the control programs, their parameters and log variables (the default)")
    for name, text in (("check", "build a program and run it on the simulated plant beside the PI-P"),
                       ("select", "check a program, then make it the machine's (from the controller's next start)")):
        p = sub.add_parser(name, help=text)
        p.add_argument("program", help="a shipped name, 'package.module:Class' or 'file.py:Class' beside the machine file")
        p.add_argument("--trajectory", choices=TRAJECTORIES, default="circle", help="what it follows (default circle)")


def run(args: argparse.Namespace) -> int:
    """0 done, 1 the program is refused (it does not build, or fails on the plant), 2 a bad machine file."""
    config = machine_for_command(args.machine, "control")
    if config is None:
        return 2
    action = args.action or "list"
    if action == "list":
        return _list(config)
    try:
        program = build(config, args.program)
    except ControlProgramError as exc:
        print(f"waterjet control: {exc}", file=sys.stderr)
        return 1
    change = {(("control",), "program"): toml_string(args.program)}
    if action == "select":
        try:  # the machine file as it would be (its parameters for this program) before the plant
            check_literals(config.source, change)
        except ConfigError as exc:
            print(f"waterjet control: {exc}", file=sys.stderr)
            return 1
    result = _check(config, program, args.program, args.trajectory)
    if result is None:
        return 1
    if action == "select":
        try:
            save_literals(config.source, change)
        except ConfigError as exc:
            print(f"waterjet control: {exc}", file=sys.stderr)
            return 1
        print(f"{config.source}: [control] program = {args.program!r}; the controller runs it from its next start")
    return 0


def _list(config) -> int:  # noqa: ANN001 - a MachineConfig
    names = dict.fromkeys([config.control.program, *SHIPPED])
    for name in names:
        try:
            program = build(config, name)
        except ControlProgramError as exc:
            print(f"{'*' if name == config.control.program else ' '} {name}: cannot be built: {exc}")
            continue
        mark = "*" if name == config.control.program else " "
        print(f"{mark} {name}  ({type(program).__name__}): {type(program).description or type(program).__doc__ or ''}")
        for p in program.parameters:
            value = ", ".join(f"{v:g}" for v in getattr(program, p.name)) if p.per_axis else f"{getattr(program, p.name):g}"
            where = f"[axis.<a>] {p.option}" if p.option else ("per axis" if p.per_axis else "")
            print(f"      parameter {p.name} = {value} {p.unit}  ({p.lo:g} to {p.hi:g}{'; ' + where if where else ''})"
                  f"  {p.doc}")
        for log in program.log_variables:
            print(f"      log {', '.join(log.names(config.axis_names))} [{log.unit}]  {log.doc}")
    print(f"(* the machine's: {config.source} [control] program; budget {config.control.budget_share:g} of the "
          f"{config.timing.period_s * 1e3:g} ms period)")
    return 0


def _check(config, program: ControlProgram, name: str, kind: str) -> TrialResult | None:  # noqa: ANN001
    """Run `program` and the PI-P on the plant; print both; None when the program failed there."""
    budget_ns = config.control.budget_share * config.timing.period_s * 1e9
    periods = config.control.check_periods
    duration = periods * config.timing.period_s
    result = run_trial(program, config, kind, duration, budget_ns=budget_ns)
    if result.failure:
        print(f"waterjet control: {name} ({type(program).__name__}) {result.failure} (period {result.failed_at} of "
              f"the {kind} trajectory on the simulated plant)", file=sys.stderr)
        return None
    peer = run_trial(PIP(config), config, kind, duration)
    mine, theirs = result.summary(), peer.summary()
    print(f"{name} ({type(program).__name__}) on the simulated plant, {kind}, {result.periods} periods: ok")
    print(f"{'figure':34} {'value':>10} {'PI-P':>10} {'ratio':>7}")
    for key, label in (("max_following_error_mm", "max following error (um)"),
                       ("rms_following_error_mm", "RMS following error (um)"),
                       ("max_contour_error_mm", "max contour error (um)"),
                       ("rms_contour_error_mm", "RMS contour error (um)")):
        a, b = mine[key] * 1e3, theirs[key] * 1e3
        print(f"{label:34} {a:10.2f} {b:10.2f} {(a / b if b else float('nan')):7.3f}")
    for key, label in (("control_p50_us", "computation p50 (us)"), ("control_p99_us", "computation p99 (us)"),
                       ("control_max_us", "computation max (us)")):
        print(f"{label:34} {mine[key]:10.1f} {theirs[key]:10.1f} {mine[key] / max(theirs[key], 1e-9):7.3f}")
    print(f"{'budget (us)':34} {budget_ns / 1000:10.1f}")
    return result
