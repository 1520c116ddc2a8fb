"""An operator station's handle on the controller: its liveliness token, the command lock, typed
commands and program upload over `<root>/u/<user>/cmd/<verb>` (what an HMI or a script uses)."""

from __future__ import annotations

import json

import msgspec
import zenoh

from .keys import Keys
from .session import LOCAL_USER
from .messages import (
    LOGIC_COMMANDS, CalibrationLadder, CalibrationRecord, ControlSelect, DeleteProgram, LoadProgram, LockRequest, LogStart, LogStop,
    ParamList, Reply, SaveParams, SetParam, SimInput, UploadProgram,
    decode, encode,
)

OPERATOR_COMMANDS: dict[str, type[msgspec.Struct]] = {
    **LOGIC_COMMANDS, "lock": LockRequest, "program": UploadProgram, "sim": SimInput, "program_delete": DeleteProgram,
    "calibration_ladder": CalibrationLadder, "calibration_record": CalibrationRecord, "control_select": ControlSelect,
}
_VERBS = {kind: verb for verb, kind in OPERATOR_COMMANDS.items()}
# An upload or load is answered once the planner has interpreted and checked the program and planned
# its first steps: seconds for a million lines on a fast host, bounded by the controller's own `[planner] load_timeout_s` (at most 7200 s) and
# the gateway's margin. The station waits that long, so the controller's answer always comes first.
LOAD_WAIT_S = 7200.0 + 60.0
LOADS = (UploadProgram, LoadProgram, CalibrationLadder)


class OperatorStation:
    """One station (`station` id, letters, digits, - and _): it is "alive" while this object is open."""

    def __init__(self, session: zenoh.Session, keys: Keys, station: str, timeout_s: float = 60.0,
                 user: str = LOCAL_USER) -> None:
        """`user`: who the session logged in as (`local` on the controller's own host, or without accounts)."""
        self.session, self.keys, self.station, self.timeout_s, self.user = session, keys, station, timeout_s, user
        zid = str(session.zid())
        self.token = session.liveliness().declare_token(keys.station(station, user, zid))
        # the gateway's ping of the lock holder: answered by Zenoh's thread at once
        self.pong = session.declare_queryable(keys.ping(station, user, zid), lambda q: q.reply(q.key_expr, b"pong"))
        self.attachment = json.dumps({"station": station, "session": zid}).encode()

    def request(self, command: msgspec.Struct, verb: str | None = None) -> Reply:
        """Send one command; the reply says ok or why not."""
        verb = verb or _VERBS[type(command)]
        return self.ask(self.keys.cmd(verb, self.user), command, verb)

    def take_lock(self) -> Reply:
        return self.request(LockRequest(take=True))

    def release_lock(self) -> Reply:
        return self.request(LockRequest(take=False))

    def set_param(self, name: str, value: float) -> Reply:
        """Change one control parameter (`axis.x.kp_1_s`); the reply says when it applied, or why not."""
        return self.ask(self.keys.user_param(self.user, name), SetParam(value), f"param {name}")

    def save_params(self) -> Reply:
        """Write the control parameters in force into the controller's machine file."""
        return self.ask(self.keys.user_params(self.user), SaveParams(), "save params")

    def log_start(self, start: LogStart) -> Reply:
        """Start a log run (logging never moves the machine: no command lock needed)."""
        return self.ask(self.keys.log("start"), start, "log start")

    def log_stop(self) -> Reply:
        return self.ask(self.keys.log("stop"), LogStop(), "log stop")

    def params(self) -> ParamList:
        """Every control parameter with its range and the value in force."""
        for reply in self.session.get(self.keys.params, timeout=self.timeout_s):
            if reply.ok is None:
                raise RuntimeError(f"params: {reply.err.payload.to_string()}")
            return decode(reply.ok.payload.to_bytes(), ParamList)
        raise TimeoutError(f"params: no answer from the controller within {self.timeout_s:g} s")

    def ask(self, key: str, msg: msgspec.Struct, what: str) -> Reply:
        """Send `msg` as a query on `key` with this station's id; its Reply, or one saying why none came."""
        limit = max(self.timeout_s, LOAD_WAIT_S) if isinstance(msg, LOADS) else self.timeout_s
        replies = self.session.get(key, payload=encode(msg), encoding=zenoh.Encoding.APPLICATION_JSON,
                                   attachment=self.attachment, timeout=limit)
        for reply in replies:
            if reply.ok is not None:
                return decode(reply.ok.payload.to_bytes(), Reply)
            return Reply(False, f"{what}: the gateway answered with an error: {reply.err.payload.to_string()}")
        return Reply(False, f"{what}: no answer from the controller within {limit:g} s")

    def upload(self, name: str, text: str) -> Reply:
        """Send a program; it is checked, interpreted and loaded, or refused with line and column."""
        return self.request(UploadProgram(name, text))

    def close(self) -> None:
        self.pong.undeclare()
        self.token.undeclare()
