"""The job history's file is shared: the control logic keeps the runs and the cut points in it, the
gateway the cutting jobs. Both set it up when they start, and they start together."""

from __future__ import annotations

import multiprocessing
import sqlite3
from pathlib import Path

from cnc.gateway.jobs import CutPoints, CutSetups, JobHistory, jobs_path

ROUNDS = 30


def _as_the_logic(history: str, go, failures) -> None:  # noqa: ANN001
    go.wait()
    try:
        JobHistory(jobs_path(history)).close()
        CutPoints(jobs_path(history)).close()
    except RuntimeError as exc:
        failures.put(f"logic: {exc}")


def _as_the_gateway(history: str, go, failures) -> None:  # noqa: ANN001
    go.wait()
    try:
        CutSetups(jobs_path(history)).close()
    except RuntimeError as exc:
        failures.put(f"gateway: {exc}")


def test_the_logic_and_the_gateway_setting_up_a_new_job_history_at_once_both_open_it(tmp_path):
    ctx = multiprocessing.get_context("forkserver")
    failures = ctx.Queue()
    for k in range(ROUNDS):
        history = str(tmp_path / f"round{k}" / "history.sqlite")
        go = ctx.Event()
        both = [ctx.Process(target=f, args=(history, go, failures)) for f in (_as_the_logic, _as_the_gateway)]
        for p in both:
            p.start()
        go.set()  # released together: each one's set-up meets the other's
        for p in both:
            p.join(60.0)
        assert [p.exitcode for p in both] == [0, 0]
        tables = {r[0] for r in sqlite3.connect(jobs_path(history)).execute("SELECT name FROM sqlite_master")}
        assert {"jobs", "cut_points", "cut_setups"} <= tables, tables
    found = []
    while not failures.empty():
        found.append(failures.get())
    assert found == [], found[:3]
    assert Path(jobs_path(history)).exists()


def test_cut_points_written_before_the_runs_start_was_kept_read_as_unknown_and_gain_the_column(tmp_path):
    """A job record from before cut points kept where their run started (and how far into the
    segment): a reader that does not migrate reads its points with both unknown; the logic's store
    adds the columns and keeps the new figures from then on."""
    from cnc.gateway.jobs import CutPoint

    path = jobs_path(tmp_path / "history.sqlite")
    old = sqlite3.connect(path)
    old.execute("CREATE TABLE cut_points (hash TEXT PRIMARY KEY, program TEXT NOT NULL, segment INTEGER NOT NULL, "
                "x_mm REAL NOT NULL, y_mm REAL NOT NULL, line INTEGER NOT NULL, updated_ns INTEGER NOT NULL)")
    old.execute("INSERT INTO cut_points VALUES ('a1', 'nest.ngc', 4, 150.5, 75.0, 5, 1)")
    old.commit()
    old.close()
    reader = CutPoints(path, readonly=True)
    assert reader.get("a1") == CutPoint("a1", "nest.ngc", 4, 150.5, 75.0, 5, 1, -1.0, ())
    reader.close()
    writer = CutPoints(path)
    assert writer.get("a1") == CutPoint("a1", "nest.ngc", 4, 150.5, 75.0, 5, 1, -1.0, ())
    writer.save(CutPoint("b2", "rel.ngc", 1, 152.8, 75.0, 5, 2, 77.7, (5.0, 5.0)))
    writer.close()
    reader = CutPoints(path, readonly=True)
    assert reader.get("b2") == CutPoint("b2", "rel.ngc", 1, 152.8, 75.0, 5, 2, 77.7, (5.0, 5.0))
    reader.close()
    damaged = sqlite3.connect(path)
    damaged.execute("UPDATE cut_points SET start_mm = '[5.0, oops' WHERE hash = 'b2'")
    damaged.commit()
    damaged.close()
    reader = CutPoints(path, readonly=True)
    assert reader.get("b2").start_mm == (), "a damaged start reads as unknown: the program placed as it is loaded"
    reader.close()
