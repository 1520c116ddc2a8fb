"""A small SQLite history: one table of numbered rows, one writer, readers in other processes.

The job history and the audit trail are both this: the file opened by its one writer in WAL mode
(readers in other processes see every committed row) with its table created if needed, or
read-only by the gateway; and pages of rows, newest first by default, optionally filtered on one
column, with `more` when the page is not the last.
"""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path
from typing import Callable

MAX_PAGE = 1000


SETUP_ATTEMPTS = 50  # a new file's set-up raced by another process's: tried again this often, 10 ms more each time


def open_store(path: Path, table_sql: str, what: str, readonly: bool = False,
               setup: Callable[[sqlite3.Connection], None] | None = None) -> sqlite3.Connection:
    """The store at `path`: read-only, or for writing with its table (`table_sql`) created and then
    `setup` run on it (a migration); RuntimeError naming the file and `what` it holds when it cannot
    be opened.

    Two processes may set up the same new file at once (the control logic's job history and the
    gateway's cutting jobs share one, and start together). SQLite answers the loser's switch to WAL
    "database is locked" at once, without waiting for its busy timeout; the set-up is then tried
    again, after 10, 20, 30 ... ms (13 s in all before it gives up): the winner's takes milliseconds."""
    try:
        if readonly:
            return sqlite3.connect(f"file:{path}?mode=ro", uri=True, check_same_thread=False)
        path.parent.mkdir(parents=True, exist_ok=True)
    except (sqlite3.Error, OSError) as exc:
        raise RuntimeError(f"{path}: cannot open the {what}: {exc}") from None
    for attempt in range(1, SETUP_ATTEMPTS + 1):
        db = None
        try:
            db = sqlite3.connect(path, check_same_thread=False)
            db.execute("PRAGMA journal_mode=WAL")
            db.execute(table_sql)
            db.commit()
            if setup is not None:
                setup(db)
                db.commit()
            return db
        except sqlite3.OperationalError as exc:
            if db is not None:
                db.close()
            if "locked" not in str(exc) or attempt == SETUP_ATTEMPTS:
                raise RuntimeError(f"{path}: cannot open the {what}: {exc}") from None
            time.sleep(0.01 * attempt)
        except sqlite3.Error as exc:
            if db is not None:
                db.close()
            raise RuntimeError(f"{path}: cannot open the {what}: {exc}") from None
    raise AssertionError("unreachable")


def page_rows(db: sqlite3.Connection, table: str, columns: str, offset: int, limit: int, newest_first: bool,
              column: str = "", value: object = None) -> tuple[list[tuple], bool]:
    """Rows of `table` by `seq`, at most `limit` (1..MAX_PAGE) from `offset`, those whose `column`
    equals `value` when a column is given; and whether more follow. A store whose writer has not
    created the table yet holds no rows."""
    limit = max(1, min(limit, MAX_PAGE))
    where, args = (f"WHERE {column} = ?", [value]) if column else ("", [])
    try:
        rows = db.execute(f"SELECT {columns} FROM {table} {where} ORDER BY seq {'DESC' if newest_first else 'ASC'} "
                          "LIMIT ? OFFSET ?", [*args, limit + 1, max(offset, 0)]).fetchall()
    except sqlite3.OperationalError as exc:
        if "no such table" in str(exc):
            return [], False
        raise
    return rows[:limit], len(rows) > limit
