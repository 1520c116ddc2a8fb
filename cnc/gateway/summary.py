"""The program library's checker: `python -m cnc.gateway.summary DIR`, a child of the gateway.

It checks the programs the job in DIR names as `waterjet check` does (read the bounded way of
`cnc.programs`, interpreted with the machine's dialect, timed with the planner's profile) and
appends one JSON line per program to DIR/results.jsonl as it goes, so that a child killed in the
middle of a batch loses only the program it was on. It runs at low priority (nice 10), ends with
the gateway, and holds a large program's memory only for its own short life.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import sys
from dataclasses import asdict
from pathlib import Path

from ..bus.service import CommandRefused
from ..config import MachineConfig
from ..runtime.child import die_with
from ..programs import read_program
from .library import Summary

NICE = 10  # below the controller's processes and the HMI, still with a share of a busy CPU


def summarise(name: str, path: Path, max_bytes: int, config: MachineConfig) -> Summary:
    """What `waterjet check` finds for one program file (its error, with line and column, when it is refused)."""
    from gcode.errors import GCodeError
    from gcode.interp import Interpreter

    from ..check import program_timing
    from ..machine_dialect import dialect_for

    try:
        st = os.stat(path)
    except OSError as exc:
        return Summary.failed(name, 0, 0, f"cannot be read: {exc.strerror}")
    try:
        data = read_program(path, max_bytes, shown_as=name)
    except CommandRefused as exc:
        return Summary.failed(name, st.st_size, st.st_mtime_ns, str(exc))
    digest = hashlib.sha256(data).hexdigest()
    try:
        program = Interpreter(dialect_for(config), name).run(data)
    except GCodeError as exc:
        return Summary(name, st.st_size, st.st_mtime_ns, digest, -1, -1, -1.0, -1, -1.0, str(exc))
    stats = program.stats
    try:
        planned = program_timing(program, config).total_ticks * config.timing.period_s
    except Exception as exc:  # a program the planner cannot time is one it cannot run either
        return Summary(name, st.st_size, st.st_mtime_ns, digest, stats.lines, stats.segments, stats.cut_length_mm,
                       stats.pierces, -1.0, f"its cycle time could not be planned: {exc}")
    return Summary(name, st.st_size, st.st_mtime_ns, digest, stats.lines, stats.segments, stats.cut_length_mm,
                   stats.pierces, planned, "")


def main(argv: list[str]) -> int:
    die_with(os.getppid())  # ends with the gateway that started it
    from ..runtime.rt import leave_realtime

    leave_realtime()
    os.nice(NICE)
    work = Path(argv[0])
    with open(work / "job.pickle", "rb") as f:
        job = pickle.load(f)
    root = Path(job["root"])
    with open(work / "results.jsonl", "a", encoding="utf-8") as out:
        for name in job["names"]:
            s = summarise(name, root / name, job["max_bytes"], job["config"])
            out.write(json.dumps(asdict(s)) + "\n")
            out.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
