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

    def alive(self, process: str) -> str:
        """Liveliness token of one controller process (or HMI station)."""
        return f"{self.root}/alive/{process}"

    @property
    def alive_all(self) -> str:
        return f"{self.root}/alive/**"
