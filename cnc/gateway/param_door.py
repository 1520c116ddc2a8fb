"""The gateway's door for control parameters: read and change them online over Zenoh, save them.

`<root>/param/<name>` answers the parameter (ParamInfo) and `<root>/params` every parameter
(ParamList), to any station. Changes go to the sender's own key `<root>/u/<user>/param/<name>`
(a SetParam payload), saves to `<root>/u/<user>/params` (SaveParams), which the router lets only
that user send: the user must be an engineer whose station holds the command lock, the value in
range, changeable in the current state, and the machine file's cross-checks must hold with the
values in force (fifo_high_ms above fifo_low_ms, ...); else the reply refuses, saying why. The
new value goes into the `params` block, of which this door is the only writer; the reply waits
until the owning process has applied it and says at which tick. A save writes the values in
force into the machine file. The routes are on the gateway's command service, on a lane of
their own: a change waits for the servo's next tick, and no Zenoh callback thread may wait.
"""
from __future__ import annotations

import logging
import time

import zenoh

from .. import params
from ..bus.keys import Keys
from ..bus.messages import ParamInfo, ParamList, Reply, SaveParams, SetParam
from ..bus.service import CommandRefused, CommandService, Request, Route
from ..config import ConfigError, MachineConfig, cross_check, load_machine
from ..data.dataserver import SharedArea
from ..data.layout import PlannerState, Proc
from ..interlock import process_gone

log = logging.getLogger(__name__)

APPLY_TIMEOUT_S = 2.0  # how long a change waits for its process to apply it


class ParamDoor:
    """The parameter routes, on `service` (the gateway's: its roles, command lock and audit trail)."""

    def __init__(self, config: MachineConfig, session: zenoh.Session, keys: Keys, area: SharedArea,
                 service: CommandService) -> None:
        self.config, self.session, self.keys = config, session, keys
        self.specs = params.registry(config)
        self.out = area.writer("params")
        self.out.load_current()
        if self.out.get("change") == 0:  # first start: the machine file's values (a restarted gateway keeps the block's)
            self._write(params.values_of(config, self.specs), 0)
        self.servo, self.motion = area.reader("servo"), area.reader("motion")
        self.pids = area.blocks["heartbeat"].array[0]["pid"]
        name_of = self.name_of
        service.serve(  # reads on the public keys; changes and saves on the sender's own keys
            Route("param", keys.param("**"), self._read_one, read=True, lane="param", audit=True,
                  what=lambda key: f"param {name_of(key)}"),
            Route("params", keys.params, self._read_all, read=True, lane="param", audit=True, what=lambda _key: "params"),
            Route("set_param", keys.user_param("*", "**"), self._change, SetParam, role="engineer", lock=True,
                  lane="param", audit=True, what=lambda key: f"param {name_of(key)}"),
            Route("save_params", keys.user_params("*"), lambda _request: self.save(), SaveParams, role="engineer",
                  lock=True, lane="param", audit=True, what=lambda _key: "save params"),
        )

    def name_of(self, key: str) -> str:
        """The parameter a key names: `param/<name>` or `u/<user>/param/<name>`."""
        if key.startswith(self.keys.param("")):
            return key[len(self.keys.param("")):]
        return key[len(self.keys.user_param(self.keys.user_of(key), "")):]

    # -- the block --------------------------------------------------------------------------------

    def values(self) -> list[float]:
        return list(self.out.get("values"))[: len(self.specs)]

    def _write(self, values: list[float], seq: int) -> None:
        slots = list(self.out.get("values"))
        slots[: len(values)] = values
        self.out.set("values", slots)
        self.out.set("change", seq)
        self.out.publish()

    # -- the routes -------------------------------------------------------------------------------

    def _read_one(self, request: Request) -> ParamInfo | Reply:
        name = self.name_of(request.key)
        if request.payload:
            return self._read_only(f"change {name}")
        if "*" in name:  # a reply must name one key: the list is at `params`
            raise CommandRefused(f"ask {self.keys.params} for every parameter")
        try:
            return self.info(params.find(self.specs, name), self.file_values())
        except params.ParamError as exc:
            raise CommandRefused(str(exc)) from None

    def _read_all(self, request: Request) -> ParamList | Reply:
        return self._read_only("save the control parameters") if request.payload else self.list()

    def _read_only(self, what: str) -> Reply:
        """A change or a save sent to the public, read-only keys: refused, saying where it goes."""
        return Reply(False, f"cannot {what} here: {self.keys.param('')}** and {self.keys.params} are read-only; "
                            f"an engineer sends it on u/<user>/ (OperatorStation.set_param, save_params)")

    def _change(self, request: Request) -> Reply:
        name = self.name_of(request.key)
        try:
            return self.set(params.find(self.specs, name), request.message.value)
        except params.ParamError as exc:
            raise CommandRefused(str(exc)) from None

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
        """Whether the controller process `process` ("servo", "planner") runs: the pid its heartbeat
        slot names is alive. (Not a liveliness query: Zenoh 1.10 answers one with nothing, at times, on
        a session with a liveliness subscriber with history, as the gateway's; bench/zenoh_liveliness_get.py.)"""
        pid = int(self.pids[Proc[process.upper()]])
        return pid > 0 and not process_gone(pid)

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
