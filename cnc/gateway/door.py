"""The gateway's doors on Zenoh: operator commands behind the command lock, program upload, and
the read-only queries (alarm history with filters, job history, the loaded program, the lock).

Commands arrive as queries on `<root>/u/<user>/cmd/<verb>`, which the router lets only `<user>`
send (`cnc.bus.access`), with the station's name (and its Zenoh session) in the query's
attachment (`{"station": "...", "session": "..."}`). The gateway's command service
(`cnc.bus.service`) decodes each into its typed message (a malformed payload is refused, never a
crash), checks it against the user's role and the command lock (held by one user's station), and
forwards it to the control logic, whose answer (ok, or refused with the reason) is the reply. A
load names a program in the machine's program directory (`cnc.programs`: nothing outside it,
no devices or pipes, size checked first, text only).
Uploaded programs are checked (size, text encoding), interpreted with the machine's dialect
(errors with line and column), stored, then loaded. Commands and queries are served by the
service's worker threads, one per lane, so that a long program load never delays a history query,
and no Zenoh callback thread ever waits. The realtime commands (stop, hold, jog stop, a jog's
refresh, reset) and the loss of the lock holder's station have a lane of their own: they never
queue behind a slow command. Every command is in the audit trail with its answer.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import threading
import time
from pathlib import Path
from typing import Any, Callable
from urllib.parse import unquote

import msgspec
import zenoh

from ..alarms import AlarmHistory, AlarmLevel, HistoryError
from .audit import AuditTrail, AuditWriter, audit_path
from ..bus.access import Roles
from ..bus.client import CommandClient
from ..bus.keys import Keys
from ..bus.messages import (
    ENGINEER_VERBS, LOCK_FREE_VERBS, LOGIC_COMMANDS, ControlSelect, MOTION_VERBS, REALTIME_VERBS, AuditPage, DeleteProgram, Hold, JobPage, LoadProgram,
    LockRequest, Notice, ProcedureCatalogue, ProcedureInfo, ProgramDiagnostic, ProgramInfo, ProgramList, ProgramPath, Reply,
    SCHEMA_VERSION, CalibrationLadder, CalibrationRecord, MaterialEntry, MaterialList, SetCut, SimInput, SimInputs, StopAll, UploadProgram, decode, encode,
)
from ..bus.service import CommandRefused, CommandService, Request, Route, report_to_logic
from ..bus.states import MachineState, PlannerState
from ..config import MachineConfig
from ..cutmodel import library_of
from ..calibration import ladder_name, library_material, machine_ladder
from ..materials import QUALITIES, Ladder, MaterialError, load_material, record_calibration
from . import control_door
from .jobs import CutSetups, JobHistory, jobs_path
from .library import ProgramLibrary, library_path
from .lock import OperatorLock, Token
from ..logic.client import LogicClient
from ..machine_dialect import dialect_for
from ..programs import ProgramDirectory
from ..runtime.rt import collector_paused
from ..siminputs import SimInputError, check, simulated_only

log = logging.getLogger(__name__)

SUPERVISOR_TIMEOUT_S = 10.0  # a simulated input's change waits at most this for the supervisor (and its PLC simulator)
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}\Z")
_CONTROL = re.compile(r"[\x00-\x08\x0b\x0e-\x1f\x7f]")  # tab, LF, FF, CR are text; the rest is not
SQLITE_INT_MIN, SQLITE_INT_MAX = -(2 ** 63), 2 ** 63 - 1  # what a read's integer parameter may be: the stores' integers


class Door:
    """Command and query routes of the gateway, on its command service (`service`, which the
    parameter door shares); `close()` undeclares them and stops the workers."""

    def __init__(
        self, config: MachineConfig, session: zenoh.Session, keys: Keys, history_path: str, program_dir: str,
        machine_state: Callable[[], str], motion: Callable[[], dict], logic_timeout_s: float = 60.0,
        inject: Callable[[], str] | None = None,
    ) -> None:
        """`inject`: handlers to fail on purpose (`cnc.data.injection`, the simulated board only)."""
        self.config, self.session, self.keys = config, session, keys
        self.history_path = history_path
        self.program_dir = Path(program_dir)
        self.programs = ProgramDirectory(self.program_dir, config.gcode.max_program_bytes)
        self.library = ProgramLibrary(self.programs, library_path(history_path), jobs_path(history_path), config,
                                      summarise=config.gateway.library_checks)
        self.machine_state, self.motion = machine_state, motion
        self.cut_setups = CutSetups(jobs_path(history_path))  # the cutting job chosen for each program
        self.lock = OperatorLock()
        self.audit = AuditWriter(audit_path(history_path))
        self.logic = LogicClient(session, keys, timeout_s=logic_timeout_s)
        # the simulated machine's inputs: the supervisor owns them (`cnc.sim.inputs`)
        self.supervisor = CommandClient(session, keys.supervisor, {"sim/set": SimInput}, "supervisor", SUPERVISOR_TIMEOUT_S)
        self.uploaded: dict[str, tuple[str, str, Any]] = {}  # program hash -> (name, text, interpreted Program)
        # one worker per lane: a stop never waits behind a load, an upload (interpreting a big, or
        # endlessly looping, program takes seconds) or a history query
        self.service = CommandService(session, keys, "gateway", report_to_logic(session, keys, "gateway"), threaded=True,
                                      roles=Roles.load(config), lock=self.lock, audit=self._audit_record,
                                      inject=inject)
        stop_all_role = "observer" if config.zenoh.access.observers_may_stop_all else "operator"
        commands = [
            Route(verb, keys.cmd_any(verb), self._forward, LOGIC_COMMANDS[verb],
                  role=stop_all_role if verb == "stop_all" else "engineer" if verb in ENGINEER_VERBS else "operator",
                  lock=verb not in LOCK_FREE_VERBS,
                  motion=verb in MOTION_VERBS, lane="realtime" if verb in REALTIME_VERBS else "cmd", audit=True)
            for verb in LOGIC_COMMANDS
        ]
        reads = [
            Route(what, key, self._read(answer), read=True, lane="query") for what, key, answer in (
                ("history", keys.alarms_history, self._history), ("jobs", keys.jobs_history, self._jobs),
                ("audit", keys.audit_history, self._audit), ("program", keys.program, self._program),
                ("lock", keys.lock, lambda _params: self.lock.state()), ("procedures", keys.procedures, self._procedures),
                ("programs", keys.programs, self._library), ("program preview", keys.program_preview, self._preview),
                ("materials", keys.materials, self._materials),
                ("control programs", keys.control_programs, lambda _params: control_door.program_list(self.config)))
        ]
        self.service.serve(
            *commands,
            Route("lock", keys.cmd_any("lock"), self._lock, LockRequest, role="operator", lane="cmd", audit=True),
            Route("program", keys.cmd_any("program"), self._upload, UploadProgram, role="operator", lock=True,
                  lane="upload", audit=True),
            Route("sim", keys.cmd_any("sim"), self._sim, SimInput, role="operator", lock=True, lane="cmd", audit=True),
            Route("program_delete", keys.cmd_any("program_delete"), self._delete, DeleteProgram, role="operator", lock=True,
                  lane="cmd", audit=True),
            Route("calibration_ladder", keys.cmd_any("calibration_ladder"), self._ladder, CalibrationLadder, role="operator",
                  lock=True, lane="upload", audit=True),
            Route("calibration_record", keys.cmd_any("calibration_record"), self._record, CalibrationRecord, role="engineer",
                  lock=True, lane="cmd", audit=True),
            Route("control_select", keys.cmd_any("control_select"), self._control_select, ControlSelect, role="engineer",
                  lock=True, lane="upload", audit=True),
            Route("sim", keys.sim, self._read(lambda _params: self._sim_inputs()), read=True, lane="query"),
            *reads,
        )
        self.lock_pub = session.declare_publisher(keys.lock, encoding=zenoh.Encoding.APPLICATION_JSON)
        self.stations = session.liveliness().declare_subscriber(keys.stations, self._on_station, history=True)
        self._closing = threading.Event()
        self.pinger = threading.Thread(target=self._ping_holder, name="door-ping", daemon=True)
        self.pinger.start()

    def close(self) -> None:
        self._closing.set()
        self.stations.undeclare()
        self.service.close()
        self.lock_pub.undeclare()
        self.pinger.join(2.0)
        self.audit.close()
        self.library.close()
        self.cut_setups.close()

    # -- commands ---------------------------------------------------------------------------
    def _forward(self, request: Request) -> Reply:
        """An operator's command to the control logic (a load by name, from the program directory only)."""
        command = request.message
        if isinstance(command, LoadProgram):
            path, data = self.programs.read(command.path)
            return self._load_checked(Path(command.path).name, path, data)
        elif isinstance(command, StopAll):  # who asked, as the router and the service know it
            caller = request.caller
            command = StopAll(f"station {caller.station or '?'} ({caller.user or 'no user'})")
        elif isinstance(command, SetCut):
            return self._set_cut(command)
        return self.logic.request(command, self._limit_for(command))

    def _set_cut(self, command: SetCut) -> Reply:
        """The cutting job of the loaded program; once taken, remembered for that program (by name),
        so that loading it again brings it back."""
        name = self.motion()["program_name"]
        reply = self.logic.request(command, self._limit_for(command))
        if reply.ok and name:
            if command.material:
                self.cut_setups.save(name, json.dumps(msgspec.to_builtins(command)))
            else:
                self.cut_setups.forget(name)
        return reply

    def _remembered_cut(self, name: str) -> SetCut | None:
        """The cutting job last chosen for the program `name` (None: the program's own)."""
        raw = self.cut_setups.get(name)
        if raw is None:
            return None
        try:
            return msgspec.convert({**json.loads(raw), "version": SCHEMA_VERSION}, SetCut)
        except (ValueError, msgspec.ValidationError) as exc:  # written by an older version: forgotten, and said
            log.warning("gateway: the cutting job remembered for %s is unreadable (%s): the program's own applies", name, exc)
            return None

    def _sim(self, request: Request) -> Reply:
        """An input of the simulated machine changed (`cnc.siminputs`): checked, told to the alarm
        history (before it takes effect, so that what it causes follows it there), then made by
        the supervisor, which owns the simulated environment."""
        msg: SimInput = request.message
        self._simulated_only()
        try:
            check(msg.input, float(msg.value))
        except SimInputError as exc:
            raise CommandRefused(str(exc)) from None
        who = request.caller.user + (f" at station {request.caller.station}" if request.caller.station else "")
        self._notice(f"simulator: {msg.input} set to {msg.value:g} by {who}")
        reply = self.supervisor.request(msg)
        if not reply.ok:
            self._notice(f"simulator: {msg.input} not changed: {reply.reason}")
        return reply

    def _sim_inputs(self) -> SimInputs:
        self._simulated_only()
        replies = list(self.session.get(self.keys.supervisor("sim"), timeout=SUPERVISOR_TIMEOUT_S))
        if not replies or replies[0].ok is None:
            raise CommandRefused("the supervisor did not list the simulated inputs")
        return decode(replies[0].ok.payload.to_bytes(), SimInputs)

    def _simulated_only(self) -> None:
        try:
            simulated_only(self.config)
        except SimInputError as exc:
            raise CommandRefused(str(exc)) from None

    def _notice(self, detail: str) -> None:
        """An info entry in the alarm history (the control logic keeps it), stored before this returns."""
        reply = self.logic.request(Notice("simulator", detail), SUPERVISOR_TIMEOUT_S)
        if not reply.ok:
            log.warning("gateway: the control logic did not note %r: %s", detail, reply.reason)

    def _audit_record(self, request: Request, reply: Reply) -> None:
        """Every command with its answer, refusals included; a read only when it carried a change
        (a parameter sent to the read-only keys)."""
        if request.read and not request.payload:
            return
        self.audit.record(request.caller.user, request.caller.station, request.what, _as_sent(request.verb, request.payload),
                          reply.ok, reply.reason)

    @staticmethod
    def _read(answer: Callable[[dict], Any]) -> Callable[[Request], Any]:
        """A read route's handler: the selector's parameters in, the data out; a parameter it
        cannot use is refused (the asker gets a Zenoh error saying which)."""
        def handler(request: Request) -> Any:
            try:
                return answer(request.params)
            except (ValueError, KeyError, HistoryError) as exc:
                raise CommandRefused(str(exc)) from None
        return handler

    # -- the lock ---------------------------------------------------------------------------
    def _lock(self, request: Request) -> Reply:
        user, station, msg = request.caller.user, request.caller.station, request.message
        silent = self.lock.silent_token(user, station, request.caller.session) if msg.take else None
        # it stopped answering the ping once; it has just sent this, so it is given the time a holder
        # is given before it is lost to answer again
        if silent is not None and self._answers(silent, self.config.gateway.station_lost_ms / 1e3):
            self.lock.token_answers(silent)
        if msg.take and not self.lock.announced(user, station):
            self._tokens_now(user, station)  # a token declared just now: the subscriber has not seen it yet
        if msg.take:
            self.lock.take(user, station, request.caller.session)
        else:
            self.lock.release(user, station)
        self._publish_lock()
        return Reply(True)

    def _tokens_now(self, user: str, station: str) -> None:
        try:
            OperatorLock.check_station(station)
        except CommandRefused:
            return
        for reply in self.session.liveliness().get(self.keys.station(station, user) + "/**", timeout=1.0):
            token = Token.parse(str(reply.ok.key_expr), self.keys.root) if reply.ok is not None else None
            if token is not None:
                self.lock.token_alive(token)
        # Zenoh 1.10 at times answers that get with nothing, at once, on a session with a liveliness
        # subscriber with history (the stations'), which gets the token instead; other queries in
        # flight make it likelier (bench/zenoh_liveliness_get.py): wait for it there
        self.lock.wait_announced(user, station, 1.0)

    def _answers(self, token: Token, timeout_s: float) -> bool:
        """Whether `token`'s station answers the ping within `timeout_s`."""
        key = self.keys.ping(token.station, token.user, token.session)
        return any(r.ok is not None for r in self.session.get(key, timeout=timeout_s))

    def _on_station(self, sample: Any) -> None:
        token = Token.parse(str(sample.key_expr), self.keys.root)
        if token is None:
            return
        if sample.kind == zenoh.SampleKind.PUT:
            self.lock.token_alive(token)
        elif self.lock.token_lost(token):
            self.service.post("realtime", lambda who=token.who: self._operator_lost(who))
        self._publish_lock()

    def _ping_holder(self) -> None:
        """Ask the lock holder's station for an answer every `[gateway] station_ping_ms`; none for
        `station_lost_ms` and it is lost, as when its token goes, and silent (`OperatorLock.token_silent`)
        until it answers again (silent stations are asked too, without waiting). A link's lease
        normally ends the token first, but Zenoh 1.10 does not expire a TLS link whose writes are
        stuck (a pulled cable while status flows to the station): this catches that, and any
        station that stopped answering."""
        period = self.config.gateway.station_ping_ms / 1e3
        lost_after = self.config.gateway.station_lost_ms / 1e3
        holder, answered = None, 0.0
        while not self._closing.wait(period):
            for token in self.lock.silent_tokens():
                self.session.get(self.keys.ping(token.station, token.user, token.session), self._on_pong(token),
                                 timeout=period)
            now = time.monotonic()
            if self.lock.holder is not holder:
                holder, answered = self.lock.holder, now
            if holder is None:
                continue
            if self._answers(holder, period):
                answered = time.monotonic()
            elif time.monotonic() - answered > lost_after and self.lock.token_silent(holder):
                log.warning("gateway: station %r has not answered for %.1f s: lost", holder.who, time.monotonic() - answered)
                self.service.post("realtime", lambda who=holder.who: self._operator_lost(who))
                self._publish_lock()

    def _on_pong(self, token: Token) -> Callable[[Any], None]:
        """A silent station's answer to the ping: it counts again."""
        def answered(reply: Any) -> None:
            if reply.ok is not None and not self._closing.is_set() and self.lock.token_answers(token):
                log.info("gateway: station %r answers again", token.who)
                self._publish_lock()
        return answered

    def _operator_lost(self, station: str) -> None:
        """The lock holder's station is gone: a cut holds (or goes on, `[gateway] on_operator_lost`);
        a jog, go-to or homing, which that station was steering, stops."""
        state = self.machine_state()
        log.warning("gateway: operator station %r lost (machine %s)", station, state)
        why = f"operator station {station!r} lost (network, host or program)"
        if self.config.gateway.on_operator_lost == "hold" and state == MachineState.RUNNING.name:
            reply = self.logic.request(Hold(why=f"{why}: feed hold"))
            log.warning("gateway: feed hold after the operator was lost: %s", "ok" if reply.ok else reply.reason)
        elif state in (MachineState.JOGGING.name, MachineState.HOMING.name, MachineState.MDI.name):
            reply = self.logic.request(Hold(why=f"{why}: the {state.lower()} stopped"))
            log.warning("gateway: %s stopped after the operator was lost: %s", state.lower(), "ok" if reply.ok else reply.reason)

    def _publish_lock(self) -> None:
        self.lock_pub.put(encode(self.lock.state()))

    # -- programs ---------------------------------------------------------------------------
    def _upload(self, request: Request) -> Reply:
        msg = request.message
        if not _NAME.match(msg.name):
            return Reply(False, f"program: name {msg.name!r} must be a plain file name (letters, digits, . _ -)")
        data = msg.text.encode("utf-8")
        limit = self.config.gcode.max_program_bytes
        if len(data) > limit:
            return Reply(False, f"program: {msg.name} is {len(data)} bytes; this machine accepts at most {limit}")
        bad = _CONTROL.search(msg.text)
        if bad:
            line = msg.text.count("\n", 0, bad.start()) + 1
            column = bad.start() - (msg.text.rfind("\n", 0, bad.start()) + 1) + 1
            why = f"not text: control character {bad.group()!r} (a binary file?)"
            return Reply(False, f"program: {msg.name}:{line}:{column}: {why}", [ProgramDiagnostic(line, column, why)])
        return self._store_and_load(msg.name, data)

    def _store_and_load(self, name: str, data: bytes) -> Reply:
        """A program's text checked by the interpreter, stored in the directory (whole or not at all),
        and loaded."""
        program, diagnostic = self._interpret(name, data)
        if diagnostic is not None:
            return _refused(name, diagnostic)
        self.program_dir.mkdir(parents=True, exist_ok=True)
        path = self.program_dir / name
        tmp = path.with_name(f".{name}.part")
        tmp.write_bytes(data)
        os.replace(tmp, path)
        self.library.changed()
        return self._load_checked(name, path, data, program)

    def _ladder(self, request: Request) -> Reply:
        """The guided calibration's first step (`cnc.calibration`): the ladder made, checked against
        the machine, stored and loaded, at its programmed feeds (a cutting job remembered for that
        name is forgotten: the rungs' speeds are the test)."""
        msg: CalibrationLadder = request.message
        try:
            material, _ = library_material(msg.material, self.config)
            ladder = Ladder(msg.thickness_mm, msg.slowest_mm_min, msg.fastest_mm_min, rungs=msg.rungs, pierce_s=msg.pierce_s)
            text = machine_ladder(material, ladder, self.config)
        except MaterialError as exc:
            raise CommandRefused(f"calibration: {exc}") from None
        name = ladder_name(material.id, msg.thickness_mm)
        self.cut_setups.forget(name)
        reply = self._store_and_load(name, text.encode("utf-8"))
        if not reply.ok:
            return reply
        speeds = ", ".join(f"{s:.0f}" for s in ladder.speeds())
        return Reply(True, f"{name} loaded: {ladder.rungs} rungs at {speeds} mm/min; cut it, then record per quality "
                           "the fastest rung whose edge is good enough")

    def _control_select(self, request: Request) -> Reply:
        """The machine's control program for its next start (`control_door.select`)."""
        reply = control_door.select(self.config, request.message.program, PlannerState(self.motion()["state"]))
        if not reply.ok:
            raise CommandRefused(reply.reason)
        return reply

    def _record(self, request: Request) -> Reply:
        """The guided calibration's last step: what the operator judged, into the material's chart."""
        msg: CalibrationRecord = request.message
        caller = request.caller
        try:
            _, path = library_material(msg.material, self.config)
            if len(msg.quality_mm_min) != len(QUALITIES) or (msg.lag_mm and len(msg.lag_mm) != len(QUALITIES)):
                raise MaterialError("quality_mm_min (and lag_mm, when given) take five values, quality 1 to 5")
            m = record_calibration(path, msg.thickness_mm, msg.separation_mm_min, list(msg.quality_mm_min), msg.pierce_s,
                                   msg.kerf_mm, f"{caller.user or 'local'} at station {caller.station or '?'}",
                                   list(msg.lag_mm) or None)
        except MaterialError as exc:
            raise CommandRefused(f"calibration: {exc}") from None
        lo, hi = m.thickness_range
        return Reply(True, f"{m.id}: {msg.thickness_mm:g} mm recorded; its chart covers "
                           + (f"{lo:g} to {hi:g} mm" if hi > lo else f"{lo:g} mm"))

    def _load_checked(self, name: str, path: Path, data: bytes, program: Any = None) -> Reply:
        """Load a program of the directory: interpreted here first (unless `program` is that), so
        that a refusal carries its line and column and the preview its text and path; then by the
        control logic and the planner, which check it against the machine."""
        digest = hashlib.sha256(data).hexdigest()
        if program is None:
            seen = self.uploaded.get(digest)
            program, diagnostic = (seen[2], None) if seen is not None else self._interpret(name, data)
            if diagnostic is not None:
                return _refused(name, diagnostic)
        # the latest and the loaded one (its preview is served while it runs, also after a refused
        # upload), no others: programs can be large
        loaded = {h: p for h, p in self.uploaded.items() if h == self.motion()["program_hash"]}
        self.uploaded = {**loaded, digest: (name, data.decode("utf-8"), program)}
        command = LoadProgram(str(path), cut=self._remembered_cut(name))
        reply = self.logic.request(command, self._limit_for(command))
        if not reply.ok:
            return reply
        return Reply(True, f"loaded {name} ({len(data)} bytes, sha256 {digest[:12]})")

    def _limit_for(self, command) -> float | None:
        """A load waits as long as the logic waits for the planner to check and plan the program
        (minutes for a large one), and a little longer; other commands the client's default."""
        return self.config.planner.load_timeout_s + 5.0 if isinstance(command, (LoadProgram, SetCut)) else None

    def _interpret(self, name: str, data: bytes) -> tuple[Any, ProgramDiagnostic | None]:
        from gcode.errors import GCodeError
        from gcode.interp import Interpreter

        try:
            with collector_paused():  # kept for the preview: no collector passes over it, now or later
                return Interpreter(dialect_for(self.config), name).run(data), None
        except GCodeError as exc:
            return None, ProgramDiagnostic(exc.line, exc.column, exc.message, (exc.source_line or "").rstrip("\r\n"))

    def _program(self, params: dict) -> ProgramInfo:
        m = self.motion()
        name, text, program = self.uploaded.get(m["program_hash"], (m["program_name"], "", None))
        want_text = params.get("text", "1") not in ("0", "false", "no")
        want_path = params.get("path", "0") not in ("0", "false", "no")
        return ProgramInfo(
            name=m["program_name"], hash=m["program_hash"], bytes=len(text.encode()) if text else 0,
            lines=m["program_lines"], planned_s=m["planned_s"], text=text if want_text else "",
            path=program_path(program) if want_path and program is not None else None,
        )

    def _materials(self, _params: dict) -> MaterialList:
        """The material library, read afresh (a file calibrated meanwhile is seen); a broken file is
        named, and the others still listed."""
        directory = library_of(self.config)
        entries, errors = [], []
        for path in sorted(directory.glob("*.toml")) if directory.is_dir() else []:
            try:
                m = load_material(path)
            except MaterialError as exc:
                errors.append(str(exc))
                continue
            rows = [r.thickness_mm for r in m.chart]
            entries.append(MaterialEntry(
                m.id, m.name, m.kind, m.source, rows, [[m.cut(t, q).speed_mm_min for q in QUALITIES] for t in rows],
                bool(m.corner_mm) and all(r.lag_mm for r in m.chart) and bool(m.chart)))
        return MaterialList(str(directory), entries, "; ".join(errors))

    def _library(self, _params: dict) -> ProgramList:
        return self.library.listing(loaded=self.motion()["program_name"])

    def _preview(self, params: dict) -> ProgramInfo:
        """A stored program for the screen's preview: its text, and its path when it is valid (else
        where and why it is refused), without loading it."""
        if "name" not in params:
            raise ValueError("parameter name=<program> is missing")
        name = unquote(params["name"])
        path, data = self.programs.read(name)
        digest = hashlib.sha256(data).hexdigest()
        seen = self.uploaded.get(digest)
        program, diagnostic = (seen[2], None) if seen is not None else self._interpret(name, data)
        summary = self.library.summary(Path(name).name)
        return ProgramInfo(
            name=path.name, hash=digest, bytes=len(data),
            lines=program.stats.lines if program is not None else len(data.splitlines()),
            planned_s=summary.planned_s if summary is not None else -1.0, text=data.decode("utf-8"),
            path=program_path(program) if program is not None else None,
            errors=[diagnostic] if diagnostic is not None else [],
        )

    def _delete(self, request: Request) -> Reply:
        """Delete a stored program; not the one a cycle or a run is using now."""
        name = request.message.name
        m = self.motion()
        if name == m["program_name"] and self.machine_state() in (MachineState.RUNNING.name, MachineState.HOLD.name):
            raise CommandRefused(f"{name} is running: stop the cycle before deleting it")
        self.library.delete(name)
        kept = "; the controller keeps it loaded until another program is loaded" if name == m["program_name"] else ""
        return Reply(True, f"deleted {name}{kept}")

    def _procedures(self, _params: dict) -> ProcedureCatalogue:
        return ProcedureCatalogue([ProcedureInfo(p.id, p.title, [s.text for s in p.step]) for p in self.config.procedure])

    # -- histories --------------------------------------------------------------------------
    def _history(self, params: dict) -> Any:
        """Filters: after (catch-up, oldest first), since_ns, until_ns, level, code (comma lists), text,
        before_seq, offset, limit, order=newest|oldest."""
        with AlarmHistory(self.history_path, readonly=True) as history:
            limit = _int(params, "limit", 500)
            if "after" in params:
                return history.after(_int(params, "after", 0), limit)
            levels = [AlarmLevel.parse(x) for x in params["level"].split(",")] if params.get("level") else None
            codes = _ints(params, "code") if params.get("code") else None
            order = params.get("order", "newest")
            if order not in ("newest", "oldest"):
                raise ValueError(f"order {order!r} is not newest or oldest")
            return history.query(
                since_ns=_opt_int(params, "since_ns"), until_ns=_opt_int(params, "until_ns"), levels=levels, codes=codes,
                text=params.get("text", ""), before_seq=_opt_int(params, "before_seq"), offset=_int(params, "offset", 0),
                limit=limit, newest_first=order == "newest",
            )

    def _audit(self, params: dict) -> Any:
        return _page_of(AuditTrail, audit_path(self.history_path), AuditPage, params, "user")

    def _jobs(self, params: dict) -> Any:
        return _page_of(JobHistory, jobs_path(self.history_path), JobPage, params, "program")


