"""Job history: every program run (program, hash, start, end, result, cycle time) in SQLite.

Written by the control logic when a run ends, read by the gateway for `<root>/jobs/history`.
It lives beside the alarm history, in its own file (WAL mode: one writer, readers in other
processes see each committed run).
"""

from __future__ import annotations

from pathlib import Path

from ..bus.messages import JobPage, JobRecord
from .store import open_store, page_rows

_TABLE = ("CREATE TABLE IF NOT EXISTS jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, program TEXT NOT NULL, "
          "hash TEXT NOT NULL, start_ns INTEGER NOT NULL, end_ns INTEGER NOT NULL, result TEXT NOT NULL, "
          "cycle_time_s REAL NOT NULL)")


def jobs_path(history_path: str | Path) -> Path:
    """The job history beside the alarm history."""
    return Path(history_path).with_name("jobs.sqlite")


class JobHistory:
    """Program runs, numbered in the order they ended."""

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.path = Path(path)
        self.db = open_store(self.path, _TABLE, "job history", readonly)

    def append(self, program: str, hash: str, start_ns: int, end_ns: int, result: str, cycle_time_s: float) -> JobRecord:
        cur = self.db.execute(
            "INSERT INTO jobs (program, hash, start_ns, end_ns, result, cycle_time_s) VALUES (?, ?, ?, ?, ?, ?)",
            (program, hash, start_ns, end_ns, result, cycle_time_s),
        )
        self.db.commit()
        return JobRecord(cur.lastrowid, program, hash, start_ns, end_ns, result, cycle_time_s)

    def page(self, offset: int = 0, limit: int = 100, newest_first: bool = True, program: str = "") -> JobPage:
        """Runs, newest first by default, optionally of one program; `more` when the page is not the last."""
        rows, more = page_rows(self.db, "jobs", "seq, program, hash, start_ns, end_ns, result, cycle_time_s", offset, limit,
                               newest_first, "program" if program else "", program)
        return JobPage([JobRecord(*r) for r in rows], more)

    def close(self) -> None:
        self.db.close()
