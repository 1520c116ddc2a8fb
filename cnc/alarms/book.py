"""The alarm book: the one owner of the active-alarm list, which stores every change before it tells anyone."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cnc.alarms.catalogue import AlarmAction, AlarmLevel, Catalogue, CatalogueEntry
from cnc.alarms.history import MAX_PAGE, AlarmHistory
from cnc.bus.messages import ActiveAlarm, AlarmEvent, AlarmList

if TYPE_CHECKING:
    from cnc.alarms.recorder import Recorder


@dataclass
class _Record:
    """One alarm in the active list: the entry that raised it and what happened since."""

    raised: AlarmEvent
    level: AlarmLevel
    active: bool = True  # the condition is still present
    acknowledged: bool = False

    def message(self) -> ActiveAlarm:
        r = self.raised
        return ActiveAlarm(
            r.code, r.id, r.level, r.text, r.detail, r.source, r.seq, r.stamp_ns, self.active, self.acknowledged
        )


class AlarmBook:
    """Raises, clears, acknowledges and resets alarms, and gives one-shot operator messages.

    An alarm is identified by its catalogue id and its detail (a following error on X and one on
    Y are two alarms). Raised, it is active; when its condition goes away (`clear`) it stays
    listed, latched, until the operator resets it, as grblHAL's alarms lock until reset. Info-level
    entries are prompts, not faults: they are not latched and leave the list when cleared.

    Every change is appended to the history, committed, applied to the list and only then handed
    to `publish`, all under one lock: subscribers see entries in sequence order, and every entry
    they see is on disk. With a `Recorder` the list changes at once and the entry is numbered at
    once, while storing and publishing happen in order on the recorder's thread (the control
    logic's scan never waits for a disk or the network). At construction the list is rebuilt by
    replaying the history, so a crashed and restarted owner still knows its alarms.
    """

    def __init__(
        self,
        catalogue: Catalogue,
        history: AlarmHistory,
        publish: Callable[[AlarmEvent], None],
        clock_ns: Callable[[], int] = time.time_ns,
        recorder: "Recorder | None" = None,
    ) -> None:
        self.catalogue = catalogue
        self.history = history
        self._publish = publish
        self._clock_ns = clock_ns
        self.recorder = recorder
        # Reentrant: a publish callback may read the book (active(), blocking()) on this thread.
        self._lock = threading.RLock()
        self._records: dict[tuple[str, str], _Record] = {}
        self._last_seq = history.last_seq()
        self._replay()

    # -- the condition side: the controller's logic ---------------------------------------

    def raise_(self, id: str, detail: str = "", source: str = "") -> bool:
        """Raise the alarm `id` (with `detail` saying what was found); returns whether it is new.
        Raising an alarm that is already active with the same id and detail writes nothing, so
        a condition checked every cycle may raise every cycle. A latched (cleared) one is raised
        anew: a new entry, active and unacknowledged again."""
        entry = self.catalogue.entry(id)
        with self._lock:
            record = self._records.get((id, detail))
            if record is not None and record.active:
                return False
            self._commit(self._event_from_catalogue(entry, AlarmAction.RAISED, detail, source))
            return True

    def clear(self, id: str, detail: str | None = None) -> bool:
        """The condition of alarm `id` went away (of every instance of it when `detail` is None).
        Returns whether an active alarm was cleared. Latched levels stay listed until reset."""
        self.catalogue.entry(id)
        with self._lock:
            cleared = [r for r in self._matching(id, detail) if r.active]
            for record in cleared:
                self._commit(self._follow_up(record, AlarmAction.CLEARED))
            return bool(cleared)

    def message(self, id: str, detail: str = "", source: str = "") -> AlarmEvent:
        """Give the operator a one-shot message: stored and published, never in the active list.
        Only info-level catalogue entries are messages (a warning or worse is a condition: raise it)."""
        entry = self.catalogue.entry(id)
        if entry.level is not AlarmLevel.INFO:
            raise ValueError(
                f"alarm {id!r} is level {entry.level.text}: only info-level entries are one-shot messages, raise_() it"
            )
        with self._lock:
            event = self._store(self._event_from_catalogue(entry, AlarmAction.RAISED, detail, source))
            if self.recorder is None:
                self._publish(event)
            return event

    # -- the operator side -------------------------------------------------------------------

    def acknowledge(self, code_or_id: int | str | None = None) -> int:
        """The operator has seen the alarm named by code or id (every listed alarm when None).
        Returns how many were newly acknowledged; an unknown code or id is an UnknownAlarm."""
        id = None if code_or_id is None else self.catalogue.lookup(code_or_id).id
        with self._lock:
            pending = [r for r in self._matching(id, None) if not r.acknowledged]
            for record in pending:
                self._commit(self._follow_up(record, AlarmAction.ACKNOWLEDGED))
            return len(pending)

    def reset(self) -> list[ActiveAlarm]:
        """Remove every cleared alarm from the list (a "reset" entry each). Returns the alarms
        that could not be reset because their condition is still active: the caller tells the
        operator what to fix. Active info-level prompts are neither reset nor reported."""
        with self._lock:
            for record in [r for r in self._records.values() if not r.active]:
                self._commit(self._follow_up(record, AlarmAction.RESET))
            return [r.message() for r in self._records.values() if r.level.latched]

    # -- the state ---------------------------------------------------------------------------

    def active(self) -> AlarmList:
        """The alarms raised and not reset, oldest first, and the newest sequence number."""
        with self._lock:
            records = sorted(self._records.values(), key=lambda r: r.raised.seq)
            return AlarmList([r.message() for r in records], self._last_seq)

    def blocking(self) -> bool:
        """Whether a fatal or error alarm is listed, active or latched: the machine must not start."""
        with self._lock:
            return any(r.level.stops_cut for r in self._records.values())

    def highest_level(self) -> AlarmLevel | None:
        """The most severe level in the list, None when it is empty."""
        with self._lock:
            return max((r.level for r in self._records.values()), default=None)

    @property
    def last_seq(self) -> int:
        """The sequence number of the newest history entry."""
        with self._lock:
            return self._last_seq

    def prune(self, keep_days: float) -> int:
        """Delete history entries older than `keep_days`, but none the listed alarms were raised
        by or after (the list must survive the next restart). Returns how many were deleted."""
        with self._lock:
            oldest = min((r.raised.seq for r in self._records.values()), default=None)
            return self.history.prune(keep_days, now_ns=self._clock_ns(), keep_from_seq=oldest)

    # -- inside ----------------------------------------------------------------------------

    def _matching(self, id: str | None, detail: str | None) -> list[_Record]:
        return [
            r for (rid, rdetail), r in self._records.items()
            if (id is None or rid == id) and (detail is None or rdetail == detail)
        ]

    def _event_from_catalogue(self, entry: CatalogueEntry, action: AlarmAction, detail: str, source: str) -> dict:
        return dict(
            code=entry.code, id=entry.id, level=entry.level, action=action, text=entry.text,
            detail=detail, source=source, cause=entry.cause, remedy=entry.remedy,
        )

    def _follow_up(self, record: _Record, action: AlarmAction) -> dict:
        """An entry about a listed alarm: its raising entry's fields with a new action. From the
        record, not the catalogue, so an alarm replayed after its id left the machine file works."""
        r = record.raised
        return dict(
            code=r.code, id=r.id, level=record.level, action=action, text=r.text,
            detail=r.detail, source=r.source, cause=r.cause, remedy=r.remedy,
        )

    def _store(self, fields: dict) -> AlarmEvent:
        if self.recorder is not None:
            f = fields
            event = AlarmEvent(self._last_seq + 1, self._clock_ns(), f["code"], f["id"], AlarmLevel(f["level"]).text,
                               AlarmAction(f["action"]).value, f["text"], f["detail"], f["source"], f["cause"], f["remedy"])
            self._last_seq = event.seq
            self.recorder.submit(lambda: self._record(event))
            return event
        event = self.history.append(stamp_ns=self._clock_ns(), **fields)
        self._last_seq = event.seq
        return event

    def _record(self, event: AlarmEvent) -> None:
        """The recorder's thread: store, then publish."""
        self.history.append_event(event)
        self.recorder.committed_seq = event.seq
        self._publish(event)

    def _commit(self, fields: dict) -> None:
        """Store, apply, then publish: in this order, so that what subscribers hear is on disk and
        a publish callback that reads the book sees the change (with a recorder: numbered and
        applied now, stored then published by the recorder)."""
        event = self._store(fields)
        self._apply(event)
        if self.recorder is None:
            self._publish(event)

    def _apply(self, event: AlarmEvent) -> None:
        """One entry's effect on the list; the same for live changes and for the replay."""
        key = (event.id, event.detail)
        action = AlarmAction.parse(event.action)
        if action is AlarmAction.RAISED:
            self._records[key] = _Record(event, AlarmLevel.parse(event.level))
            return
        record = self._records.get(key)
        if record is None:
            return
        if action is AlarmAction.CLEARED:
            record.active = False
            if not record.level.latched:
                del self._records[key]
        elif action is AlarmAction.ACKNOWLEDGED:
            record.acknowledged = True
        elif action is AlarmAction.RESET:
            del self._records[key]

    def _replay(self) -> None:
        """Rebuild the list from the whole history. Info-level entries are skipped: one-shot
        messages are stored as info "raised" entries too, and info prompts are not latched, so
        the live logic raises them again if their condition is still there. An alarm whose id
        the machine file no longer declares can never be cleared, so it comes back latched:
        listed, and removed by the next reset."""
        seq = 0
        while True:
            page = self.history.after(seq, MAX_PAGE)
            for event in page.entries:
                if event.level != AlarmLevel.INFO.text:
                    self._apply(event)
            if not page.more:
                break
            seq = page.entries[-1].seq
        for (id, _), record in self._records.items():
            if id not in self.catalogue:
                record.active = False
