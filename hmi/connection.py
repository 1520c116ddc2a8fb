"""The HMI's one Zenoh session to the controller: subscriptions into the model, catch-up, watchdog, commands."""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from urllib.parse import quote

import msgspec
import zenoh

from cnc.bus.certs import TlsFiles
from cnc.bus.keys import Keys
from cnc.bus.messages import (
    AlarmEvent, AlarmList, HistoryPage, LockRequest, LockState, LogLive, LogRunData, LogStart, LogState, MaterialList, ControlProgramList,
    ParamList, Position, ProcedureCatalogue, ProcedureState, ProgramInfo, ProgramList, Reply, SimInput, SimInputs, Status,
    StopAll, decode,
)
from cnc.bus.operator import OperatorStation
from cnc.bus.session import LOCAL_USER, open_client

from .commands import describe
from .model import HISTORY_KEPT, MachineModel
from .tuning_model import TuningModel

log = logging.getLogger(__name__)

STATUS_TIMEOUT_S = 1.5  # no status for this long: the controller is unreachable
QUERY_TIMEOUT_S = 3.0  # how long a catch-up query may wait for its answer
PAGE_SIZE = 500  # history entries per query (the controller caps a page at 1000)
POLL_PERIOD_S = 0.1  # the worker's watchdog and catch-up period
GAP_GRACE_S = 0.5  # a status may announce an entry before its event arrives: wait this long
TUNING_REFRESH_S = 2.0  # the parameters and the logger's runs are read again this often
SEARCH_LIMIT = 1000  # entries a search of the controller's history returns at most
OPEN_RETRY_S = 1.0  # no router accepted the session: try again this often
ACTIVE_RECHECK_S = 1.0  # a status whose alarm count differs from the model's re-reads the list this often

_DECODE_ERRORS = (msgspec.ValidationError, msgspec.DecodeError)  # SchemaVersionError is a ValueError: below


class NoAnswer(RuntimeError):
    """A catch-up query got no usable answer (the controller is away or answered with an error)."""


