"""Job history: every program run (program, hash, start, end, result, cycle time, planned cycle time) in SQLite.

Written by the control logic when a run ends, read by the gateway for `<root>/jobs/history`.
It lives beside the alarm history, in its own file (WAL mode: one writer, readers in other
processes see each committed run).
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from ..bus.messages import JobPage, JobRecord
from .store import open_store, page_rows

_TABLE = ("CREATE TABLE IF NOT EXISTS jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, program TEXT NOT NULL, "
          "hash TEXT NOT NULL, start_ns INTEGER NOT NULL, end_ns INTEGER NOT NULL, result TEXT NOT NULL, "
          "cycle_time_s REAL NOT NULL, planned_s REAL NOT NULL DEFAULT -1)")
_COLUMNS = "seq, program, hash, start_ns, end_ns, result, cycle_time_s"


def jobs_path(history_path: str | Path) -> Path:
    """The job history beside the alarm history."""
    return Path(history_path).with_name("jobs.sqlite")


class JobHistory:
    """Program runs, numbered in the order they ended."""

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.path = Path(path)
        self.db = open_store(self.path, _TABLE, "job history", readonly)
        if not readonly and not self._has_planned():  # a history written before the planned time was kept
            self.db.execute("ALTER TABLE jobs ADD COLUMN planned_s REAL NOT NULL DEFAULT -1")
            self.db.commit()

    def _has_planned(self) -> bool:
        return any(row[1] == "planned_s" for row in self.db.execute("PRAGMA table_info(jobs)"))

    def append(self, program: str, hash: str, start_ns: int, end_ns: int, result: str, cycle_time_s: float,
               planned_s: float = -1.0) -> JobRecord:
        """Record a run: its machine time and its planned cycle time at 100 % override (-1 when the
        planner had not finished timing it)."""
        cur = self.db.execute(
            "INSERT INTO jobs (program, hash, start_ns, end_ns, result, cycle_time_s, planned_s) VALUES (?, ?, ?, ?, ?, ?, ?)",
            (program, hash, start_ns, end_ns, result, cycle_time_s, planned_s),
        )
        self.db.commit()
        return JobRecord(cur.lastrowid, program, hash, start_ns, end_ns, result, cycle_time_s, planned_s)

    def page(self, offset: int = 0, limit: int = 100, newest_first: bool = True, program: str = "") -> JobPage:
        """Runs, newest first by default, optionally of one program; `more` when the page is not the last."""
        columns = _COLUMNS + (", planned_s" if self._has_planned() else "")
        rows, more = page_rows(self.db, "jobs", columns, offset, limit, newest_first, "program" if program else "", program)
        return JobPage([JobRecord(*r) for r in rows], more)

    def last_runs(self) -> dict[str, JobRecord]:
        """Each program's last run, by program name."""
        columns = _COLUMNS + (", planned_s" if self._has_planned() else "")
        try:
            rows = self.db.execute(f"SELECT {columns} FROM jobs WHERE seq IN (SELECT MAX(seq) FROM jobs GROUP BY program)")
        except sqlite3.OperationalError as exc:  # its writer has not created the table yet
            if "no such table" in str(exc):
                return {}
            raise
        return {r[1]: JobRecord(*r) for r in rows}

    def close(self) -> None:
        self.db.close()
