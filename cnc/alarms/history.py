"""The persistent alarm and message history: one SQLite file in WAL mode, one writer, many readers."""

from __future__ import annotations

import sqlite3
import threading
import time
import urllib.parse
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType

from cnc.alarms.catalogue import AlarmAction, AlarmLevel
from cnc.bus.messages import AlarmEvent, HistoryPage

# "CNCA" in ASCII: marks the file as ours, so that another program's SQLite file is refused
# instead of having a table added to it.
APPLICATION_ID = 0x434E4341
SCHEMA_VERSION = 1
MAX_PAGE = 1000  # most entries one page may hold: a query answer stays a small message

# Column order is AlarmEvent's field order, so that a row builds the message positionally.
_COLUMNS = ("seq", "stamp_ns", "code", "id", "level", "action", "text", "detail", "source", "cause", "remedy")
_SELECT = f"SELECT {', '.join(_COLUMNS)} FROM entry"

# AUTOINCREMENT keeps the largest seq ever handed out in sqlite_sequence, so a number is never
# reused, even after prune() deleted every row: a subscriber that saw seq N never sees another N.
_SCHEMA = """
CREATE TABLE entry (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    stamp_ns INTEGER NOT NULL,
    code INTEGER NOT NULL,
    id TEXT NOT NULL,
    level TEXT NOT NULL,
    action TEXT NOT NULL,
    text TEXT NOT NULL,
    detail TEXT NOT NULL,
    source TEXT NOT NULL,
    cause TEXT NOT NULL,
    remedy TEXT NOT NULL
);
CREATE INDEX entry_stamp ON entry (stamp_ns);
CREATE INDEX entry_code ON entry (code, seq);
"""


class HistoryError(RuntimeError):
    """The history file cannot be used: missing, not SQLite, not a history, damaged, or read-only."""


