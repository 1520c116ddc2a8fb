"""`waterjet certs`: the machine's TLS certificate authority and the certificates it signs.

    waterjet certs ca [--machine M]                         a new CA for the machine
    waterjet certs controller --host HOST [--host ...]      the controller's router (names/addresses stations use)
    waterjet certs router --host HOST [--host ...]          a shop router of the machine
    waterjet certs station NAME                             a station (copy NAME.pem, NAME.key and ca.pem to it)
    waterjet certs list

The directory is `[zenoh.access] tls_dir` (default `<machine>.tls` beside the machine file), its
keys mode 0600. Endpoints `tls/HOST:PORT` in `[zenoh] listen` then use them (`cnc.bus.certs`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .bus.certs import CertError, describe, issue, make_ca
from .config import ConfigError, MachineConfig, beside, load_machine


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="certs_command", required=True, metavar="ACTION")
    sub.add_parser("ca", help="a new certificate authority for the machine")
    for name in ("controller", "router"):
        p = sub.add_parser(name, help=f"the {'controller' if name == 'controller' else 'shop router'}'s certificate")
        p.add_argument("--host", action="append", required=True, help="a host name or address stations connect to (repeatable)")
    station = sub.add_parser("station", help="a station's certificate (mutual TLS)")
    station.add_argument("name")
    sub.add_parser("list", help="the certificates made so far")
    for p in sub.choices.values():
        p.add_argument("--machine", "-m", default="machines/waterjet.toml", help="machine file (default machines/waterjet.toml)")
        p.add_argument("--days", type=int, default=825, help="validity in days (default 825)")


def tls_directory(config: MachineConfig) -> Path:
    """`[zenoh.access] tls_dir`, or `<machine file stem>.tls` beside the machine file."""
    if config.zenoh.access.tls_dir:
        return beside(config, config.zenoh.access.tls_dir)
    return Path(config.source).resolve().with_suffix(".tls")


def run(args: argparse.Namespace) -> int:
    try:
        config = load_machine(args.machine)
    except ConfigError as exc:
        print(f"waterjet certs: {exc}", file=sys.stderr)
        return 2
    directory = tls_directory(config)
    try:
        if args.certs_command == "list":
            found = sorted(directory.glob("*.pem")) if directory.is_dir() else []
            print("\n".join(describe(p) for p in found) or f"no certificates in {directory}")
            return 0
        if args.certs_command == "ca":
            made = [make_ca(directory, config.machine.name, args.days)]
        elif args.certs_command == "station":
            files = issue(directory, args.name, None, args.days)
            made = [files.certificate, files.key]
        else:
            files = issue(directory, args.certs_command, args.host, args.days)
            made = [files.certificate, files.key]
    except CertError as exc:
        print(f"waterjet certs: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {', '.join(str(p) for p in made)}")
    if not config.zenoh.access.tls_dir:
        print(f"set [zenoh.access] tls_dir = \"{directory.name}\" in {config.source} for tls/ endpoints")
    return 0
