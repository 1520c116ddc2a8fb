"""Job history: every program run (program, hash, start, end, result, cycle time, planned cycle time,
cutting job) in SQLite, where the jet last cut in each program whose run did not end (`CutPoints`),
and the cutting job the operator chose for each program (`CutSetups`).

Written by the control logic when a run ends, read by the gateway for `<root>/jobs/history`.
It lives beside the alarm history, in its own file (WAL mode: one writer, readers in other
processes see each committed run).
"""

from __future__ import annotations

import json
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path

from ..bus.messages import JobPage, JobRecord
from .store import open_store, page_rows

_TABLE = ("CREATE TABLE IF NOT EXISTS jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, program TEXT NOT NULL, "
          "hash TEXT NOT NULL, start_ns INTEGER NOT NULL, end_ns INTEGER NOT NULL, result TEXT NOT NULL, "
          "cycle_time_s REAL NOT NULL, planned_s REAL NOT NULL DEFAULT -1, cut TEXT NOT NULL DEFAULT '')")
_COLUMNS = "seq, program, hash, start_ns, end_ns, result, cycle_time_s"
_ADDED = (("planned_s", "REAL NOT NULL DEFAULT -1"), ("cut", "TEXT NOT NULL DEFAULT ''"))  # columns later versions added


_CUTS = ("CREATE TABLE IF NOT EXISTS cut_points (hash TEXT PRIMARY KEY, program TEXT NOT NULL, segment INTEGER NOT NULL, "
         "x_mm REAL NOT NULL, y_mm REAL NOT NULL, line INTEGER NOT NULL, updated_ns INTEGER NOT NULL, "
         "segment_mm REAL NOT NULL DEFAULT -1, start_mm TEXT NOT NULL DEFAULT '')")
_CUT_COLUMNS = "hash, program, segment, x_mm, y_mm, line, updated_ns"
_CUT_ADDED = (("segment_mm", "REAL NOT NULL DEFAULT -1"), ("start_mm", "TEXT NOT NULL DEFAULT ''"))  # later versions'


@dataclass(frozen=True)
class CutPoint:
    """Where the jet last cut in a program (by its hash): the segment and the head's position."""

    hash: str
    program: str
    segment: int
    x_mm: float
    y_mm: float
    line: int
    updated_ns: int = 0
    segment_mm: float = -1.0  # roughly how far into the segment (-1 unknown): which turn of an arc of several
    start_mm: tuple[float, ...] = ()  # where the run started from, per machine axis (a G91 program's place); () unknown


class CutPoints:
    """The last cut point of each program whose run did not end: what "continue" continues, also
    after the controller was restarted or lost its power. Beside the job history, in its file."""

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.db = open_store(Path(path), _CUTS, "job history (cut points)", readonly,
                             setup=None if readonly else _add_cut_columns)

    def save(self, p: CutPoint) -> None:
        self.db.execute(f"INSERT OR REPLACE INTO cut_points ({_CUT_COLUMNS}, segment_mm, start_mm) "
                        "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        (p.hash, p.program, p.segment, p.x_mm, p.y_mm, p.line, p.updated_ns or time.time_ns(),
                         p.segment_mm, json.dumps(list(p.start_mm)) if p.start_mm else ""))
        self.db.commit()

    def clear(self, hash: str) -> None:
        """The program ran to its end: nothing of it is left to continue."""
        self.db.execute("DELETE FROM cut_points WHERE hash = ?", (hash,))
        self.db.commit()

    def get(self, hash: str) -> CutPoint | None:
        try:
            # a file written before these were kept, read by a reader that does not migrate it: without them
            have = _table_columns(self.db, "cut_points")
            extra = "".join(f", {name}" for name, _ in _CUT_ADDED if name in have)
            row = self.db.execute(f"SELECT {_CUT_COLUMNS}{extra} FROM cut_points WHERE hash = ?", (hash,)).fetchone()
        except sqlite3.OperationalError as exc:  # a store whose writer has not created the table yet
            if "no such table" in str(exc):
                return None
            raise
        if not row:
            return None
        return CutPoint(*row[:8], start_mm=_start_of(row[8] if len(row) > 8 else ""))

    def close(self) -> None:
        self.db.close()


_SETUPS = ("CREATE TABLE IF NOT EXISTS cut_setups (program TEXT PRIMARY KEY, setup TEXT NOT NULL, "
           "updated_ns INTEGER NOT NULL)")


