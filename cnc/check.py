"""`waterjet check`: validate a program completely and summarise it (planned cycle time included), or show the first error."""

from __future__ import annotations

import time
from pathlib import Path
from typing import IO

from gcode.errors import GCodeError
from gcode.interp import Interpreter
from gcode.program import Program

from .config import MachineConfig
from .machine_dialect import dialect_for
from .planner.runner import ProgramRunner


class ProgressBar:
    """A one-line progress bar on stderr, drawn only when stderr is a terminal."""

    def __init__(self, stream: IO[str]) -> None:
        self.stream = stream
        self.enabled = stream.isatty()
        self._last = 0.0

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if not self.enabled or now - self._last < 0.1:
            return
        self._last = now
        frac = done / total if total else 1.0
        bar = "#" * int(frac * 40)
        self.stream.write(f"\r[{bar:<40}] {frac * 100:5.1f}% line {done}/{total}")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\r" + " " * 72 + "\r")
            self.stream.flush()


def check_program(
    path: str, config: MachineConfig, tool_table: str | None, segments_out: str | None, out: IO[str], err: IO[str]
) -> int:
    """Interpret `path`; print the summary (exit 0) or the error with its source line (exit 1)."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        print(f"{path}: error: cannot read the program: {exc.strerror}", file=err)
        return 1
    if len(data) > config.gcode.max_program_bytes:
        print(f"{path}: error: program is {len(data)} bytes; this machine accepts at most {config.gcode.max_program_bytes}", file=err)
        return 1
    bar = ProgressBar(err)
    try:
        dialect = dialect_for(config, tool_table)
        program = Interpreter(dialect, path).run(data, progress=bar)
    except GCodeError as exc:
        bar.close()
        print(exc.render(), file=err)
        return 1
    bar.close()
    if segments_out:
        with open(segments_out, "w", encoding="utf-8") as f:
            program.write_segments_jsonl(f)
    print(summary(program, config), file=out)
    print(f"  cycle time       {planned_cycle_time_s(program, config):.2f} s planned at 100 % override"
          f" (from X0 Y0; pauses at program stops not counted)", file=out)
    return 0


def planned_cycle_time_s(program: Program, config: MachineConfig) -> float:
    """The program's cycle time from the planner's profile (acceleration, jerk, corners, dwells, jet delays)."""
    return ProgramRunner(program, config).planned_ticks() * config.timing.period_s


def summary(program: Program, config: MachineConfig) -> str:
    st = program.stats
    lines = [
        f"{program.name}: valid",
        f"  lines            {st.lines}",
        f"  segments         {st.segments}",
        f"  cut length       {st.cut_length_mm:.1f} mm (jet on)",
        f"  feed length      {st.feed_length_mm:.1f} mm",
        f"  rapid length     {st.rapid_length_mm:.1f} mm",
        f"  pierces          {st.pierces}",
        f"  dwell            {st.dwell_s:.2f} s",
        f"  messages         {len(program.messages)}",
    ]
    if st.segments and st.bounds_min[0] == st.bounds_min[0]:
        for i, axis in enumerate("xyz"):
            lo, hi = st.bounds_min[i], st.bounds_max[i]
            a = config.axis.get(axis)
            if a is None:
                if lo != 0.0 or hi != 0.0:
                    lines.append(f"  bounds {axis.upper()}         {lo:.3f} .. {hi:.3f} mm  (the machine has no {axis.upper()} axis)")
                continue
            ok = a.travel_min_mm <= lo and hi <= a.travel_max_mm
            verdict = "within travel" if ok else f"OUTSIDE travel {a.travel_min_mm:g} .. {a.travel_max_mm:g} mm"
            lines.append(f"  bounds {axis.upper()}         {lo:.3f} .. {hi:.3f} mm  {verdict}")
    return "\n".join(lines)
