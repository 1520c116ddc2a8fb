"""The audit trail: every command a station sent, who sent it, and what became of it.

Each command the gateway answers (accepted or refused, parameter changes and saves included) is
one row: when, the user (from the command key the router let only that user send), the station,
the verb, the command as sent (its JSON, a program upload by name and size only), ok or not and
the reason. A jog's refreshes (the dead-man, many a second) are left out; its start and stop are
in. The gateway owns the file (`audit.sqlite` beside the alarm history, WAL mode) and writes it
from a thread of its own: no command waits for the disk. A command's row is handed over before
its reply goes out, so the rows keep the order in which the commands were answered (handed over
after it, the next command of the same station, answered on another thread, could come first).
`<root>/audit/history` answers pages of it (`offset`, `limit`, `user`, `order`).
"""

from __future__ import annotations

import logging
import queue
import sqlite3
import threading
import time
from pathlib import Path

from ..bus.messages import AuditPage, AuditRecord
from .store import open_store, page_rows

log = logging.getLogger(__name__)

_TABLE = ("CREATE TABLE IF NOT EXISTS audit (seq INTEGER PRIMARY KEY AUTOINCREMENT, at_ns INTEGER NOT NULL, "
          "user TEXT NOT NULL, station TEXT NOT NULL, verb TEXT NOT NULL, command TEXT NOT NULL, "
          "ok INTEGER NOT NULL, reason TEXT NOT NULL)")
UNRECORDED = ("jog_refresh",)  # many a second while a key is held: the jog's start and stop are recorded


def audit_path(history_path: str | Path) -> Path:
    """The audit trail beside the alarm history."""
    return Path(history_path).with_name("audit.sqlite")


class AuditTrail:
    """The rows of the trail, numbered in the order they were written."""

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.path = Path(path)
        self.db = open_store(self.path, _TABLE, "audit trail", readonly)

    def append(self, at_ns: int, user: str, station: str, verb: str, command: str, ok: bool, reason: str) -> None:
        self.db.execute("INSERT INTO audit (at_ns, user, station, verb, command, ok, reason) VALUES (?, ?, ?, ?, ?, ?, ?)",
                        (at_ns, user, station, verb, command, int(ok), reason))
        self.db.commit()

    def page(self, offset: int = 0, limit: int = 100, newest_first: bool = True, user: str = "") -> AuditPage:
        """Rows, newest first by default, optionally of one user; `more` when the page is not the last."""
        rows, more = page_rows(self.db, "audit", "seq, at_ns, user, station, verb, command, ok, reason", offset, limit,
                               newest_first, "user" if user else "", user)
        return AuditPage([AuditRecord(r[0], r[1], r[2], r[3], r[4], r[5], bool(r[6]), r[7]) for r in rows], more)

    def close(self) -> None:
        self.db.close()


class AuditWriter:
    """Rows handed over without waiting, written by a thread of their own."""

    def __init__(self, path: str | Path) -> None:
        self.trail = AuditTrail(path)
        self.rows: queue.Queue = queue.Queue()
        self.written = 0
        self.thread = threading.Thread(target=self._write, name="audit", daemon=True)
        self.thread.start()

    def record(self, user: str, station: str, verb: str, command: str, ok: bool, reason: str) -> None:
        if verb not in UNRECORDED:
            self.rows.put((time.time_ns(), user, station, verb, command, ok, reason))

    def _write(self) -> None:
        while (row := self.rows.get()) is not None:
            try:
                self.trail.append(*row)
                self.written += 1
            except sqlite3.Error:  # the disk: the command was answered; the trail says what it lost in the log
                log.exception("audit: a row could not be written: %r", row)

    def close(self) -> None:
        self.rows.put(None)
        self.thread.join(5.0)
        self.trail.close()