class CutSetups:
    """The cutting job the operator chose for each program (by name), as the `SetCut` JSON: given
    with the program whenever it is loaded again. Beside the job history, in its file; the gateway
    writes it."""

    def __init__(self, path: str | Path) -> None:
        self.db = open_store(Path(path), _SETUPS, "job history (cutting jobs)")

    def save(self, program: str, setup_json: str) -> None:
        self.db.execute("INSERT OR REPLACE INTO cut_setups (program, setup, updated_ns) VALUES (?, ?, ?)",
                        (program, setup_json, time.time_ns()))
        self.db.commit()

    def forget(self, program: str) -> None:
        self.db.execute("DELETE FROM cut_setups WHERE program = ?", (program,))
        self.db.commit()

    def get(self, program: str) -> str | None:
        row = self.db.execute("SELECT setup FROM cut_setups WHERE program = ?", (program,)).fetchone()
        return row[0] if row else None

    def close(self) -> None:
        self.db.close()


def _table_columns(db: sqlite3.Connection, table: str) -> set[str]:
    return {row[1] for row in db.execute(f"PRAGMA table_info({table})")}


def _start_of(text: str) -> tuple[float, ...]:
    """A cut point's `start_mm` as stored (a JSON list); unknown (the program as it is loaded) when
    it is not one of numbers: a damaged record degrades to the old placement, never to a failure."""
    try:
        values = json.loads(text) if text else []
        return tuple(float(v) for v in values) if isinstance(values, list) else ()
    except (ValueError, TypeError):
        return ()


def _add_cut_columns(db: sqlite3.Connection) -> None:
    """Cut points written before these were kept get their columns (segment_mm -1: unknown, the
    first turn; start_mm '': unknown, the program as it is loaded)."""
    have = _table_columns(db, "cut_points")
    for name, kind in _CUT_ADDED:
        if name not in have:
            db.execute(f"ALTER TABLE cut_points ADD COLUMN {name} {kind}")


def _add_columns(db: sqlite3.Connection) -> None:
    """A history written before these were kept gets their columns."""
    have = _table_columns(db, "jobs")
    for name, kind in _ADDED:
        if name not in have:
            db.execute(f"ALTER TABLE jobs ADD COLUMN {name} {kind}")


def jobs_path(history_path: str | Path) -> Path:
    """The job history beside the alarm history."""
    return Path(history_path).with_name("jobs.sqlite")


class JobHistory:
    """Program runs, numbered in the order they ended."""

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.path = Path(path)
        self.db = open_store(self.path, _TABLE, "job history", readonly, setup=None if readonly else _add_columns)

    def _select(self) -> str:
        """The columns a JobRecord takes, as far as this file has them (an older one may lack the last)."""
        have = _table_columns(self.db, "jobs")
        extra = []
        for name, _ in _ADDED:
            if name not in have:
                break
            extra.append(name)
        return ", ".join([_COLUMNS, *extra])

    def append(self, program: str, hash: str, start_ns: int, end_ns: int, result: str, cycle_time_s: float,
               planned_s: float = -1.0, cut: str = "") -> JobRecord:
        """Record a run: its machine time, its planned cycle time at 100 % override (-1 when the
        planner had not finished timing it) and the cutting job it ran with."""
        cur = self.db.execute(
            "INSERT INTO jobs (program, hash, start_ns, end_ns, result, cycle_time_s, planned_s, cut) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (program, hash, start_ns, end_ns, result, cycle_time_s, planned_s, cut),
        )
        self.db.commit()
        return JobRecord(cur.lastrowid, program, hash, start_ns, end_ns, result, cycle_time_s, planned_s, cut)

    def page(self, offset: int = 0, limit: int = 100, newest_first: bool = True, program: str = "") -> JobPage:
        """Runs, newest first by default, optionally of one program; `more` when the page is not the last."""
        columns = self._select()
        rows, more = page_rows(self.db, "jobs", columns, offset, limit, newest_first, "program" if program else "", program)
        return JobPage([JobRecord(*r) for r in rows], more)

    def last_runs(self) -> dict[str, JobRecord]:
        """Each program's last run, by program name."""
        try:
            columns = self._select()
            rows = self.db.execute(f"SELECT {columns} FROM jobs WHERE seq IN (SELECT MAX(seq) FROM jobs GROUP BY program)")
        except sqlite3.OperationalError as exc:  # its writer has not created the table yet
            if "no such table" in str(exc):
                return {}
            raise
        return {r[1]: JobRecord(*r) for r in rows}

    def close(self) -> None:
        self.db.close()
