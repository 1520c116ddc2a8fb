"""Exporting a log run (the `LogRunData` message) to MATLAB (`.mat`, scipy.io.savemat) and CSV, with the
control parameters in force; shared by `waterjet log export` and the operator screen.

MATLAB gets one struct per concern: `log.<variable>` with `t` (s since the run started), `v` and
`unit`; `settings.<variable>` with its logging mode; `params_start` and `params_end` with the
control parameters; `param_changes` with `t`, `name` and `value` of each change during the run.
Names become MATLAB identifiers (`x.following_error` -> `x_following_error`). CSV gets the
variables in one file, a `t_s` column and one column per variable (empty where that variable has
no sample at that time), and the parameters in `<name>_params.csv`. Values are written with
Python's shortest exact repr, so both files read back bit for bit.
"""

from __future__ import annotations

import csv
import re
import time
from pathlib import Path

import numpy as np

from .messages import LogRunData


def columns(data: LogRunData) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each variable's (t, v) arrays."""
    return {name: (np.frombuffer(c.t, "<f8").copy(), np.frombuffer(c.v, "<f8").copy()) for name, c in data.columns.items()}


def mat_name(name: str) -> str:
    """A MATLAB identifier for a variable or parameter name."""
    ident = re.sub(r"\W", "_", name)
    return ident if ident[:1].isalpha() else f"v_{ident}"


def to_mat(data: LogRunData, path: str | Path) -> Path:
    """Write the run as a MATLAB 5 file; returns its path."""
    from scipy.io import savemat

    path = Path(path)
    log = {mat_name(n): {"t": t, "v": v, "unit": data.units.get(n, "")} for n, (t, v) in columns(data).items()}
    settings = {mat_name(s.name): {"mode": s.mode, "divisor": s.divisor, "start_s": s.start_s, "duration_s": s.duration_s,
                                   "window_s": s.window_s, "enable_when": s.enable_when, "disable_when": s.disable_when}
                for s in data.settings}
    changes = data.param_changes
    savemat(path, {
        "run": data.run, "title": data.title, "started": _iso(data.started_ns), "ended": _iso(data.ended_ns),
        "period_s": data.period_s, "log": log, "settings": settings,
        "params_start": {mat_name(k): v for k, v in data.params_start.items()},
        "params_end": {mat_name(k): v for k, v in data.params_end.items()},
        "param_changes": {"t": np.array([c[0] for c in changes], dtype=float),
                          "name": np.array([c[1] for c in changes], dtype=object),
                          "value": np.array([c[2] for c in changes], dtype=float)},
        "truncated": np.array(data.truncated, dtype=object),
        "control": {"program": data.control_program,
                    **dict(zip(("p50_us", "p99_us", "max_us"), data.control_us or [-1.0, -1.0, -1.0]))},
    }, do_compression=True, oned_as="column")
    return path


def to_csv(data: LogRunData, path: str | Path) -> list[Path]:
    """Write the variables to `path` and the parameters beside it; returns both paths."""
    path = Path(path)
    cols = columns(data)
    times = np.unique(np.concatenate([t for t, _ in cols.values()])) if cols else np.zeros(0)
    table = {n: dict(zip(t.tolist(), v.tolist())) for n, (t, v) in cols.items()}
    with path.open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(["t_s", *(f"{n} [{data.units[n]}]" if data.units.get(n) else n for n in cols)])
        for t in times.tolist():
            out.writerow([repr(t), *(repr(table[n][t]) if t in table[n] else "" for n in cols)])
    params = path.with_name(f"{path.stem}_params.csv")
    with params.open("w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(["parameter", "at_start", "at_end", "changes (t_s=value; ...)"])
        for name, start in data.params_start.items():
            changes = "; ".join(f"{t!r}={v!r}" for t, n, v in data.param_changes if n == name)
            out.writerow([name, repr(start), repr(data.params_end.get(name, start)), changes])
    return [path, params]


def read_csv(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Read a CSV written by `to_csv` back into (t, v) per variable (unit suffixes dropped)."""
    with Path(path).open(newline="", encoding="utf-8") as f:
        rows = list(csv.reader(f))
    names = [re.sub(r" \[.*\]$", "", h) for h in rows[0][1:]]
    out: dict[str, tuple[list[float], list[float]]] = {n: ([], []) for n in names}
    for row in rows[1:]:
        t = float(row[0])
        for name, cell in zip(names, row[1:]):
            if cell:
                out[name][0].append(t)
                out[name][1].append(float(cell))
    return {n: (np.array(t), np.array(v)) for n, (t, v) in out.items()}


def _iso(stamp_ns: int) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(stamp_ns / 1e9)) if stamp_ns else ""
