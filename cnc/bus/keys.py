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
    def alarms_active(self) -> str:
        return f"{self.root}/alarms/active"

    @property
    def alarms_history(self) -> str:
        return f"{self.root}/alarms/history"

    def alive(self, process: str) -> str:
        """Liveliness token of one controller process (or HMI station)."""
        return f"{self.root}/alive/{process}"

    @property
    def alive_all(self) -> str:
        return f"{self.root}/alive/**"
