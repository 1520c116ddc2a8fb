"""`waterjet sim`: the simulated machine's inputs from a shell.

    waterjet sim                      every input, its value and what it takes
    waterjet sim doors_open 1         open a safety door (0 closes it)
    waterjet sim transport_button 1   press the transport station's button
    waterjet sim friction 40          forty times the axes' friction: a following error

A change is an operator command (`cmd/sim`) like any other: it needs the operator role and the
command lock, which this command takes for the change and gives back (it is refused while another
station holds the lock), and it is in the audit trail and, as an info entry, in the alarm history.
Only a controller on the simulated board has these inputs.
"""

from __future__ import annotations

import argparse
import sys

from .bus.messages import SimInput, SimInputs, decode
from .bus.operator import OperatorStation
from .bus.session import LOCAL_USER
from .config import ConfigError
from .watch import WatchError, _credentials, add_connection_arguments, address, session_for

ANSWER_TIMEOUT_S = 10.0
_WORDS = {"on": 1.0, "off": 0.0, "true": 1.0, "false": 0.0, "open": 1.0, "closed": 0.0, "pressed": 1.0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_connection_arguments(parser)
    parser.add_argument("name", nargs="?", help="the input to change (without it: list every input)")
    parser.add_argument("value", nargs="?", help="its new value: 1 or 0 for a switch (on/off), 1 presses a button, "
                        "a number for a value")
    parser.add_argument("--station", default="sim-cli", help="the station name this command acts as (default sim-cli)")


def run(args: argparse.Namespace) -> int:
    """0 done, 1 refused or the controller unreachable, 2 a bad argument or machine file."""
    if args.name is not None and args.value is None:
        print(f"waterjet sim: {args.name}: which value? (waterjet sim {args.name} 1)", file=sys.stderr)
        return 2
    value = None
    if args.value is not None:
        try:
            value = _WORDS[args.value.lower()] if args.value.lower() in _WORDS else float(args.value)
        except ValueError:
            print(f"waterjet sim: value {args.value!r} is not a number (nor on/off)", file=sys.stderr)
            return 2
    try:
        keys, endpoints = address(args)
        credentials = _credentials(args.credentials)
        session = session_for(args, endpoints)
    except ConfigError as exc:
        print(f"waterjet sim: {exc}", file=sys.stderr)
        return 2
    except WatchError as exc:
        print(f"waterjet sim: {exc}", file=sys.stderr)
        return 1
    try:
        if value is None:
            return _list(session, keys)
        station = OperatorStation(session, keys, args.station, ANSWER_TIMEOUT_S,
                                  user=credentials[0] if credentials else LOCAL_USER)
        taken = station.take_lock()
        if not taken.ok:
            print(f"waterjet sim: the command lock: {taken.reason}", file=sys.stderr)
            return 1
        try:
            reply = station.request(SimInput(args.name, value))
        finally:
            station.release_lock()
        if not reply.ok:
            print(f"waterjet sim: {args.name}: refused: {reply.reason}", file=sys.stderr)
            return 1
        print(f"waterjet sim: {reply.reason}")
        return 0
    finally:
        session.close()


def _list(session, keys) -> int:  # noqa: ANN001
    for reply in session.get(keys.sim, timeout=ANSWER_TIMEOUT_S):
        if reply.ok is None:
            print(f"waterjet sim: {reply.err.payload.to_string()}", file=sys.stderr)
            return 1
        inputs: SimInputs = decode(reply.ok.payload.to_bytes(), SimInputs)
        for i in inputs.inputs:
            takes = "1 presses it" if i.kind == "button" else "0 or 1" if i.kind == "switch" else \
                f"{i.minimum:g} to {i.maximum:g} {i.unit}".rstrip()
            print(f"{i.name:<18} {i.value:>6g} {i.unit:<3} {i.kind:<7} {takes:<14} {i.doc}")
        return 0
    print(f"waterjet sim: no answer from the controller within {ANSWER_TIMEOUT_S:g} s", file=sys.stderr)
    return 1
