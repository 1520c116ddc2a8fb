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
