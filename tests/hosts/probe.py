"""What a session from another host reaches (run inside a network namespace by
tests/test_two_hosts.py): prints one JSON line - whether the session opened, whether a status
arrived, the answer to a command on its own key and on another user's, and any answer from the
controller's internal keys."""

from __future__ import annotations

import argparse
import json
import sys
import threading
from pathlib import Path

import zenoh

from cnc.bus.certs import files_for
from cnc.bus.keys import Keys
from cnc.bus.messages import LockRequest, Reset, encode
from cnc.bus.session import zenoh_config


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--connect", required=True)
    parser.add_argument("--machine", required=True)
    parser.add_argument("--login", default="", metavar="USER:PASSWORD")
    parser.add_argument("--other", default="alice", help="another user, whose command key is tried too")
    parser.add_argument("--tls", default="", metavar="DIR", help="ca.pem and <name>.pem/.key for tls/ endpoints")
    parser.add_argument("--tls-name", default="probe")
    args = parser.parse_args()
    keys = Keys("wj", args.machine)
    credentials = tuple(args.login.split(":", 1)) if args.login else None
    try:
        tls = files_for(Path(args.tls), args.tls_name) if args.tls else None
        session = zenoh.open(zenoh_config("client", connect=[args.connect], credentials=credentials, tls=tls))
    except zenoh.ZError as exc:
        print(json.dumps({"opened": False, "why": str(exc).splitlines()[0]}), flush=True)
        return 0
    user = credentials[0] if credentials else "local"
    status = threading.Event()
    _sub = session.declare_subscriber(keys.status, lambda s: status.set())
    got_status = status.wait(10.0)

    def answers(key: str, payload: bytes) -> list[str]:
        attachment = json.dumps({"station": "probe"}).encode()
        return [r.ok.payload.to_string() if r.ok is not None else f"error: {r.err.payload.to_string()}"
                for r in session.get(key, payload=payload, attachment=attachment, timeout=3.0)]

    result = {
        "opened": True, "status": got_status,
        "own": answers(keys.cmd("lock", user), encode(LockRequest(take=True))),
        "other": answers(keys.cmd("reset", args.other), encode(Reset())),
        "internal": answers(keys.logic("reset"), encode(Reset())) + answers(keys.planner("stop"), b"{}"),
    }
    print(json.dumps(result), flush=True)
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
