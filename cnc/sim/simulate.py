"""`waterjet simulate`: run a program on the real controller processes on the virtual clock and measure it.

The hardware server (simulated board), servo and planner run as in production; the virtual
clock runs them as fast as the CPU allows, tick by tick, deterministically. The machine is
homed first (through the planner), then the program is loaded and started, and the clock is
stepped in chunks that the servo's trace ring holds whole, so every tick is recorded. From
the trace:

- cycle_time_s: the program's records, one per servo period, from its first to its last;
- path_deviation_max_mm: commanded setpoints against the programmed geometry;
- tracking_error_max_mm / _rms_mm: actual position against the setpoint, normal to the path;
- contour_error_max_mm: actual position against the programmed geometry, on the feed moves
  (what the cut shows; rapids separately, as contour_error_rapid_max_mm);
- following_error_max_mm, peak_velocity_mm_s, peak_accel_mm_s2, peak_jerk_mm_s3: per axis;
- fifo_min_fill (the lowest fill the planner saw at a refill), underruns, overruns;
- with a cutting job (`cnc.cutmodel`: the program's `(MATERIAL, ...)` comment, or `--material`
  ...): the job, and per quality the cut length, its peak speed and the quality's straight speed
  (`--plot` also draws the speed along the path coloured by quality, into OUT-speed.png).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from gcode.canon import RAPID
from gcode.interp import Interpreter
from gcode.program import Program

from ..bus.messages import Home, LoadProgram, SetCut, Start
from ..config import MachineConfig, load_machine
from ..cutmodel import CutSetup
from ..planner.quality import CutPlan, CutPlanError, cut_plan_for
from .demo import free_port
from ..data.fifo import SetpointFlag
from ..data.layout import PlannerState, RunResult, ServoState
from ..machine_dialect import dialect_for
from ..planner.measure import ProgrammedPath, peaks
from ..planner.path import elements_from_program, sample
from ..runtime.supervisor import MOTION_ONLY, Supervisor, SupervisorError
from .operator import ScriptError, ask_planner as _ask_planner

CHUNK_TICKS = 20_000  # ticks per step of the clock: well within the trace ring
SETTLE_S = 0.2  # recorded after the last setpoint: the table comes to rest


class SimulationError(RuntimeError):
    """The simulation could not run the program; the message says why."""


@dataclass
class SimulationResult:
    """Figures of one simulated run, and its trace for plots."""

    program: str
    metrics: dict
    trace: np.ndarray = field(repr=False)
    programmed_xy: np.ndarray = field(repr=False)
    dt: float = 0.001
    cut: CutPlan | None = field(default=None, repr=False)


def simulate(program_path: str, config: MachineConfig, cut: CutSetup | None = None) -> SimulationResult:
    """Home, load, run; return the figures. Raises ScriptError with the planner's reason on refusal.
    `config` should listen on a port of its own (see `run_cli`); `cut`: the operator's cutting job
    (else the program's own)."""
    dt = config.timing.period_s
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        load_s = _prepare(sup, program_path, cut)
        sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 3600.0, "the program's cycle time to be planned")
        m0, s0 = sup.motion(), sup.servo()
        sup.pause_virtual_clock()
        sup.set_tracing(True)
        sup.trace.drain()
        t0 = time.perf_counter()
        _ask_planner(sup, Start(), "start")
        while sup.motion()["records_pushed"] == m0["records_pushed"]:  # the planner pushes at its next wake
            sup.run_ticks(1)
        start_to_motion_s = time.perf_counter() - t0
        records = _run_to_end(sup, m0["run_seq"] + 1)
        m, s = sup.motion(), sup.servo()
    program = _as_run(program_path, config, s0["commanded_mm"])
    metrics = _metrics(records, program, config, dt)
    plan, cut_text = cut_plan_for(program, cut, config, Path(program_path).name)
    metrics["cut"] = cut_text
    if plan is not None:
        metrics["quality"] = _by_quality(records, plan, dt)
    metrics.update(
        cycle_time_s=(m["records_pushed"] - m0["records_pushed"]) * dt,  # one record per servo period
        planned_cycle_time_s=m0["planned_s"],
        load_s=load_s,  # wall time of the load command: interpretation, travel check, first steps
        start_to_motion_s=start_to_motion_s,  # wall time from the start command to the first setpoint in the FIFO
        fifo_min_fill=int(m["fifo_min_fill"]),
        underruns=int(s["underruns"] - s0["underruns"]),
        overruns=int(s["overruns"] - s0["overruns"]),
        result=RunResult(m["run_result"]).name,
    )
    xy = sample(elements_from_program(program.segments), step_mm=0.05)
    return SimulationResult(Path(program_path).name, metrics, records, xy, dt, plan)


