"""Every Zenoh key of a machine, built in one place: `<prefix>/<machine>/...`."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Keys:
    """The key space of one machine."""

    prefix: str
    machine: str

    @property
    def root(self) -> str:
        return f"{self.prefix}/{self.machine}"

    @property
    def status(self) -> str:
        return f"{self.root}/status"

    @property
    def position(self) -> str:
        return f"{self.root}/position"

    def planner(self, verb: str) -> str:
        """The planner's command queryable for one verb (controller-internal: the commander asks)."""
        return f"{self.root}/internal/planner/{verb}"

    def supervisor(self, what: str) -> str:
        """The supervisor's queryables (controller-internal): `sim` lists the simulated machine's
        inputs, `sim/set` changes one (the gateway asks, behind the lock)."""
        return f"{self.root}/internal/supervisor/{what}"

    @property
    def sim(self) -> str:
        """The simulated machine's inputs (read-only query; changed with `cmd/sim`)."""
        return f"{self.root}/sim"

    def logic(self, verb: str) -> str:
        """The control logic's command queryable for one verb (the gateway and tests ask)."""
        return f"{self.root}/internal/logic/{verb}"

    @property
    def event_alarm(self) -> str:
        return f"{self.root}/event/alarm"

    @property
    def procedure(self) -> str:
        return f"{self.root}/procedure"

    @property
    def procedures(self) -> str:
        """The catalogue of guided procedures (queryable)."""
        return f"{self.root}/procedures"

    @property
    def alarms_active(self) -> str:
        return f"{self.root}/alarms/active"

    @property
    def alarms_history(self) -> str:
        return f"{self.root}/alarms/history"

    def cmd(self, verb: str, user: str = "local") -> str:
        """An operator command sent by `user` (the gateway answers; roles and the command lock
        apply). Only `user` may query under `u/<user>/**`: the router's rules say who sent it."""
        return f"{self.root}/u/{user}/cmd/{verb}"

    def cmd_any(self, verb: str) -> str:
        """Every user's command key for `verb` (what the gateway declares)."""
        return f"{self.root}/u/*/cmd/{verb}"

    def user_param(self, user: str, name: str) -> str:
        """Changing control parameter `name` (a SetParam payload), sent by `user` (an engineer)."""
        return f"{self.root}/u/{user}/param/{name}"

    def user_params(self, user: str) -> str:
        """Saving the control parameters in force into the machine file, asked by `user`."""
        return f"{self.root}/u/{user}/params"

    def user_of(self, key: str) -> str:
        """The user a key under `u/<user>/` belongs to ("" for any other key)."""
        head = f"{self.root}/u/"
        return key[len(head):].split("/", 1)[0] if key.startswith(head) else ""

    @property
    def lock(self) -> str:
        return f"{self.root}/lock"

    @property
    def programs(self) -> str:
        """Query: the program library (`ProgramList`)."""
        return f"{self.root}/programs"

    @property
    def materials(self) -> str:
        """Query: the material library (`MaterialList`), for the job set-up."""
        return f"{self.root}/materials"

    @property
    def control_programs(self) -> str:
        """Query: the axis control programs, the one running and the one selected (`ControlProgramList`)."""
        return f"{self.root}/control/programs"

    @property
    def program_preview(self) -> str:
        """Query `?name=<percent-encoded name>`: a stored program's text and path (`ProgramInfo`)."""
        return f"{self.root}/programs/preview"

    @property
    def program(self) -> str:
        return f"{self.root}/program"

    def param(self, name: str) -> str:
        """One control parameter (`axis.x.kp_1_s`): read it, or change it with a SetParam payload."""
        return f"{self.root}/param/{name}"

    @property
    def params(self) -> str:
        """Every control parameter; a SaveParams payload writes them into the machine file."""
        return f"{self.root}/params"

    def log(self, what: str) -> str:
        """The data logger: `state`, `start`, `stop`, `live` (put) and `runs/<n>`."""
        return f"{self.root}/log/{what}"

    @property
    def audit_history(self) -> str:
        """The audit trail: every command, who sent it and its answer (queryable)."""
        return f"{self.root}/audit/history"

    @property
    def jobs_history(self) -> str:
        return f"{self.root}/jobs/history"

    def station(self, station: str, user: str = "local", session: str = "") -> str:
        """Liveliness token of an operator station (HMI) of `user`, one per Zenoh session
        (`session`: its id): its presence is the station's "network alive"."""
        return f"{self.root}/hmi/{user}/{station}" + (f"/{session}" if session else "")

    def ping(self, station: str, user: str = "local", session: str = "") -> str:
        """A station answers here (`OperatorStation`): the gateway asks the lock holder's regularly,
        so a station behind a dead link is lost even where the link's lease does not expire it."""
        return f"{self.root}/ping/{user}/{station}" + (f"/{session}" if session else "")

    @property
    def stations(self) -> str:
        return f"{self.root}/hmi/**"

    def alive(self, process: str) -> str:
        """Liveliness token of one controller process (or HMI station)."""
        return f"{self.root}/alive/{process}"

    @property
    def alive_all(self) -> str:
        return f"{self.root}/alive/**"
