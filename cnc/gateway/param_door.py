"""The gateway's door for control parameters: read and change them online over Zenoh, save them.

`<root>/param/<name>` answers the parameter (ParamInfo) and `<root>/params` every parameter
(ParamList), to any station. Changes go to the sender's own key `<root>/u/<user>/param/<name>`
(a SetParam payload), saves to `<root>/u/<user>/params` (SaveParams), which the router lets only
that user send: the user must be an engineer whose station holds the command lock, the value in
range, changeable in the current state, and the machine file's cross-checks must hold with the
values in force (fifo_high_ms above fifo_low_ms, ...); else the reply refuses, saying why. The
new value goes into the `params` block, of which this door is the only writer; the reply waits
until the owning process has applied it and says at which tick. A save writes the values in
force into the machine file. Queries are served by a worker thread: a change waits for the
servo's next tick, and no Zenoh callback thread may wait.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

import msgspec
import zenoh

from .. import params
from .audit import AuditWriter
from ..bus.access import AccessRefused, Roles
from ..bus.keys import Keys
from ..bus.messages import ParamInfo, ParamList, Reply, SaveParams, SchemaVersionError, SetParam, decode, encode
from ..config import ConfigError, MachineConfig, cross_check, load_machine
from ..data.dataserver import SharedArea
from .door import station_of
from ..data.layout import PlannerState
from .lock import LockRefused, OperatorLock

log = logging.getLogger(__name__)

APPLY_TIMEOUT_S = 2.0  # how long a change waits for its process to apply it


class ParamDoor:
    """`param/**` and `params` queryables; `lock` is the gateway's command lock (None: no lock, any station)."""

    def __init__(self, config: MachineConfig, session: zenoh.Session, keys: Keys, area: SharedArea,
                 lock: OperatorLock | None, audit: AuditWriter | None = None) -> None:
        """`audit`: where changes and saves are recorded (the gateway's trail; None: not recorded)."""
        self.config, self.session, self.keys, self.lock, self.audit = config, session, keys, lock, audit
        self.roles = Roles.load(config)
        self.specs = params.registry(config)
        self.out = area.writer("params")
        self.out.load_current()
        if self.out.get("change") == 0:  # first start: the machine file's values (a restarted gateway keeps the block's)
            self._write(params.values_of(config, self.specs), 0)
        self.servo, self.motion = area.reader("servo"), area.reader("motion")
        self.queries: queue.Queue = queue.Queue()
        root = len(keys.param(""))
        self.declared = [  # reads on the public keys; changes and saves on the sender's own keys
            session.declare_queryable(keys.param("**"), lambda q: self.queries.put((str(q.key_expr)[root:], q, ""))),
            session.declare_queryable(keys.params, lambda q: self.queries.put(("", q, ""))),
            session.declare_queryable(keys.user_param("*", "**"), lambda q: self.queries.put(self._users(q))),
            session.declare_queryable(keys.user_params("*"), lambda q: self.queries.put(("", q, keys.user_of(str(q.key_expr))))),
        ]
        self.worker = threading.Thread(target=self._serve, name="param-door", daemon=True)
        self.worker.start()

    def close(self) -> None:
        for q in self.declared:
            q.undeclare()
        self.queries.put(None)
        self.worker.join(APPLY_TIMEOUT_S + 1.0)

    # -- the block --------------------------------------------------------------------------------

    def values(self) -> list[float]:
        return list(self.out.get("values"))[: len(self.specs)]

    def _write(self, values: list[float], seq: int) -> None:
        slots = list(self.out.get("values"))
        slots[: len(values)] = values
        self.out.set("values", slots)
        self.out.set("change", seq)
        self.out.publish()

    # -- serving ----------------------------------------------------------------------------------

    def _serve(self) -> None:
        while (item := self.queries.get()) is not None:
            name, query, user = item
            payload = query.payload.to_bytes() if query.payload is not None else b""
            station = station_of(query)  # read before the query is answered and dropped
            try:
                answer = self._answer(name, query, user)
            except Exception as exc:  # a bug: the door stays open, the station learns what happened
                log.exception("params: %r failed", name)
                answer = Reply(False, f"param {name}: internal error in the gateway: {exc!r}")
            if "*" in name:  # a reply must name one key: the list is at `params`
                query.reply_err(zenoh.ZBytes(f"param/{name}: ask {self.keys.params} for every parameter".encode()))
            elif isinstance(answer, str):  # a read that cannot be answered: the asker expects no Reply
                query.reply_err(zenoh.ZBytes(answer.encode()))
            else:
                query.reply(query.key_expr, encode(answer), encoding=zenoh.Encoding.APPLICATION_JSON)
            query.drop()
            if self.audit is not None and payload and isinstance(answer, Reply):  # a change or a save, not a read
                self.audit.record(user, station, f"param {name}" if name else "save params",
                                  payload.decode("utf-8", errors="replace")[:2000], answer.ok, answer.reason)

    def _users(self, query: Any) -> tuple[str, Any, str]:
        key = str(query.key_expr)
        user = self.keys.user_of(key)
        return key[len(self.keys.user_param(user, "")):], query, user

    def _answer(self, name: str, query: Any, user: str) -> msgspec.Struct | str:
        """The answer to a query; a text when a read must be answered with an error instead.
        `user`: who sent a change or a save (its own key); "" on the public, read-only keys."""
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            if payload and not user:
                what = "save the control parameters" if name == "" else f"change {name}"
                return Reply(False, f"cannot {what} here: {self.keys.param('')}** and {self.keys.params} are read-only; "
                                    f"an engineer sends it on u/<user>/ (OperatorStation.set_param, save_params)")
            if name == "":
                if payload:
                    self._require(user, query, "save the control parameters")
                    decode(payload, SaveParams)
                    return self.save()
                return self.list()
            if not payload:
                try:
                    return self.info(params.find(self.specs, name), self.file_values())
                except params.ParamError as exc:
                    return str(exc)
            spec = params.find(self.specs, name)
            self._require(user, query, f"change {name}")
            return self.set(spec, decode(payload, SetParam).value)
        except (msgspec.ValidationError, msgspec.DecodeError, SchemaVersionError) as exc:
            return Reply(False, f"param {name}: malformed request: {exc}")
        except (params.ParamError, LockRefused, AccessRefused) as exc:
            return Reply(False, str(exc))

    def _require(self, user: str, query: Any, what: str) -> None:
        """An engineer's station holding the command lock (the lock only where the gateway has one)."""
        self.roles.require(user, "engineer", f"cannot {what}")
        if self.lock is not None:
            try:
                self.lock.require(user, station_of(query))
            except LockRefused as exc:
                raise LockRefused(f"cannot {what}: {exc}") from None

    # -- what the door does -------------------------------------------------------------------------

    def list(self) -> ParamList:
        file_values = self.file_values()
        return ParamList([self.info(s, file_values) for s in self.specs], self.out.get("change"))

    def info(self, spec: params.ParamSpec, file_values: list[float]) -> ParamInfo:
        return ParamInfo(spec.name, spec.description, spec.unit, spec.lo, spec.hi, self.values()[spec.index],
                         file_values[spec.index], spec.owner, spec.when, spec.effect)

    def file_values(self) -> list[float]:
        """What the machine file says now (it may have been saved since the controller started)."""
        try:
            return params.values_of(load_machine(self.config.source), self.specs)
        except ConfigError:
            return params.values_of(self.config, self.specs)

    def set(self, spec: params.ParamSpec, value: float) -> Reply:
        """Check, write, and wait for the owning process to apply the change."""
        state = PlannerState(self.motion.read_dict()["state"]).name
        spec.check(value, state)
        values = self.values()
        old, values[spec.index] = values[spec.index], float(value)
        try:  # the machine file's own cross-checks (fifo_high_ms above fifo_low_ms, ...) on the values in force
            cross_check(params.with_values(self.config, self.specs, values))
        except ConfigError as exc:
            raise params.ParamError(f"{spec.name} = {value:g} refused: with the values in force, {exc}") from None
        seq = self.out.get("change") + 1
        self._write(values, seq)
        log.info("params: %s %g -> %g (change %d)", spec.name, old, value, seq)
        where = f"{spec.name} = {value:g}{' ' + spec.unit if spec.unit else ''} (was {old:g})"
        if not self._alive(spec.owner):
            return Reply(True, f"{where}; the {spec.owner} is not running: it applies it when it starts")
        reader = self.servo if spec.owner == "servo" else self.motion
        deadline = time.monotonic() + APPLY_TIMEOUT_S
        while (applied := reader.read_dict())["params_change"] < seq:
            if time.monotonic() > deadline:
                return Reply(True, f"{where}; written, but the {spec.owner} has not applied it within "
                                   f"{APPLY_TIMEOUT_S:g} s (it takes it at {spec.effect})")
            time.sleep(0.001)
        at = f" at tick {applied['params_tick']}" if spec.owner == "servo" else ""
        return Reply(True, f"{where}; applied by the {spec.owner}{at}; takes effect at {spec.effect}")

    def _alive(self, process: str) -> bool:
        """The controller process announces itself (its liveliness token)."""
        replies = self.session.liveliness().get(self.keys.alive(process), timeout=0.5)
        return any(r.ok is not None for r in replies)

    def save(self) -> Reply:
        """Write every parameter whose value differs from the machine file's into the file."""
        source = self.config.source
        try:
            file_values = params.values_of(load_machine(source), self.specs)
        except ConfigError as exc:
            return Reply(False, f"save: cannot read the machine file: {exc}")
        changes = {(s.path, s.key): v for s, v, f in zip(self.specs, self.values(), file_values) if v != f}
        if not changes:
            return Reply(True, f"save: {source} already holds every value in force")
        try:
            written = params.save(source, changes)
        except (ConfigError, OSError) as exc:
            return Reply(False, f"save: {source} was not changed: {exc}")
        log.info("params: saved %s into %s", ", ".join(written), source)
        return Reply(True, f"saved {len(written)} parameter(s) into {source} ({', '.join(written)}); "
                           f"the previous file is {source}.bak")