class Connection:
    """One operator station's link: a client session, the station's liveliness token, the live
    subscriptions feeding `model`, and a worker thread that watches the status, catches up on
    what was missed (at start and after every reconnect) and fills alarm sequence gaps.

    Zenoh callbacks only decode and apply (never block, never raise); every query runs on the
    worker thread. The model's observers therefore run on Zenoh's threads or on the worker.
    """

    def __init__(
        self, model: MachineModel, endpoints: list[str], keys: Keys, station: str,
        credentials: tuple[str, str] | None = None, status_timeout_s: float = STATUS_TIMEOUT_S,
        tuning: TuningModel | None = None, tls: TlsFiles | None = None,
    ) -> None:
        """`tuning`: also follow the control parameters and the data logger (the tuning windows);
        `tls`: the station's TLS files for `tls/` endpoints (`cnc.bus.certs`)."""
        self.tls = tls
        self.model, self.endpoints, self.keys, self.station = model, endpoints, keys, station
        self.tuning = tuning
        self._next_tuning = 0.0
        self.credentials, self.status_timeout_s = credentials, status_timeout_s
        self.session: zenoh.Session | None = None
        self.operator: OperatorStation | None = None
        self._subscribers: list[zenoh.Subscriber] = []
        self._lock = threading.Lock()
        self._last_status_at: float | None = None  # monotonic time of the last status decoded
        self._contiguous_seq = 0  # every history entry up to here is in the model
        self._gap = threading.Event()  # an event skipped sequence numbers: read the history
        self._ahead_since: float | None = None
        self._next_active_check = 0.0
        self._caught_up = False
        self._error_key: str | None = None  # the key whose unreadable message set the model's error
        self.last_open_error = ""  # why the session could not be opened yet ("" when it is open)
        self._next_open = 0.0
        self._stop = threading.Event()
        self._worker: threading.Thread | None = None

    # -- life --------------------------------------------------------------------------------

    def start(self) -> None:
        """Open the session, declare the station, subscribe, and start the worker. The first
        status (or the next after a loss) triggers the catch-up; until then the model is offline.
        When no router answers yet (the HMI came up before the controller), the worker keeps
        trying to open the session; meanwhile the model is offline and `last_open_error` says why."""
        self._stop.clear()
        self._try_open()
        self._worker = threading.Thread(target=self._run, name=f"hmi-connection-{self.station}", daemon=True)
        self._worker.start()

    def _try_open(self) -> bool:
        """Open the session and subscribe; False (and the reason kept) when no router accepts it."""
        try:
            session = open_client(self.endpoints, self.credentials, self.tls)
        except zenoh.ZError as exc:
            why = re.sub(r"\s+at /\S+$", "", str(exc).strip())  # Zenoh appends its source location
            self.last_open_error = f"cannot reach {', '.join(self.endpoints)}: {why}"
            return False
        self.last_open_error = ""
        handlers: dict[str, tuple[type[msgspec.Struct], Callable[[msgspec.Struct], None]]] = {
            self.keys.status: (Status, self._on_status),
            self.keys.position: (Position, self.model.apply_position),
            self.keys.event_alarm: (AlarmEvent, self._on_alarm),
            self.keys.procedure: (ProcedureState, self.model.apply_procedure),
            self.keys.lock: (LockState, self.model.apply_lock),
        }
        if self.tuning is not None:
            handlers[self.keys.log("live")] = (LogLive, self.tuning.apply_live)
        self._subscribers = [
            session.declare_subscriber(key, self._handler(key, kind, apply)) for key, (kind, apply) in handlers.items()
        ]
        user = self.credentials[0] if self.credentials else LOCAL_USER  # local: a station on the controller's host
        self.operator = OperatorStation(session, self.keys, self.station, user=user)
        self.session = session
        return True

    def close(self) -> None:
        """Stop the worker, drop the subscriptions and the station's token, close the session."""
        self._stop.set()
        if self._worker is not None:
            self._worker.join(timeout=QUERY_TIMEOUT_S * 3)
        for sub in self._subscribers:
            sub.undeclare()
        self._subscribers = []
        if self.operator is not None:
            self.operator.close()
        if self.session is not None:
            self.session.close()
        self.session = self.operator = None
        self.model.set_reachable(False)

    def __enter__(self) -> Connection:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- commands ------------------------------------------------------------------------------

    def command(self, msg: msgspec.Struct) -> Reply:
        """Send one operator command through the station; refused here, with the reason, when this
        station does not hold the command lock (a LockRequest always goes: it is how one takes it).
        Blocks until the controller answers: call it off the GUI thread or accept the wait."""
        refused = self._refuse(describe(msg), needs_lock=not isinstance(msg, (LockRequest, StopAll)))
        if refused is not None:
            return refused
        reply = self.operator.request(msg)
        if isinstance(msg, LockRequest) and reply.ok:
            self._refresh(self.keys.lock, LockState, self.model.apply_lock)
        elif isinstance(msg, SimInput):
            try:
                self._read_sim()  # the panel shows the values the controller now has
            except NoAnswer as exc:
                log.info("refresh: %s", exc)
        return reply

    def _read_sim(self) -> None:
        """The simulated machine's inputs; a controller that refuses (a real board) has none."""
        session = self.session
        if session is None:
            return
        for reply in session.get(self.keys.sim, timeout=QUERY_TIMEOUT_S):
            if reply.ok is None:
                self.model.apply_sim_inputs(None)
                return
            inputs = self._decode(self.keys.sim, reply.ok.payload.to_bytes(), SimInputs)
            if inputs is not None:
                self.model.apply_sim_inputs(inputs)
            return
        raise NoAnswer(f"{self.keys.sim}: no answer within {QUERY_TIMEOUT_S:g} s")

    # -- callbacks (Zenoh's threads) -------------------------------------------------------------

    def _handler(self, key: str, kind: type[msgspec.Struct], apply: Callable[[msgspec.Struct], None]
                 ) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            msg = self._decode(key, sample.payload.to_bytes(), kind)
            if msg is None:
                return
            try:
                apply(msg)
            except Exception:  # a bug: logged with its traceback, never raised into Zenoh
                log.exception("%s: applying %s failed", key, kind.__name__)
                self.model.set_error(f"{key}: internal error applying {kind.__name__} (see the log)")
        return on_sample

    def _decode(self, key: str, payload: bytes, kind: type[msgspec.Struct]) -> msgspec.Struct | None:
        """Decode or set the model's error text (another schema version, malformed JSON): None.
        The text stays until a message on the same key is read again."""
        try:
            msg = decode(payload, kind)
        except (*_DECODE_ERRORS, ValueError) as exc:
            with self._lock:
                self._error_key = key
            self.model.set_error(f"{key}: cannot read the controller's {kind.__name__}: {exc}")
            return None
        with self._lock:
            recovered = self._error_key == key
            if recovered:
                self._error_key = None
        if recovered:
            self.model.set_error("")
        return msg

    def _on_status(self, status: Status) -> None:
        with self._lock:
            self._last_status_at = time.monotonic()
        self.model.apply_status(status)

    def _on_alarm(self, event: AlarmEvent) -> None:
        self.model.apply_alarm(event)
        with self._lock:
            if not self._caught_up:
                return  # the catch-up reads the history anyway
            if event.seq == self._contiguous_seq + 1:
                self._contiguous_seq = event.seq
            elif event.seq > self._contiguous_seq + 1:
                self._gap.set()

    # -- the worker ------------------------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.wait(POLL_PERIOD_S):
            try:
                self.poll()
            except Exception:  # a bug: logged, shown, and the watchdog keeps running
                log.exception("the HMI connection's worker failed")
                self.model.set_error("connection: internal error (see the log)")

    def poll(self) -> None:
        """One round of the watchdog and the catch-up (the worker calls it every POLL_PERIOD_S)."""
        if self.session is None:
            if time.monotonic() >= self._next_open and not self._try_open():
                self._next_open = time.monotonic() + OPEN_RETRY_S
            if self.session is None:
                return
        with self._lock:
            heard = self._last_status_at is not None and time.monotonic() - self._last_status_at < self.status_timeout_s
        if not heard:
            with self._lock:
                self._caught_up = False  # whatever comes back is caught up with first
            self.model.set_reachable(False)
            return
        self.model.set_reachable(True)  # status flows
        if not self._caught_up:
            done = self.catch_up()  # a failed one is retried next round
            with self._lock:
                self._caught_up = done
            return
        self._keep_up()

    def catch_up(self) -> bool:
        """Read what the subscriptions may have missed: the history after the last entry seen, the
        active alarms, the lock, the program and the procedure catalogue. Returns whether every query answered."""
        try:
            self._read_history()
            self._read(self.keys.alarms_active, AlarmList, self.model.apply_active)
            self._read(self.keys.lock, LockState, self.model.apply_lock)
            self._read(f"{self.keys.program}?path=1", ProgramInfo, self.model.apply_program)
            self._read(self.keys.procedures, ProcedureCatalogue, self.model.apply_catalogue)
            self._read_sim()
        except NoAnswer as exc:
            log.info("catch-up incomplete: %s", exc)
            return False
        self._refresh_quietly()  # a controller without a logger still gets its operator screen
        return True

    def refresh_tuning(self) -> None:
        """Read the control parameters and the logger's state (runs, variables) again."""
        if self.tuning is None:
            return
        self._next_tuning = time.monotonic() + TUNING_REFRESH_S
        self._read(self.keys.params, ParamList, self.tuning.apply_params)
        self._read(self.keys.log("state"), LogState, self.tuning.apply_log_state)

    def _keep_up(self) -> None:
        """Fill alarm gaps, notice entries a status announces but no event brought, re-read the
        active list when its count disagrees, fetch a program the status names but we lack, and
        now and then the parameters and the logger's runs."""
        if self.tuning is not None and time.monotonic() >= self._next_tuning:
            try:
                self.refresh_tuning()
            except NoAnswer as exc:
                log.info("tuning refresh: %s", exc)
        status = self.model.status
        now = time.monotonic()
        behind = status is not None and status.alarm_seq > self._contiguous_seq
        if behind and self._ahead_since is None:
            self._ahead_since = now
        elif not behind:
            self._ahead_since = None
        try:
            if self._gap.is_set() or (behind and now - self._ahead_since >= GAP_GRACE_S):
                self._gap.clear()
                self._ahead_since = None
                self._read_history()
                self._read(self.keys.alarms_active, AlarmList, self.model.apply_active)
            elif status is not None and status.alarms_active != len(self.model.active_alarms) \
                    and now >= self._next_active_check:
                self._next_active_check = now + ACTIVE_RECHECK_S
                self._read(self.keys.alarms_active, AlarmList, self.model.apply_active)
            if self.model.program_outdated:
                self._read(f"{self.keys.program}?path=1", ProgramInfo, self.model.apply_program)
        except NoAnswer as exc:
            log.info("keeping up: %s", exc)

    def _read_history(self) -> None:
        """Every history entry after the last contiguous one, page by page, into the model."""
        while True:
            with self._lock:
                after = self._contiguous_seq
            status = self.model.status
            if after == 0 and status is not None and status.alarm_seq > HISTORY_KEPT:
                after = status.alarm_seq - HISTORY_KEPT  # a long history: the newest the model keeps; older by search
            page = self._query(f"{self.keys.alarms_history}?after={after};limit={PAGE_SIZE}", HistoryPage)
            self.model.apply_history(page)
            newest = page.entries[-1].seq if page.entries else page.last_seq
            with self._lock:
                self._contiguous_seq = max(self._contiguous_seq, newest)
            if not page.more or not page.entries:
                return

    # -- tuning and logging (blocking: call them off the GUI thread) ------------------------------

    def set_param(self, name: str, value: float) -> Reply:
        """Change one control parameter (this station must hold the command lock)."""
        refused = self._refuse(f"param {name}")
        if refused is not None:
            return refused
        reply = self.operator.set_param(name, value)
        self._refresh_quietly()
        return reply

    def save_params(self) -> Reply:
        refused = self._refuse("save params")
        if refused is not None:
            return refused
        reply = self.operator.save_params()
        self._refresh_quietly()
        return reply

    def log_start(self, start: LogStart) -> Reply:
        """Start a log run (no command lock needed: logging never moves the machine)."""
        refused = self._refuse("log start", needs_lock=False)
        reply = refused or self.operator.log_start(start)
        self._refresh_quietly()
        return reply

    def log_stop(self) -> Reply:
        refused = self._refuse("log stop", needs_lock=False)
        reply = refused or self.operator.log_stop()
        self._refresh_quietly()
        return reply

    def log_run(self, run: int) -> LogRunData:
        """A whole log run (for plots after the run and for export); NoAnswer when there is none."""
        return self._query(self.keys.log(f"runs/{run}"), LogRunData)

    def _refuse(self, what: str, needs_lock: bool = True) -> Reply | None:
        """Why `what` cannot be sent from here (not connected; read-only when it needs the lock), or None."""
        if self.operator is None:
            return Reply(False, f"{what}: not connected to the controller")
        if needs_lock and self.model.read_only:
            holder = self.model.lock_holder
            who = f"station {holder!r} holds the command lock" if holder else "nobody holds the command lock"
            return Reply(False, f"{what}: read-only: {who}; take the lock first")
        return None

    def _refresh_quietly(self) -> None:
        try:
            self.refresh_tuning()
        except NoAnswer as exc:
            log.info("tuning refresh: %s", exc)

    def search_history(self, text: str = "", levels: list[str] | None = None, codes: list[int] | None = None,
                       limit: int = SEARCH_LIMIT) -> HistoryPage:
        """The controller's whole history searched there (newest first): for entries older than the
        model keeps. Blocks for the round trip; NoAnswer when the controller does not answer."""
        params = [f"limit={limit}", "order=newest"]
        if text.strip():
            params.append("text=" + re.sub(r"[;=&?]", " ", text.strip()))  # the selector's separators
        if levels:
            params.append("level=" + ",".join(levels))
        if codes:
            params.append("code=" + ",".join(str(c) for c in codes))
        return self._query(f"{self.keys.alarms_history}?{';'.join(params)}", HistoryPage)

    def programs(self) -> ProgramList:
        """The controller's program library (blocking: off the GUI thread); NoAnswer when it does not answer."""
        return self._query(self.keys.programs, ProgramList)

    def materials(self) -> MaterialList:
        """The controller's material library, for the job set-up (blocking: off the GUI thread); NoAnswer
        when it does not answer."""
        return self._query(self.keys.materials, MaterialList)

    def control_programs(self) -> ControlProgramList:
        """The axis control programs, the running and the selected one (blocking: off the GUI thread);
        NoAnswer when the controller does not answer."""
        return self._query(self.keys.control_programs, ControlProgramList)

    def preview(self, name: str) -> ProgramInfo:
        """A stored program's text and path, without loading it (blocking); NoAnswer says why not."""
        return self._query(f"{self.keys.program_preview}?name={quote(name, safe='')}", ProgramInfo)

    def _read(self, selector: str, kind: type[msgspec.Struct], apply: Callable[[msgspec.Struct], None]) -> None:
        apply(self._query(selector, kind))

    def _refresh(self, selector: str, kind: type[msgspec.Struct], apply: Callable[[msgspec.Struct], None]) -> None:
        """Like `_read`, but an unanswered query only leaves the model as it is."""
        try:
            self._read(selector, kind, apply)
        except NoAnswer as exc:
            log.info("refresh: %s", exc)

    def _query(self, selector: str, kind: type[msgspec.Struct]) -> msgspec.Struct:
        """One query's decoded answer; NoAnswer when nobody answers, the answer is an error, or it
        cannot be read (the model's error then says why)."""
        session = self.session
        if session is None:
            raise NoAnswer(f"{selector}: not connected")
        for reply in session.get(selector, timeout=QUERY_TIMEOUT_S):
            if reply.ok is None:
                raise NoAnswer(f"{selector}: the controller answered with an error: {reply.err.payload.to_string()}")
            msg = self._decode(selector, reply.ok.payload.to_bytes(), kind)
            if msg is None:
                raise NoAnswer(f"{selector}: unreadable answer")
            return msg
        raise NoAnswer(f"{selector}: no answer within {QUERY_TIMEOUT_S:g} s")
