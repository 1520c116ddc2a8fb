"""`waterjet plc-sim`: run the PLC simulator on a serial device or a fresh pty pair, and start
it as a child process for the supervisor.

Command line (wired into `cnc/cli.py` with `add_arguments` and `run`):

    waterjet plc-sim --make-pty               # prints the device the CNC must open
    waterjet plc-sim --port /dev/ttyUSB1      # serve on a real serial port (null-modem cable)

From the supervisor or a test (`sim_server.start_simulator_process`):

    sim = start_simulator_process("machines/waterjet.toml")   # or (config, spawn_context)
    rt.plc_port = sim.device                  # the PLC link opens this
    sim.inject("estop", True)                 # faults travel over a Pipe to the child
    sim.press_button(); sim.inputs()          # {"pump_pressure": 300.0, ...}
    sim.stop()

The child owns the pty pair: the device exists as long as the child runs.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from cnc.config import ConfigError, PlcConfig, load_machine

from .pty_pair import PtyPair, is_pty
from .sim_model import ModelError, PlcModel
from .sim_server import PlcSimServer

DEFAULT_MACHINE = Path(__file__).resolve().parent.parent / "machines" / "waterjet.toml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The `plc-sim` subcommand's options."""
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", metavar="DEVICE", help="serial device (or pty end) to serve on")
    where.add_argument("--make-pty", action="store_true", help="create a pty pair and print the device the master opens")
    parser.add_argument("--machine", default=str(DEFAULT_MACHINE), help="machine file with the [plc] map (default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    """Serve until SIGINT/SIGTERM; 0 on a clean stop, 2 on a bad machine file or device."""
    try:
        plc = load_machine(args.machine).plc
        model = PlcModel(plc)
    except (ConfigError, ModelError) as exc:
        print(f"plc-sim: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.make_pty:
        with PtyPair() as pair:
            print(pair.device, flush=True)
            return _serve(plc, model, pair.server_fd, stop)
    import serial

    try:
        port = serial.Serial(
            args.port, baudrate=plc.baud, parity="N" if is_pty(args.port) else plc.parity,
            stopbits=plc.stop_bits, bytesize=8, timeout=0,
        )
    except (serial.SerialException, OSError) as exc:
        print(f"plc-sim: cannot open {args.port!r}: {exc}", file=sys.stderr)
        return 2
    with port:
        print(f"PLC simulator serving unit {plc.unit_id} on {args.port} ({plc.baud} {plc.parity}{plc.stop_bits})", flush=True)
        return _serve(plc, model, port.fileno(), stop)


def _serve(plc: PlcConfig, model: PlcModel, fd: int, stop: threading.Event) -> int:
    server = PlcSimServer(plc, model, fd)
    server.start()
    try:
        while not stop.wait(0.2):
            if server.error is not None:
                return 1
    finally:
        server.stop()
        print(f"plc-sim: stopped ({server.stats})", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="waterjet plc-sim", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