class AlarmHistory:
    """Every alarm and message entry the controller produced, in sequence order, on disk.

    One process (the one that owns the `AlarmBook`) opens the file for writing; any number of
    others open it with `readonly=True` and see each entry as soon as `append` has returned: WAL
    lets readers work on a committed snapshot while the writer appends. The object may be shared
    between threads (a lock serialises use of its one connection).
    """

    def __init__(self, path: str | Path, readonly: bool = False) -> None:
        self.path = Path(path)
        self.readonly = readonly
        self._lock = threading.Lock()
        self._db = self._connect()
        try:
            self._prepare()
        except sqlite3.DatabaseError as e:
            self._db.close()
            raise HistoryError(f"{self.path}: not a usable alarm history database ({e})") from e
        except HistoryError:
            self._db.close()
            raise
        self._db.create_function("has_text", -1, _has_text, deterministic=True)

    # -- opening ---------------------------------------------------------------------------

    def _connect(self) -> sqlite3.Connection:
        if self.path.is_dir():
            raise HistoryError(f"{self.path}: is a directory, not an alarm history file")
        if self.readonly:
            if not self.path.exists():
                raise HistoryError(f"{self.path}: no alarm history file there to read")
            uri = f"file:{urllib.parse.quote(str(self.path.resolve()))}?mode=ro"
            return sqlite3.connect(uri, uri=True, isolation_level=None, check_same_thread=False)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise HistoryError(f"{self.path}: cannot create the history's directory ({e})") from e
        # isolation_level=None: no implicit transactions; each method opens the one it needs.
        return sqlite3.connect(self.path, isolation_level=None, check_same_thread=False, timeout=5.0)

    def _prepare(self) -> None:
        """Create the schema in a new file, or check that an existing file is a history we know."""
        db = self._db
        if not self.readonly:
            mode = db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise HistoryError(f"{self.path}: cannot switch the history to WAL mode (journal mode stays {mode})")
            # FULL: every commit is fsynced into the WAL before append() returns. NORMAL would
            # already survive a killed process (a committed transaction is in the WAL file, in
            # the OS cache); only a power loss could take back the last entries. On a machine
            # whose main switch also cuts the PC that is an ordinary event, and a lost entry would
            # hand its seq out again to a different alarm after an HMI already saw it. Alarms are
            # rare and an fsync costs well under a millisecond to a few ms, so durability wins.
            db.execute("PRAGMA synchronous=FULL")
        app_id = db.execute("PRAGMA application_id").fetchone()[0]
        version = db.execute("PRAGMA user_version").fetchone()[0]
        tables = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
        if app_id == 0 and not tables:
            if self.readonly:
                raise HistoryError(f"{self.path}: an empty database, not an alarm history")
            self._create_schema()
            return
        if app_id != APPLICATION_ID:
            raise HistoryError(
                f"{self.path}: an SQLite database of another program (application_id {app_id:#x}, "
                f"an alarm history has {APPLICATION_ID:#x})"
            )
        if version != SCHEMA_VERSION:
            raise HistoryError(
                f"{self.path}: alarm history schema version {version}, this program knows version {SCHEMA_VERSION}"
            )
        if not self.readonly:
            problems = [r[0] for r in db.execute("PRAGMA quick_check")]
            if problems != ["ok"]:
                raise HistoryError(f"{self.path}: the alarm history is damaged: {'; '.join(problems[:5])}")

    def _create_schema(self) -> None:
        db = self._db
        db.execute("BEGIN IMMEDIATE")
        try:
            for statement in _SCHEMA.split(";"):
                if statement.strip():
                    db.execute(statement)
            db.execute(f"PRAGMA application_id = {APPLICATION_ID}")
            db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            db.execute("COMMIT")
        except BaseException:
            if db.in_transaction:
                db.execute("ROLLBACK")
            raise

    # -- writing ---------------------------------------------------------------------------

    def append(
        self,
        *,
        stamp_ns: int,
        code: int,
        id: str,
        level: AlarmLevel,
        action: AlarmAction,
        text: str,
        detail: str = "",
        source: str = "",
        cause: str = "",
        remedy: str = "",
    ) -> AlarmEvent:
        """Store one entry and return it with its sequence number. The transaction is committed
        (and fsynced) before this returns, so the caller may publish the entry right after: no
        subscriber ever hears of an entry the file could lose."""
        self._check_writable("append")
        row = (stamp_ns, code, id, level.text, action.value, text, detail, source, cause, remedy)
        with self._lock, self._failing_as(f"cannot store entry {id} {action.value}"):
            self._db.execute("BEGIN IMMEDIATE")
            try:
                cursor = self._db.execute(f"INSERT INTO entry ({', '.join(_COLUMNS[1:])}) VALUES (?{', ?' * 9})", row)
                seq = cursor.lastrowid
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:  # SQLite may already have rolled back (I/O error)
                    self._db.execute("ROLLBACK")
                raise
        return AlarmEvent(seq, *row)

    def append_event(self, event: AlarmEvent) -> None:
        """Store an entry whose sequence number its owner has already given it (`AlarmBook` with a
        `Recorder`: numbers are handed out in the scan, stored in order off it). Committed and
        fsynced before this returns."""
        self._check_writable("append")
        row = (event.seq, event.stamp_ns, event.code, event.id, event.level, event.action, event.text, event.detail,
               event.source, event.cause, event.remedy)
        with self._lock, self._failing_as(f"cannot store entry {event.seq} {event.id} {event.action}"):
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._db.execute(f"INSERT INTO entry ({', '.join(_COLUMNS)}) VALUES (?{', ?' * 10})", row)
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise

    def prune(self, keep_days: float, now_ns: int | None = None, keep_from_seq: int | None = None) -> int:
        """Delete the entries older than `keep_days`; returns how many. Entries from `keep_from_seq`
        on are kept whatever their age (the owner of the active list passes its oldest raise, so
        that a restart can still rebuild it). Sequence numbers continue after the largest ever used."""
        self._check_writable("prune")
        if not keep_days > 0:
            raise ValueError(f"prune: keep_days must be positive, got {keep_days}")
        now_ns = time.time_ns() if now_ns is None else now_ns
        cutoff_ns = now_ns - int(keep_days * 86400e9)
        keep_seq = keep_from_seq if keep_from_seq is not None else self.last_seq() + 1
        with self._lock, self._failing_as("cannot prune"):
            self._db.execute("BEGIN IMMEDIATE")
            try:
                deleted = self._db.execute(
                    "DELETE FROM entry WHERE stamp_ns < ? AND seq < ?", (cutoff_ns, keep_seq)
                ).rowcount
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:  # SQLite may already have rolled back (I/O error)
                    self._db.execute("ROLLBACK")
                raise
        return deleted

    @contextmanager
    def _failing_as(self, what: str) -> Iterator[None]:
        """Turn SQLite's errors (disk full, damaged file, locked too long) into one naming the file."""
        try:
            yield
        except sqlite3.Error as e:
            raise HistoryError(f"{self.path}: {what} ({e})") from e

    def _check_writable(self, what: str) -> None:
        if self.readonly:
            raise HistoryError(f"{self.path}: {what} refused, the history is open read-only")

    # -- reading ---------------------------------------------------------------------------

    def last_seq(self) -> int:
        """The largest sequence number ever handed out (0 for a new history), pruned or not."""
        with self._lock, self._failing_as("cannot read"):
            return self._last_seq()

    def _last_seq(self) -> int:
        row = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'entry'").fetchone()
        return row[0] if row else 0

    def after(self, seq: int, limit: int = 100) -> HistoryPage:
        """Catch-up: the entries with a sequence number above `seq`, oldest first, at most `limit`;
        `more` says whether further entries follow the last one returned."""
        return self._page("WHERE seq > ?", [seq], "ORDER BY seq", 0, limit)

    def query(
        self,
        *,
        since_ns: int | None = None,
        until_ns: int | None = None,
        levels: Iterable[AlarmLevel] | None = None,
        codes: Iterable[int] | None = None,
        text: str = "",
        before_seq: int | None = None,
        after_seq: int | None = None,
        offset: int = 0,
        limit: int = 100,
        newest_first: bool = True,
    ) -> HistoryPage:
        """The entries that pass every filter given, newest first unless `newest_first` is false.

        Time is the half-open range [since_ns, until_ns). `levels` and `codes` keep entries whose
        level or code is among them (None: any; empty: none). `text` keeps entries whose text,
        detail or id contain it, ignoring case. Page with `offset`, or, stable while entries
        arrive, with `before_seq` (newest first: pass the last seq of the previous page) or
        `after_seq` (oldest first). `more` says whether the filters match entries beyond this page.
        """
        where: list[str] = []
        args: list[object] = []
        for clause, value in (("stamp_ns >= ?", since_ns), ("stamp_ns < ?", until_ns),
                              ("seq < ?", before_seq), ("seq > ?", after_seq)):
            if value is not None:
                where.append(clause)
                args.append(value)
        for column, values in (("level", None if levels is None else [lv.text for lv in levels]),
                               ("code", None if codes is None else list(codes))):
            if values is not None:
                where.append(f"{column} IN ({', '.join('?' * len(values))})" if values else "0")
                args += values
        if text:
            where.append("has_text(?, text, detail, id)")
            args.append(text)
        clause = f"WHERE {' AND '.join(where)}" if where else ""
        order = "ORDER BY seq DESC" if newest_first else "ORDER BY seq"
        return self._page(clause, args, order, offset, limit)

    def _page(self, where: str, args: list[object], order: str, offset: int, limit: int) -> HistoryPage:
        if not 1 <= limit <= MAX_PAGE:
            raise ValueError(f"history page limit must be 1 to {MAX_PAGE}, got {limit}")
        if offset < 0:
            raise ValueError(f"history page offset must not be negative, got {offset}")
        with self._lock, self._failing_as("cannot read"):
            # One read transaction: the entries and last_seq come from the same snapshot.
            self._db.execute("BEGIN")
            try:
                sql = f"{_SELECT} {where} {order} LIMIT ? OFFSET ?"
                rows = self._db.execute(sql, [*args, limit + 1, offset]).fetchall()
                last = self._last_seq()
            finally:
                if self._db.in_transaction:
                    self._db.execute("COMMIT")
        return HistoryPage([AlarmEvent(*row) for row in rows[:limit]], last, more=len(rows) > limit)

    # -- life cycle ------------------------------------------------------------------------

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def __enter__(self) -> AlarmHistory:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"AlarmHistory({str(self.path)!r}{', readonly=True' if self.readonly else ''})"


def _has_text(needle: str, *fields: str) -> bool:
    """SQL function for the text filter: SQLite's LIKE folds only ASCII case, the operators'
    languages need Unicode case folding."""
    folded = needle.casefold()
    return any(folded in f.casefold() for f in fields)
