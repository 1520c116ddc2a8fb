"""`waterjet users`: the machine's accounts (who may log in from another host, and in which role).

    waterjet users add NAME --role operator|engineer|observer [--password-stdin] [--machine M]
    waterjet users remove NAME [--machine M]
    waterjet users list [--machine M]

The accounts live in `[zenoh.access] users_file` (default `<machine>.users` beside the machine
file), mode 0600. Passwords are asked twice on the terminal (or read as one line from standard
input with `--password-stdin`) and never printed. A change takes effect when the controller (and
a shop router) next starts: Zenoh reads its access rules and logins when its router opens.
"""

from __future__ import annotations

import argparse
import getpass
import sys

from .bus.users import ROLES, Account, UsersError, check_name, check_password, check_role, read_users, write_users
from .config import ConfigError, load_machine, users_path

EFFECT = "it takes effect when the controller (and a shop router) next starts"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="users_command", required=True, metavar="ACTION")
    add = sub.add_parser("add", help="add an account, or change its role and password")
    add.add_argument("name")
    add.add_argument("--role", required=True, choices=ROLES)
    add.add_argument("--password-stdin", action="store_true", help="read the password as one line from standard input")
    remove = sub.add_parser("remove", help="remove an account")
    remove.add_argument("name")
    sub.add_parser("list", help="the accounts and their roles (never the passwords)")
    for p in sub.choices.values():
        p.add_argument("--machine", "-m", default="machines/waterjet.toml", help="machine file (default machines/waterjet.toml)")


def run(args: argparse.Namespace) -> int:
    """0 when done, 2 when the request or the file is wrong (the message says which)."""
    try:
        config = load_machine(args.machine)
    except ConfigError as exc:  # a broken users file included: the message names it and the line
        print(f"waterjet users: {exc}", file=sys.stderr)
        return 2
    path = users_path(config)
    try:
        accounts = read_users(path)
        if args.users_command == "list":
            if not accounts:
                print(f"no accounts in {path}: the controller serves its own host only")
            for a in accounts.values():
                print(f"{a.name}\t{a.role}")
            return 0
        name = check_name(args.name)
        if args.users_command == "remove":
            if name not in accounts:
                raise UsersError(f"{path}: no account {name!r} (accounts: {', '.join(accounts) or 'none'})")
            del accounts[name]
            write_users(path, accounts)
            print(f"removed {name} from {path}; {EFFECT}")
            return 0
        role = check_role(args.role)
        password = check_password(_password(args.password_stdin))
        existed = name in accounts
        accounts[name] = Account(name, role, password)
        write_users(path, accounts)
        print(f"{'changed' if existed else 'added'} {name} ({role}) in {path}; {EFFECT}")
        return 0
    except UsersError as exc:
        print(f"waterjet users: {exc}", file=sys.stderr)
        return 2


def _password(from_stdin: bool) -> str:
    if from_stdin:
        return sys.stdin.readline().rstrip("\r\n")
    if not sys.stdin.isatty():
        raise UsersError("no terminal to ask the password on: pass --password-stdin and write it to standard input")
    first = getpass.getpass("password: ")
    if getpass.getpass("again: ") != first:
        raise UsersError("the two passwords differ: nothing was changed")
    return first
