"""`waterjet hmi`: the operator screen on its own host, reaching the controller only over Zenoh.

    waterjet hmi [--connect ENDPOINT] [--machine ID] [--station NAME] [--credentials FILE]
                 [--screenshot OUT.png [--after SECONDS]]

`--machine` is the machine's id (its key space `<prefix>/<id>`): the screen's host needs no
machine file, everything it shows comes from the controller. `--screenshot` renders the screen
to a PNG once it has caught up with the controller (status, position, history, program), or after
`--after` seconds at the latest, and exits (offscreen when there is no display): for
documentation and for checking a remote screen.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import socket
import sys
from pathlib import Path

DEFAULT_PREFIX = "wj"
DEFAULT_MACHINE = "waterjet"
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"

_ID = r"[A-Za-z0-9_-]+"
_PREFIX = rf"{_ID}(/{_ID})*"

log = logging.getLogger(__name__)


class HmiArgumentError(ValueError):
    """A command-line value the screen cannot start with; the text names the option."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `waterjet hmi` (no Qt imported here: `waterjet --help` stays quick)."""
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help=f"Zenoh endpoint of the controller or the shop router (repeatable; default {DEFAULT_ENDPOINT})")
    parser.add_argument("--machine", "-m", metavar="ID", default=DEFAULT_MACHINE,
                        help=f"the machine's id, its machine file's [machine] name (default {DEFAULT_MACHINE!r})")
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help=f"key prefix, [zenoh] key_prefix (default {DEFAULT_PREFIX!r})")
    parser.add_argument("--station", help="this station's id (default hmi-<host name>)")
    parser.add_argument("--credentials", metavar="FILE", help="a user:password line, when the controller has accounts")
    parser.add_argument("--tls", metavar="DIR", help="for tls/ endpoints: a directory with ca.pem and this station's "
                        "<station>.pem and <station>.key (`waterjet certs station NAME`)")
    parser.add_argument("--screenshot", metavar="OUT.png",
                        help="render the screen to a PNG once it has caught up with the controller, and exit")
    parser.add_argument("--after", type=float, default=10.0, metavar="SECONDS",
                        help="--screenshot renders after this long at the latest, caught up or not (default 10 s)")
    parser.add_argument("--take-lock", action="store_true", help="take the command lock once connected")


def default_station() -> str:
    """hmi-<host name>, reduced to the letters a station id allows."""
    return "hmi-" + (re.sub(r"[^A-Za-z0-9_-]", "-", socket.gethostname()) or "station")[:40]


def has_display() -> bool:
    """Whether Qt can open a window here: a display server, or a platform chosen explicitly."""
    return any(os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"))


def resolve(args: argparse.Namespace) -> tuple[list[str], str, str, tuple[str, str] | None]:
    """(endpoints, key prefix, machine id, credentials) from the options; HmiArgumentError names the bad one."""
    for option, value, pattern in (("--machine", args.machine, _ID), ("--prefix", args.prefix, _PREFIX)):
        if not re.fullmatch(pattern, value):
            raise HmiArgumentError(f"{option} {value!r}: use letters, digits, _ and - (the machine file's "
                                   f"{'[machine] name' if option == '--machine' else '[zenoh] key_prefix'})")
    if not 0.0 <= args.after <= 3600.0:
        raise HmiArgumentError(f"--after {args.after:g}: give 0 to 3600 seconds")
    credentials = None
    if args.credentials:
        from cnc.bus.access import station_login

        try:
            credentials = station_login(args.credentials)
        except ValueError as exc:
            raise HmiArgumentError(f"--credentials {exc}") from None
    return args.connect or [DEFAULT_ENDPOINT], args.prefix, args.machine, credentials


def run(args: argparse.Namespace) -> int:
    """Open the screen until its window is closed (0), or render one screenshot (0 when written)."""
    try:
        endpoints, prefix, machine, credentials = resolve(args)
    except HmiArgumentError as exc:
        print(f"waterjet hmi: {exc}", file=sys.stderr)
        return 2
    station = args.station or default_station()
    if not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", station):
        print(f"waterjet hmi: --station {station!r}: use 1 to 64 letters, digits, _ or -", file=sys.stderr)
        return 2
    if not has_display():
        if not args.screenshot:
            print("waterjet hmi: no display (DISPLAY and WAYLAND_DISPLAY are not set); "
                  "use --screenshot OUT.png to render the screen without one", file=sys.stderr)
            return 2
        os.environ["QT_QPA_PLATFORM"] = "offscreen"
    from .session import OperatorScreen

    tls = None
    if args.tls:
        from cnc.bus.certs import CertError, files_for

        try:
            tls = files_for(Path(args.tls), station).check()
        except CertError as exc:
            print(f"waterjet hmi: --tls {exc}", file=sys.stderr)
            return 2
    with OperatorScreen(endpoints, prefix, machine, station, credentials, tls) as screen:
        if args.take_lock:
            screen.take_lock_when_connected()
        if args.screenshot:
            return screen.screenshot_after(args.after, Path(args.screenshot))
        screen.window.show()
        return screen.app.exec()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="waterjet hmi", description=__doc__.splitlines()[0])
    add_arguments(parser)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