def _as_run(program_path: str, config: MachineConfig, start_mm: list[float]) -> Program:
    """The program as the planner ran it: interpreted from where the head stood at the start."""
    start = [0.0, 0.0, 0.0]
    for name, value in zip(config.axis_names, start_mm):
        start["xyz".index(name)] = value
    dialect = dataclasses.replace(dialect_for(config), start_position_mm=tuple(start))
    return Interpreter(dialect, program_path).run(Path(program_path).read_bytes())


def speed_along_path(records: np.ndarray, plan: CutPlan, dt: float) -> tuple[np.ndarray, ...]:
    """Per servo period: the distance along the path (mm), the setpoint speed (mm/s), the quality
    in force where the jet cuts (0 elsewhere) and that quality's straight speed (mm/s)."""
    cmd = records["commanded"][:, :2]
    step = np.concatenate(([0.0], np.hypot(*np.diff(cmd, axis=0).T)))
    distance, speed = np.cumsum(step), step / dt
    segment = np.clip(records["segment"].astype(np.int64), 0, len(plan.quality) - 1)
    cutting = (records["flags"] & int(SetpointFlag.JET_ON)) != 0
    quality = np.where(cutting, plan.quality[segment], 0).astype(np.int64)
    return distance, speed, quality, plan.model.speed_mm_s[quality]


def _by_quality(records: np.ndarray, plan: CutPlan, dt: float) -> dict:
    """Per quality: the length cut at it, its peak speed and its straight speed (the peak never above)."""
    distance, speed, quality, straight = speed_along_path(records, plan, dt)
    step = np.diff(distance, prepend=0.0)
    out = {}
    for q in range(1, 6):
        at = quality == q
        if at.any():
            out[str(q)] = {"cut_mm": float(step[at].sum()), "peak_speed_mm_s": float(speed[at].max()),
                           "straight_speed_mm_s": float(straight[at][0])}
    return out


def _prepare(sup: Supervisor, program_path: str, cut: CutSetup | None = None) -> float:
    """Home the machine and load the program; the load's wall time (s)."""
    sup.enable()
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 10.0, "the servo to close the loop")
    _ask_planner(sup, Home(), "homing")
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE, 300.0, "homing")
    if sup.motion()["error"]:
        raise SimulationError(f"homing failed: {sup.motion()['error']}")
    sup.wait_until(lambda: abs(max(sup.servo()["following_error_mm"], key=abs)) < 0.002, 10.0, "the axes to settle")
    t0 = time.perf_counter()
    given = None if cut is None else SetCut(cut.material, cut.thickness_mm, cut.quality, cut.mode, cut.pierce_quality)
    _ask_planner(sup, LoadProgram(str(Path(program_path).resolve()), cut=given), "loading the program")
    return time.perf_counter() - t0


def _run_to_end(sup: Supervisor, run: int) -> np.ndarray:
    """Step the clock until the run has ended and the table settled; every tick's trace record."""
    chunks = []
    settle_ticks = int(SETTLE_S / sup.config.timing.period_s)
    ended_at = None
    while True:
        sup.run_ticks(CHUNK_TICKS if ended_at is None else settle_ticks)
        chunks.append(sup.trace.drain())
        m = sup.motion()
        if ended_at is not None:
            break
        if m["run_seq"] == run and m["state"] == PlannerState.IDLE:
            ended_at = m["run_end_tick"]
        if sup.servo()["state"] == ServoState.FAULT:
            raise SimulationError(f"the servo tripped: {sup.servo_fault().name} ({m['error']})")
    if sup.trace.dropped():
        raise SimulationError(f"the trace ring dropped {sup.trace.dropped()} ticks")
    records = np.concatenate(chunks)
    records = records[records["tick"] <= ended_at + settle_ticks]
    first = np.flatnonzero(records["flags"] & int(SetpointFlag.IN_MOTION))  # the program's first record
    return records[first[0]:] if len(first) else records


