"""The program library: the controller's program directory as an operator sees it.

Every program in the directory (`cnc.programs`) is listed with its size, and with the figures
`waterjet check` gives (lines, motions, cut length, pierces, the planned cycle time) or why it
would be refused; beside them its last run and how that ended (the job history). The figures
cost an interpretation and a timing of the whole program (seconds for a large one), so they are
made once per version of a file (its size and modification time) by a child process at low
priority (`cnc.gateway.summary`), in the background, and kept in a small SQLite index beside
the alarm history; a listing never waits for them: a program not yet checked is pending.
Programs copied into the directory by hand are found at the next listing like uploaded ones.

The gateway is the index's one writer (the summariser thread and the delete command, under one
lock); the index is only a cache: deleting it loses nothing.
"""

from __future__ import annotations

import json
import logging
import os
import pickle
import shutil
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from ..bus.messages import JobRecord, ProgramEntry, ProgramList
from ..bus.service import CommandRefused
from ..bus.states import ProgramCheck
from ..config import MachineConfig
from ..programs import ProgramDirectory
from .jobs import JobHistory
from .store import open_store

log = logging.getLogger(__name__)

BATCH = 32  # programs one summary child checks before the listing is looked at again
JOB_PREFIX = ".summary-"  # then the gateway's pid: the work directory of a summary child
_TABLE = ("CREATE TABLE IF NOT EXISTS programs (name TEXT PRIMARY KEY, bytes INTEGER NOT NULL, "
          "modified_ns INTEGER NOT NULL, hash TEXT NOT NULL, lines INTEGER NOT NULL, segments INTEGER NOT NULL, "
          "cut_mm REAL NOT NULL, pierces INTEGER NOT NULL, planned_s REAL NOT NULL, error TEXT NOT NULL)")
_COLUMNS = ("name", "bytes", "modified_ns", "hash", "lines", "segments", "cut_mm", "pierces", "planned_s", "error")


def library_path(history_path: str | Path) -> Path:
    """The library's index beside the alarm history."""
    return Path(history_path).with_name("library.sqlite")


@dataclass(frozen=True)
class Summary:
    """What checking one version of a program found (`error` empty when it is valid)."""

    name: str
    bytes: int
    modified_ns: int
    hash: str
    lines: int
    segments: int
    cut_mm: float
    pierces: int
    planned_s: float
    error: str

    @classmethod
    def failed(cls, name: str, size: int, modified_ns: int, why: str) -> "Summary":
        return cls(name, size, modified_ns, "", -1, -1, -1.0, -1, -1.0, why)