def program_path(program: Any) -> ProgramPath:
    """The motions of an interpreted program as columns (dwells left out)."""
    from gcode.canon import DWELL

    seg = program.segments[program.segments["kind"] != DWELL]
    return ProgramPath(
        kind=seg["kind"].tolist(), start_x=seg["start"][:, 0].tolist(), start_y=seg["start"][:, 1].tolist(),
        end_x=seg["end"][:, 0].tolist(), end_y=seg["end"][:, 1].tolist(), center_x=seg["center"][:, 0].tolist(),
        center_y=seg["center"][:, 1].tolist(), cw=seg["cw"].astype(bool).tolist(), line=seg["line"].tolist(),
    )


def _refused(name: str, diagnostic: ProgramDiagnostic) -> Reply:
    return Reply(False, f"program: {name}:{diagnostic.line}:{diagnostic.column}: {diagnostic.message}", [diagnostic])


def _as_sent(verb: str, payload: bytes) -> str:
    """A command as the audit trail keeps it: its JSON (at most 2000 characters), an upload by its
    name and size (a program is large, and it is stored anyway)."""
    if verb == "program":
        try:
            name = json.loads(payload).get("name", "?")
        except (ValueError, AttributeError):
            name = "?"
        return json.dumps({"name": name, "bytes": len(payload)})
    return payload.decode("utf-8", errors="replace")[:2000]


