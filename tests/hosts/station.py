"""An operator station on another host (run inside a network namespace by
tests/test_two_hosts.py): the HMI's own connection and model, no window, driven over stdin.

Each stdin line is a JSON request, answered by one JSON line on stdout:
    {"observe": true}                       -> what the operator screen would show
    {"send": "CycleStart", "args": {...}}   -> the controller's reply to that command
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cnc.bus import messages
from cnc.bus.certs import files_for
from cnc.bus.keys import Keys
from hmi.connection import Connection
from hmi.model import MachineModel


def observe(model: MachineModel) -> dict:
    st = model.status
    reachable = model.reachable
    return {
        "reachable": reachable,
        "network_alive": bool(reachable and st is not None and st.network_alive),  # the screen's lamp
        "state": st.machine_state if st else "", "phase": st.cycle_phase if st else "",
        "planner": st.planner_state if st else "", "cycles_done": st.cycles_done if st else 0,
        "alarm_seq": st.alarm_seq if st else 0, "history": sorted(e.seq for e in model.history_view()),
        "codes": sorted({e.code for e in model.history_view()}), "holder": model.lock_holder,
    }


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--connect", required=True)
    parser.add_argument("--machine", required=True)
    parser.add_argument("--prefix", default="wj")
    parser.add_argument("--station", required=True)
    parser.add_argument("--login", default="", metavar="USER:PASSWORD", help="the account to log in with")
    parser.add_argument("--tls", default="", metavar="DIR", help="ca.pem and <station>.pem/.key for tls/ endpoints")
    args = parser.parse_args()
    model = MachineModel(args.station)
    credentials = tuple(args.login.split(":", 1)) if args.login else None
    tls = files_for(Path(args.tls), args.station) if args.tls else None
    connection = Connection(model, [args.connect], Keys(args.prefix, args.machine), args.station, credentials, tls=tls)
    connection.start()
    print(json.dumps({"started": True}), flush=True)
    try:
        for line in sys.stdin:
            request = json.loads(line)
            if request.get("observe"):
                out = observe(model)
            else:
                msg = getattr(messages, request["send"])(**request.get("args", {}))
                try:
                    reply = connection.command(msg)
                    out = {"ok": reply.ok, "reason": reply.reason}
                except Exception as exc:  # noqa: BLE001 - no answer across a cut link: say so
                    out = {"ok": False, "reason": f"{type(exc).__name__}: {exc}"}
            print(json.dumps(out), flush=True)
    finally:
        connection.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
