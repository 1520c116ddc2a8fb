"""`waterjet check`: validate a program completely and summarise it (planned cycle time included), or show the first error."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import IO

from gcode.errors import GCodeError
from gcode.interp import Interpreter
from gcode.program import Program

from .config import MachineConfig
from .machine_dialect import dialect_for
from .cutmodel import CutSetup
from .planner.quality import CutPlan, CutPlanError, cut_plan_for
from .planner.steps import ProgramTiming, timing_workers


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
    path: str, config: MachineConfig, tool_table: str | None, segments_out: str | None, out: IO[str], err: IO[str],
    json_out: str | None = None, cut: CutSetup | None = None,
) -> int:
    """Interpret `path`; print the summary (exit 0) or the error with its source line (exit 1).
    `json_out`: also write the figures as JSON ("-": to `out` instead of the summary), with the
    wall times of interpretation and planning apart. `cut`: the cutting job (else the program's
    `(MATERIAL, ...)` comment, else none): the cycle time is planned with its model, and the one at
    the programmed F given beside it."""
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        print(f"{path}: error: cannot read the program: {exc.strerror}", file=err)
        return 1
    if len(data) > config.gcode.max_program_bytes:
        print(f"{path}: error: program is {len(data)} bytes; this machine accepts at most {config.gcode.max_program_bytes}", file=err)
        return 1
    bar = ProgressBar(err)
    t0 = time.perf_counter()
    try:
        dialect = dialect_for(config, tool_table)
        program = Interpreter(dialect, path).run(data, progress=bar)
    except GCodeError as exc:
        bar.close()
        print(exc.render(), file=err)
        return 1
    bar.close()
    t1 = time.perf_counter()
    if segments_out:
        with open(segments_out, "w", encoding="utf-8") as f:
            program.write_segments_jsonl(f)
    try:
        plan, cut_text = cut_plan_for(program, cut, config, path)
    except CutPlanError as exc:
        print(f"{exc}", file=err)
        return 1
    timing = program_timing(program, config, plan)
    t2 = time.perf_counter()
    cycle_s = timing.total_ticks * config.timing.period_s
    at_feed_s = None
    if plan is not None and plan.applies:
        at_feed_s = program_timing(program, config).total_ticks * config.timing.period_s
    if json_out:
        figures = json_figures(program, cycle_s, timing.total_mm, t1 - t0, t2 - t1)
        figures["cut"] = cut_text
        figures["programmed_feed_cycle_time_s"] = at_feed_s if at_feed_s is not None else cycle_s
        text = json.dumps(figures, indent=2) + "\n"
        if json_out == "-":
            out.write(text)
            return 0
        Path(json_out).write_text(text, encoding="utf-8")
    print(summary(program, config), file=out)
    if plan is not None:
        m = plan.model
        print(f"  cutting job      {cut_text}", file=out)
        print(f"  speeds           " + ", ".join(f"q{q} {m.speed(q) * 60.0:.0f}" for q in range(1, 6))
              + " mm/min straight" + ("; slower in corners and arcs (jet lag)" if m.corners_modelled else ""), file=out)
    print(f"  cycle time       {cycle_s:.2f} s planned at 100 % override"
          + (" with the cutting model" if at_feed_s is not None else "")
          + " (from X0 Y0; pauses at program stops not counted)", file=out)
    if at_feed_s is not None:
        print(f"  at programmed F  {at_feed_s:.2f} s (the same program cut at its F)", file=out)
    print(f"  wall time        interpretation {t1 - t0:.2f} s, planning {t2 - t1:.2f} s "
          f"({cycle_s / max(t2 - t1, 1e-9):.0f}x real time)", file=out)
    return 0


def program_timing(program: Program, config: MachineConfig, cut: CutPlan | None = None) -> ProgramTiming:
    """The program's cycle time from the planner's profile (acceleration, jerk, corners, dwells, jet
    delays; the cutting model's speeds under `cut`), step by step as the planner streams it."""
    timing = ProgramTiming.of(program, config, cut, workers=timing_workers())
    if timing.failure is not None:
        raise timing.failure
    return timing


def json_figures(program: Program, cycle_s: float, path_mm: float, interpret_s: float, plan_s: float) -> dict:
    """`check --json`: the summary's figures, and the wall times of interpretation and planning."""
    st = program.stats
    return {
        "program": program.name, "valid": True, "lines": st.lines, "segments": st.segments,
        "cut_length_mm": st.cut_length_mm, "feed_length_mm": st.feed_length_mm, "rapid_length_mm": st.rapid_length_mm,
        "pierces": st.pierces, "dwell_s": st.dwell_s, "messages": len(program.messages),
        "bounds_min_mm": list(st.bounds_min), "bounds_max_mm": list(st.bounds_max),
        "planned_cycle_time_s": cycle_s, "path_mm": path_mm,
        "interpretation_wall_s": interpret_s, "planning_wall_s": plan_s,
        "planning_speed_x_real_time": cycle_s / plan_s if plan_s > 0 else None,
    }


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