def _page_of(store: type, path: Path, empty: type, params: dict, filter_by: str) -> Any:
    """A page of a store (`offset`, `limit`, `order`, and its one filter), opened read-only for the query."""
    if not path.exists():
        return empty([], False)
    opened = store(path, readonly=True)
    try:
        return opened.page(_int(params, "offset", 0), _int(params, "limit", 100), params.get("order", "newest") != "oldest",
                           params.get(filter_by, ""))
    finally:
        opened.close()


def _int(params: dict, key: str, default: int, raw: str | None = None) -> int:
    """The integer parameter `key` (`raw`: one item of its comma list); a ValueError naming it
    when it is not one the stores can take (SQLite's, 64 bits)."""
    text = params.get(key, default) if raw is None else raw
    shown = f"{key}={params.get(key, default)!r}" + ("" if raw is None else f" (item {raw!r})")
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"parameter {shown} is not an integer") from None
    if not SQLITE_INT_MIN <= value <= SQLITE_INT_MAX:
        raise ValueError(f"parameter {shown} is out of range: allowed {SQLITE_INT_MIN} to {SQLITE_INT_MAX}")
    return value


def _ints(params: dict, key: str) -> list[int]:
    """The comma list of integers `key` (alarm codes)."""
    items = params[key].split(",")
    return [_int(params, key, 0, item if len(items) > 1 else None) for item in items]


def _opt_int(params: dict, key: str) -> int | None:
    return _int(params, key, 0) if key in params else None

