"""A small SQLite history: one table of numbered rows, one writer, readers in other processes.

The job history and the audit trail are both this: the file opened by its one writer in WAL mode
(readers in other processes see every committed row) with its table created if needed, or
read-only by the gateway; and pages of rows, newest first by default, optionally filtered on one
column, with `more` when the page is not the last.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

MAX_PAGE = 1000


def open_store(path: Path, table_sql: str, what: str, readonly: bool = False) -> sqlite3.Connection:
    """The store at `path`: read-only, or for writing with its table (`table_sql`) created;
    RuntimeError naming the file and `what` it holds when it cannot be opened."""
    try:
        if readonly:
            return sqlite3.connect(f"file:{path}?mode=ro", uri=True, check_same_thread=False)
        path.parent.mkdir(parents=True, exist_ok=True)
        db = sqlite3.connect(path, check_same_thread=False)
        db.execute("PRAGMA journal_mode=WAL")
        db.execute(table_sql)
        db.commit()
        return db
    except sqlite3.Error as exc:
        raise RuntimeError(f"{path}: cannot open the {what}: {exc}") from None


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