class ProgramLibrary:
    """The listing, the background summaries and deletion, for one program directory."""

    def __init__(self, programs: ProgramDirectory, index_path: str | Path, jobs_path: str | Path,
                 config: MachineConfig, summarise: bool = True) -> None:
        """`summarise`: check new programs in the background (off: the listing shows them pending)."""
        self.programs, self.config = programs, config
        self.index_path, self.jobs_path = Path(index_path), Path(jobs_path)
        self._lock = threading.Lock()
        self.db = open_store(self.index_path, _TABLE, "program library")
        self._remove_stale_jobs()
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._child: subprocess.Popen | None = None
        self.summaries_made = 0  # programs checked since start (tests and the log)
        self._thread = threading.Thread(target=self._summarise_forever, name="library-summaries", daemon=True)
        if summarise:
            self._thread.start()
            self._wake.set()

    def close(self) -> None:
        self._closing.set()
        self._wake.set()
        child = self._child
        if child is not None and child.poll() is None:
            child.kill()
        if self._thread.is_alive():
            self._thread.join(10.0)
        with self._lock:
            self.db.close()

    # -- the listing --------------------------------------------------------------------------
    def listing(self, loaded: str = "") -> ProgramList:
        """Every program of the directory by name, with what is known of it; `loaded`: the name of
        the program the controller has loaded. Programs not yet checked wake the summariser."""
        files = self._files()
        with self._lock:
            known = {row[0]: Summary(*row) for row in self.db.execute(f"SELECT {', '.join(_COLUMNS)} FROM programs")}
        runs = self._last_runs()
        entries, pending = [], False
        for name, (size, modified) in files.items():
            s = known.get(name)
            fresh = s is not None and s.bytes == size and s.modified_ns == modified
            pending = pending or not fresh
            run = runs.get(name)
            entries.append(ProgramEntry(
                name=name, bytes=size, modified_ns=modified,
                summary=ProgramCheck.PENDING if not fresh else ProgramCheck.REFUSED if s.error else ProgramCheck.READY,
                lines=s.lines if fresh else -1, segments=s.segments if fresh else -1,
                cut_length_mm=s.cut_mm if fresh else -1.0, pierces=s.pierces if fresh else -1,
                planned_s=s.planned_s if fresh else -1.0, error=s.error if fresh else "",
                last_run_end_ns=run.end_ns if run else 0, last_result=run.result if run else "",
                last_cycle_s=run.cycle_time_s if run else -1.0, loaded=bool(loaded) and name == loaded,
            ))
        if pending:
            self._wake.set()
        return ProgramList(str(self.programs.root), self.programs.max_bytes, entries)

    def summary(self, name: str) -> Summary | None:
        """The summary of `name` as it is now on disk, when it has been made."""
        files = self._files()
        if name not in files:
            return None
        with self._lock:
            row = self.db.execute(f"SELECT {', '.join(_COLUMNS)} FROM programs WHERE name = ?", (name,)).fetchone()
        s = Summary(*row) if row else None
        return s if s is not None and (s.bytes, s.modified_ns) == files[name] else None

    def changed(self) -> None:
        """A program was stored (an upload): check it soon."""
        self._wake.set()

    def _files(self) -> dict[str, tuple[int, int]]:
        """name -> (size, modification time in ns) of the directory's programs."""
        out = {}
        for name in self.programs.names():
            try:
                st = os.stat(self.programs.root / name)
            except OSError:  # deleted meanwhile
                continue
            out[name] = (st.st_size, st.st_mtime_ns)
        return out

    def _last_runs(self) -> dict[str, JobRecord]:
        if not self.jobs_path.exists():
            return {}
        history = JobHistory(self.jobs_path, readonly=True)
        try:
            return history.last_runs()
        finally:
            history.close()

    # -- deleting -----------------------------------------------------------------------------
    def delete(self, name: str) -> None:
        """Remove the program `name` (a plain name in the directory; a symbolic link is removed, not
        what it points to). CommandRefused says why not."""
        if not name or "/" in name or name.startswith("."):
            raise CommandRefused(f"program name {name!r} must be the plain name of a program in the library")
        self.programs.resolve(name)  # inside the directory, and there
        entry = self.programs.root / name
        if not entry.is_symlink() and not entry.is_file():
            raise CommandRefused(f"{name}: is not a program file")
        try:
            entry.unlink()
        except OSError as exc:
            raise CommandRefused(f"{name}: cannot be deleted: {exc.strerror}") from None
        with self._lock:
            self.db.execute("DELETE FROM programs WHERE name = ?", (name,))
            self.db.commit()

    # -- the summaries ------------------------------------------------------------------------
    def _summarise_forever(self) -> None:
        while not self._closing.is_set():
            self._wake.wait()
            self._wake.clear()
            while not self._closing.is_set():
                todo = self._stale()
                if not todo:
                    break
                try:
                    self._summarise(todo[:BATCH])
                except Exception:  # a bug: logged; the programs stay pending and are tried at the next wake
                    log.exception("library: checking %d programs failed", len(todo[:BATCH]))
                    break

    def _stale(self) -> list[tuple[str, int, int]]:
        """Programs whose summary is missing or made of another version of the file."""
        files = self._files()
        with self._lock:
            known = {r[0]: (r[1], r[2]) for r in self.db.execute("SELECT name, bytes, modified_ns FROM programs")}
        return [(n, size, mtime) for n, (size, mtime) in files.items() if known.get(n) != (size, mtime)]

    def _summarise(self, todo: list[tuple[str, int, int]]) -> None:
        """Check `todo` in a child process (`cnc.gateway.summary`) and keep what it found; a program
        the child could not finish (it died) is kept as refused, with the reason."""
        work = self.index_path.parent / f"{JOB_PREFIX}{os.getpid()}"
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        try:
            with open(work / "job.pickle", "wb") as f:
                pickle.dump({"config": self.config, "root": str(self.programs.root), "max_bytes": self.programs.max_bytes,
                             "names": [n for n, _, _ in todo]}, f)
            with open(work / "stderr.txt", "wb") as err:
                self._child = subprocess.Popen(
                    [sys.executable, "-m", "cnc.gateway.summary", str(work)],
                    stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, close_fds=True,
                )
                code = self._child.wait()
            self._child = None
            if self._closing.is_set():
                return
            found = _read_results(work / "results.jsonl")
            tail = (work / "stderr.txt").read_text(errors="replace").strip().splitlines()
            for name, size, mtime in todo:
                s = found.get(name) or Summary.failed(
                    name, size, mtime, f"could not be checked: the checker ended (exit {code})"
                    + (f": {tail[-1]}" if tail else ""))
                self._store(s)
                self.summaries_made += 1
        finally:
            shutil.rmtree(work, ignore_errors=True)

    def _store(self, s: Summary) -> None:
        with self._lock:
            self.db.execute(f"INSERT OR REPLACE INTO programs ({', '.join(_COLUMNS)}) VALUES ({', '.join('?' * len(_COLUMNS))})",
                            (s.name, s.bytes, s.modified_ns, s.hash, s.lines, s.segments, s.cut_mm, s.pierces,
                             s.planned_s, s.error))
            self.db.commit()

    def _remove_stale_jobs(self) -> None:
        """Work directories of gateways that are gone (killed while a child checked programs)."""
        for d in self.index_path.parent.glob(f"{JOB_PREFIX}*"):
            pid = d.name[len(JOB_PREFIX):]
            if pid.isdigit() and not Path(f"/proc/{pid}").exists():
                shutil.rmtree(d, ignore_errors=True)


def _read_results(path: Path) -> dict[str, Summary]:
    """The child's results, one JSON object a line (a line cut short by its death is left out)."""
    found: dict[str, Summary] = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError:
        return found
    for line in lines:
        try:
            s = Summary(**json.loads(line))
        except (ValueError, TypeError):
            continue
        found[s.name] = s
    return found
