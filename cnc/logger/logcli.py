"""`waterjet log`: the data logger from a terminal: list runs, start and stop one, export it.

    waterjet log list
    waterjet log start x.following_error y.following_error [--mode timed|continuous|triggered]
                       [--divisor N] [--start S] [--duration S] [--window S] [--when COND] [--until COND]
    waterjet log stop
    waterjet log export RUN [--format mat|csv] [--out FILE]

Every form takes the watcher's connection options (`--connect`, `--machine`, `--prefix`,
`--credentials`). Export writes the run's variables and the control parameters in force.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import msgspec

from ..bus.keys import Keys
from ..bus.messages import LogRunData, LogSetting, LogStart, LogState, LogStop, Reply, decode, encode
from ..config import ConfigError
from ..watch import WatchError, add_connection_arguments, address, session_for

ANSWER_TIMEOUT_S = 10.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)
    sub = parser.add_subparsers(dest="log_command", required=True, metavar="ACTION")
    sub.add_parser("list", help="the variables that can be logged and the runs kept")
    start = sub.add_parser("start", help="start a log run of these variables (all with the same settings)")
    start.add_argument("variables", nargs="+", metavar="VARIABLE")
    start.add_argument("--mode", default="timed", choices=("timed", "continuous", "triggered"))
    start.add_argument("--divisor", type=int, default=1, help="log every Nth base tick (default 1: every tick)")
    start.add_argument("--start", type=float, default=0.0, metavar="S", help="timed: seconds after the run starts")
    start.add_argument("--duration", type=float, default=10.0, metavar="S", help="timed: seconds to log")
    start.add_argument("--window", type=float, default=10.0, metavar="S", help="continuous: the last S seconds kept")
    start.add_argument("--when", default="", metavar="COND", help="triggered: log while (or from when) COND holds")
    start.add_argument("--until", default="", metavar="COND", help="triggered: stop logging when COND holds")
    start.add_argument("--title", default="")
    sub.add_parser("stop", help="end the run under way (what it recorded is kept)")
    export = sub.add_parser("export", help="write a run to a MATLAB .mat or a CSV file")
    export.add_argument("run", type=int, help="the run's number (waterjet log list)")
    export.add_argument("--format", choices=("mat", "csv"), default=None, help="default: from --out's suffix, else mat")
    export.add_argument("--out", metavar="FILE", help="default: run-<N>.mat (or .csv) here")


def run(args: argparse.Namespace) -> int:
    """0 done, 1 the controller refused or could not be reached, 2 a bad option or machine file."""
    try:
        keys, endpoints = address(args)
    except ConfigError as exc:
        print(f"waterjet log: {exc}", file=sys.stderr)
        return 2
    try:
        session = session_for(args, endpoints)
    except WatchError as exc:
        print(f"waterjet log: {exc}", file=sys.stderr)
        return 1
    try:
        return _ACTIONS[args.log_command](session, keys, args)
    except LogCliError as exc:
        print(f"waterjet log {args.log_command}: {exc}", file=sys.stderr)
        return 1
    finally:
        session.close()


class LogCliError(RuntimeError):
    """The logger did not answer, or refused."""


def _ask(session, key: str, kind: type[msgspec.Struct], payload: msgspec.Struct | None = None) -> msgspec.Struct:  # noqa: ANN001
    options = {"payload": encode(payload)} if payload is not None else {}
    for reply in session.get(key, timeout=ANSWER_TIMEOUT_S, **options):
        if reply.ok is None:
            raise LogCliError(reply.err.payload.to_string())
        return decode(reply.ok.payload.to_bytes(), kind)
    raise LogCliError(f"{key}: no answer within {ANSWER_TIMEOUT_S:g} s (is the controller's logger running?)")


def _list(session, keys: Keys, args: argparse.Namespace) -> int:  # noqa: ANN001
    state: LogState = _ask(session, keys.log("state"), LogState)
    print(f"log variables (base tick {state.period_s * 1000:g} ms):")
    for v in state.variables:
        print(f"  {v.name:<28} {v.unit:<6} {v.description}")
    print("runs:" if state.runs else "runs: none kept")
    for r in state.runs:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(r.started_ns / 1e9))
        print(f"  {r.run:4d}  {r.state:<8} {when}  {r.duration_s:8.3f} s  {r.samples:9d} samples  "
              f"{', '.join(r.variables)}{'  ' + r.title if r.title else ''}")
    return 0


def _start(session, keys: Keys, args: argparse.Namespace) -> int:  # noqa: ANN001
    settings = [LogSetting(name, args.mode, args.divisor, args.start, args.duration, args.window, args.when, args.until)
                for name in args.variables]
    return _report(_ask(session, keys.log("start"), Reply, LogStart(settings, args.title)))


def _stop(session, keys: Keys, args: argparse.Namespace) -> int:  # noqa: ANN001
    return _report(_ask(session, keys.log("stop"), Reply, LogStop()))


def _report(reply: Reply) -> int:
    if not reply.ok:
        raise LogCliError(reply.reason)
    print(reply.reason)
    return 0


def _export(session, keys: Keys, args: argparse.Namespace) -> int:  # noqa: ANN001
    from ..bus.logexport import to_csv, to_mat

    fmt = args.format or (Path(args.out).suffix.lstrip(".") if args.out and Path(args.out).suffix in (".mat", ".csv")
                          else "mat")
    out = Path(args.out or f"run-{args.run}.{fmt}")
    data: LogRunData = _ask(session, keys.log(f"runs/{args.run}"), LogRunData)
    written = [to_mat(data, out)] if fmt == "mat" else to_csv(data, out)
    samples = sum(len(c.v) // 8 for c in data.columns.values())
    print(f"run {data.run}: {len(data.columns)} variables, {samples} samples, {len(data.params_end)} control parameters "
          f"-> {', '.join(str(p) for p in written)}")
    return 0


_ACTIONS = {"list": _list, "start": _start, "stop": _stop, "export": _export}
