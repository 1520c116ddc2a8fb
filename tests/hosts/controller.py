"""The simulated machine's controller on its own host (run inside a network namespace by
tests/test_two_hosts.py): every controller process and the PLC simulator on the real-time clock,
its router joined to a shop router, until stdin closes. Prints one JSON line once it is up."""

from __future__ import annotations

import argparse
import json
import sys
import threading

from cnc.config import load_machine
from cnc.sim.faultinject import FAST_PLANT
from cnc.runtime.supervisor import Supervisor


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--machine", required=True)
    parser.add_argument("--listen", required=True)
    parser.add_argument("--connect", required=True)
    parser.add_argument("--history", required=True)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=JSON", help="machine-file override")
    args = parser.parse_args()
    overrides = {"zenoh.listen": [args.listen], "zenoh.connect": [args.connect]}
    overrides.update({k: json.loads(v) for k, v in (item.split("=", 1) for item in args.set)})
    config = load_machine(args.machine, overrides)
    gone = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), gone.set()), daemon=True).start()
    with Supervisor(config, clock="realtime", history_path=args.history, plc_sim_times=FAST_PLANT) as sup:
        print(json.dumps({"up": True, "machine": config.machine.name}), flush=True)
        return sup.run(gone.is_set)


if __name__ == "__main__":
    sys.exit(main())