def _metrics(records: np.ndarray, program, config: MachineConfig, dt: float) -> dict:
    names = config.axis_names
    cmd, act, vel = records["commanded"], records["actual"], records["velocity"]
    path = ProgrammedPath(program.segments)
    seg = records["segment"].astype(np.int64)
    deviation = path.distance(cmd, seg)
    contour = path.distance(act, seg)
    rapid = program.segments["kind"][np.clip(seg, 0, len(program.segments) - 1)] == RAPID
    err = act - cmd
    speed = np.hypot(vel[:, 0], vel[:, 1])
    moving = speed > 1e-6
    ux = np.where(moving, vel[:, 0] / np.where(moving, speed, 1.0), 0.0)
    uy = np.where(moving, vel[:, 1] / np.where(moving, speed, 1.0), 0.0)
    normal = np.where(moving, np.abs(ux * err[:, 1] - uy * err[:, 0]), np.hypot(err[:, 0], err[:, 1]))
    pk = peaks(cmd, dt)
    per_axis = lambda arr: {a: float(arr[i]) for i, a in enumerate(names)}  # noqa: E731
    return {
        "path_deviation_max_mm": float(deviation.max()),
        "tracking_error_max_mm": float(normal.max()),
        "tracking_error_rms_mm": float(math.sqrt(np.mean(normal**2))),
        "contour_error_max_mm": float(contour[~rapid].max()) if (~rapid).any() else 0.0,
        "contour_error_rapid_max_mm": float(contour[rapid].max()) if rapid.any() else 0.0,
        "following_error_max_mm": per_axis(np.abs(err).max(axis=0)),
        "peak_velocity_mm_s": per_axis(pk["velocity"]),
        "peak_accel_mm_s2": per_axis(pk["acceleration"]),
        "peak_jerk_mm_s3": per_axis(pk["jerk"]),
        "ticks_recorded": int(len(records)),
    }


def report(result: SimulationResult, out: IO[str]) -> None:
    """The figures as a short table."""
    m = result.metrics
    axes = list(m["following_error_max_mm"])
    rows = [
        ("cycle time", f"{m['cycle_time_s']:.3f} s", f"planned {m['planned_cycle_time_s']:.3f} s"),
        ("path deviation (setpoints vs program)", f"{m['path_deviation_max_mm'] * 1000:.2f} um", ""),
        ("tracking error normal to the path", f"{m['tracking_error_max_mm'] * 1000:.2f} um max",
         f"{m['tracking_error_rms_mm'] * 1000:.2f} um rms"),
        ("contour error (actual vs program)", f"{m['contour_error_max_mm'] * 1000:.2f} um",
         f"on the cut; rapids {m['contour_error_rapid_max_mm'] * 1000:.2f} um"),
    ]
    for key, label, scale, unit in (
        ("following_error_max_mm", "following error", 1000.0, "um"), ("peak_velocity_mm_s", "peak velocity", 1.0, "mm/s"),
        ("peak_accel_mm_s2", "peak acceleration", 1.0, "mm/s^2"), ("peak_jerk_mm_s3", "peak jerk", 1.0, "mm/s^3"),
    ):
        rows.append((label, "  ".join(f"{a.upper()} {m[key][a] * scale:.6g}" for a in axes), unit))
    rows.append(("FIFO", f"min fill {m['fifo_min_fill']}", f"underruns {m['underruns']}, overruns {m['overruns']}"))
    if m.get("cut"):
        rows.append(("cutting job", m["cut"], ""))
        for q, f in m.get("quality", {}).items():
            rows.append((f"  quality {q}", f"{f['cut_mm']:.1f} mm cut", f"peak {f['peak_speed_mm_s'] * 60:.0f} mm/min, "
                         f"straight {f['straight_speed_mm_s'] * 60:.0f} mm/min"))
    print(f"{result.program}: {m['result']}", file=out)
    for label, value, note in rows:
        print(f"  {label:<40} {value:<28} {note}", file=out)


def run_cli(program: str, machine: str, json_out: str | None, plot_out: str | None, out: IO[str], err: IO[str],
            cut: CutSetup | None = None) -> int:
    """`waterjet simulate`: exit 0 with the figures, 1 when the program cannot run (with the reason)."""
    config = load_machine(machine, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"]})
    try:
        result = simulate(program, config, cut)
    except (SimulationError, ScriptError, SupervisorError, TimeoutError, CutPlanError) as exc:
        print(f"waterjet simulate: {exc}", file=err)
        return 1
    report(result, out)
    if json_out:
        Path(json_out).write_text(json.dumps({"program": result.program, **result.metrics}, indent=2) + "\n")
    if plot_out:
        from ..logger.plots import plot_run

        r = result.trace
        plot_run(
            plot_out, t_s=np.arange(len(r)) * result.dt, commanded_mm=r["commanded"], actual_mm=r["actual"],
            velocity_mm_s=r["velocity"], speed_command_v=r["speed_cmd"], programmed_xy=result.programmed_xy,
            title=f"{result.program}: simulated run",
        )
        if result.cut is not None:
            from ..logger.plots import plot_speed_by_quality

            distance, speed, quality, straight = speed_along_path(r, result.cut, result.dt)
            speed_png = Path(plot_out).with_name(Path(plot_out).stem + "-speed.png")
            plot_speed_by_quality(speed_png, distance, speed, quality, straight,
                                  title=f"{result.program}: speed along the path, {result.metrics['cut']}")
            print(f"  speed along the path by quality: {speed_png}", file=out)
    return 0

