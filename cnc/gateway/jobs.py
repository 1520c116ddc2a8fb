"""Job history: every program run (program, hash, start, end, result, cycle time) in SQLite.

Written by the control logic when a run ends, read by the gateway for `<root>/jobs/history`.
It lives beside the alarm history, in its own file (WAL mode: one writer, readers in other
processes see each committed run).
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

from ..bus.messages import JobPage, JobRecord

MAX_PAGE = 1000


def jobs_path(history_path: str | Path) -> Path:
    """The job history beside the alarm history."""
    return Path(history_path).with_name("jobs.sqlite")


class JobHistory:
    """Program runs, numbered in the order they ended."""

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.path = Path(path)
        try:
            if readonly:
                self.db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, check_same_thread=False)
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.db = sqlite3.connect(self.path, check_same_thread=False)
                self.db.execute("PRAGMA journal_mode=WAL")
                self.db.execute(
                    "CREATE TABLE IF NOT EXISTS jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, program TEXT NOT NULL, "
                    "hash TEXT NOT NULL, start_ns INTEGER NOT NULL, end_ns INTEGER NOT NULL, result TEXT NOT NULL, "
                    "cycle_time_s REAL NOT NULL)"
                )
                self.db.commit()
        except sqlite3.Error as exc:
            raise RuntimeError(f"{self.path}: cannot open the job history: {exc}") from None

    def append(self, program: str, hash: str, start_ns: int, end_ns: int, result: str, cycle_time_s: float) -> JobRecord:
        cur = self.db.execute(
            "INSERT INTO jobs (program, hash, start_ns, end_ns, result, cycle_time_s) VALUES (?, ?, ?, ?, ?, ?)",
            (program, hash, start_ns, end_ns, result, cycle_time_s),
        )
        self.db.commit()
        return JobRecord(cur.lastrowid, program, hash, start_ns, end_ns, result, cycle_time_s)

    def page(self, offset: int = 0, limit: int = 100, newest_first: bool = True, program: str = "") -> JobPage:
        """Runs, newest first by default, optionally of one program; `more` when the page is not the last."""
        limit = max(1, min(limit, MAX_PAGE))
        where, args = ("WHERE program = ?", [program]) if program else ("", [])
        try:
            rows = self.db.execute(
                f"SELECT seq, program, hash, start_ns, end_ns, result, cycle_time_s FROM jobs {where} "
                f"ORDER BY seq {'DESC' if newest_first else 'ASC'} LIMIT ? OFFSET ?", [*args, limit + 1, max(offset, 0)],
            ).fetchall()
        except sqlite3.OperationalError as exc:
            if "no such table" in str(exc):
                return JobPage([], False)
            raise
        return JobPage([JobRecord(*r) for r in rows[:limit]], len(rows) > limit)

    def close(self) -> None:
        self.db.close()
