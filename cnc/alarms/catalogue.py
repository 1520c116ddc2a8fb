"""The alarm and message catalogue: the machine file's `[[alarm]]` entries, looked up by id or code."""

from __future__ import annotations

import enum
from collections.abc import Iterator
from dataclasses import dataclass

from cnc.bus.states import AlarmLevel  # noqa: F401 - defined with the schemas, shared with the HMI
from cnc.config import MachineConfig


class AlarmAction(enum.Enum):
    """What a history entry records about an alarm; the value is the `AlarmEvent.action` text."""

    RAISED = "raised"  # the condition appeared (or a one-shot message was given)
    CLEARED = "cleared"  # the condition went away; a latched alarm waits for reset
    ACKNOWLEDGED = "acknowledged"  # the operator has seen it
    RESET = "reset"  # the operator reset it: it leaves the active list

    @classmethod
    def parse(cls, text: str) -> AlarmAction:
        """The action named by `text`; ValueError naming it when unknown."""
        try:
            return cls(text)
        except ValueError:
            known = ", ".join(a.value for a in cls)
            raise ValueError(f"alarm action {text!r} is not one of {known}") from None


class UnknownAlarm(KeyError):
    """An alarm id or code that is not in the catalogue (a programming or configuration error)."""

    def __str__(self) -> str:
        # KeyError's own __str__ shows the repr of its argument, quotes and all.
        return str(self.args[0])


@dataclass(frozen=True)
class CatalogueEntry:
    """One alarm or message as declared in the machine file, with its level parsed."""

    code: int
    id: str
    level: AlarmLevel
    text: str
    cause: str = ""
    remedy: str = ""


class Catalogue:
    """All alarms and messages the machine knows, from the machine file's `[[alarm]]` entries.
    The config loader has already refused duplicate codes and ids; this is the lookup."""

    def __init__(self, config: MachineConfig) -> None:
        self.source = config.source
        self._by_id: dict[str, CatalogueEntry] = {}
        self._by_code: dict[int, CatalogueEntry] = {}
        for a in config.alarm:
            entry = CatalogueEntry(a.code, a.id, AlarmLevel.parse(a.level), a.text, a.cause, a.remedy)
            self._by_id[entry.id] = entry
            self._by_code[entry.code] = entry

    def entry(self, id: str) -> CatalogueEntry:
        """The entry with this id; UnknownAlarm naming the id and the machine file otherwise."""
        try:
            return self._by_id[id]
        except KeyError:
            raise UnknownAlarm(f"alarm id {id!r} is not in the [[alarm]] catalogue of {self.source}") from None

    def by_code(self, code: int) -> CatalogueEntry:
        """The entry with this numeric code; UnknownAlarm naming the code and the machine file otherwise."""
        try:
            return self._by_code[code]
        except KeyError:
            raise UnknownAlarm(f"alarm code {code} is not in the [[alarm]] catalogue of {self.source}") from None

    def lookup(self, code_or_id: int | str) -> CatalogueEntry:
        """The entry named by a code (int) or an id (str), as an operator command gives it."""
        if isinstance(code_or_id, int):
            return self.by_code(code_or_id)
        return self.entry(code_or_id)

    def __contains__(self, id: object) -> bool:
        return id in self._by_id

    def __iter__(self) -> Iterator[CatalogueEntry]:
        """Entries in the machine file's order."""
        return iter(self._by_id.values())

    def __len__(self) -> int:
        return len(self._by_id)
