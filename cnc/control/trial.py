"""A control program on the simulated plant, without the controller: test trajectories, the dry
run that checks a program before it is selected, and the figures that compare programs.

The loop is the servo's (`cnc.servo`): each period the encoders are read, the program computes
the speed commands from the same `ControlInputs`, they are scaled into volts and clamped to the
drive's full scale, and they reach the drive one period later (the output delay of the real
hardware server). The plant is the simulated board's (`cnc.hw.sim_board`): the drive's lag,
viscous and Coulomb friction, its current limit. The trajectories are those of QMotor's
experiments: hold, a position step, a ramp, a circle and the paper's Fig. 10 contour, the last
two planned by the real planner (jerk-limited, as a program would run them).
"""

from __future__ import annotations

import gc
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..config import MachineConfig
from ..hw.board import BoardInputs
from ..hw.sim_board import SimBoard
from .program import ControlInputs, ControlProgram, outputs_problem

from .trajectories import CIRCLE_MM_MIN, CIRCLE_RADIUS_MM, FIG10, RAMP_MM_S, STEP_MM, TRAJECTORIES  # noqa: F401 - TRAJECTORIES: for the callers
DIRECTION_MM_S = 1.0  # below this setpoint speed the path's direction is not known: no contour error


@dataclass
class Trajectory:
    """Setpoints per period: positions and velocities (N x axes)."""

    name: str
    position: np.ndarray
    velocity: np.ndarray

    def __len__(self) -> int:
        return len(self.position)


@dataclass
class TrialResult:
    """What one trial of a program showed."""

    program: str
    trajectory: str
    periods: int
    following_error_mm: np.ndarray  # N x axes: setpoint - measured
    contour_error_mm: np.ndarray  # N: the following error's component normal to the path (0 below DIRECTION_MM_S)
    control_ns: np.ndarray  # N: the program's CPU time per period
    failure: str = ""  # what the program did wrong ("" none), at `failed_at`
    failed_at: int = -1
    figures: dict = field(default_factory=dict)

    def summary(self) -> dict[str, float]:
        """The figures: following and contour error (max, RMS), computation time (p50, p99, max)."""
        fe = np.abs(self.following_error_mm) if len(self.following_error_mm) else np.zeros((1, 1))
        ce = np.abs(self.contour_error_mm) if len(self.contour_error_mm) else np.zeros(1)
        ns = self.control_ns if len(self.control_ns) else np.zeros(1)
        return {
            "max_following_error_mm": float(fe.max()),
            "rms_following_error_mm": float(np.sqrt(np.mean(fe ** 2))),
            "max_contour_error_mm": float(ce.max()),
            "rms_contour_error_mm": float(np.sqrt(np.mean(ce ** 2))),
            "control_p50_us": float(np.percentile(ns, 50) / 1000.0),
            "control_p99_us": float(np.percentile(ns, 99) / 1000.0),
            "control_max_us": float(ns.max() / 1000.0),
        }


def trajectory(kind: str, config: MachineConfig, start: list[float], duration_s: float = 1.0) -> Trajectory:
    """A test trajectory from `start` (machine mm per axis): "hold", "step" (STEP_MM on the first
    axis at a tenth of the duration), "ramp" (RAMP_MM_S on the first axis from a tenth), "circle"
    and "fig10" (planned as programs: their own length, then at rest to the duration)."""
    dt, n = config.timing.period_s, len(config.axis_names)
    if kind in ("circle", "fig10"):
        return _planned(kind, config, start, duration_s)
    if kind not in TRAJECTORIES:
        raise ValueError(f"trajectory {kind!r} is not one of: {', '.join(TRAJECTORIES)}")
    count = max(2, int(round(duration_s / dt)))
    pos = np.tile(np.asarray(start, dtype=float), (count, 1))
    vel = np.zeros((count, n))
    begin = count // 10
    if kind == "step":
        pos[begin:, 0] += STEP_MM
    elif kind == "ramp":
        t = np.arange(count - begin) * dt
        pos[begin:, 0] += RAMP_MM_S * t
        vel[begin:, 0] = RAMP_MM_S
    return Trajectory(kind, pos, vel)


def _planned(kind: str, config: MachineConfig, start: list[float], duration_s: float) -> Trajectory:
    import dataclasses  # noqa: PLC0415

    from gcode.interp import Interpreter  # noqa: PLC0415

    from ..machine_dialect import dialect_for  # noqa: PLC0415
    from ..planner.runner import ProgramRunner  # noqa: PLC0415

    names = config.axis_names
    xyz = [0.0, 0.0, 0.0]
    for a, v in zip(names, start):
        xyz["xyz".index(a)] = float(v)
    if kind == "circle":
        x, y = xyz[0], xyz[1]
        text = (f"G21 G90 G17 G64 P0.005\nG1 X{x + CIRCLE_RADIUS_MM:.4f} Y{y:.4f} F{CIRCLE_MM_MIN:g}\n"
                f"G2 X{x + CIRCLE_RADIUS_MM:.4f} Y{y:.4f} I{-CIRCLE_RADIUS_MM:g} J0\nG1 X{x:.4f} Y{y:.4f}\nM2\n")
    else:
        text = FIG10.read_text()
    dialect = dataclasses.replace(dialect_for(config), start_position_mm=tuple(xyz))
    program = Interpreter(dialect, f"{kind}.ngc").run(text.encode())
    runner = ProgramRunner(program, config)
    chunks = []
    while not runner.idle:
        records, _ = runner.take(4096)
        if len(records):
            chunks.append(records)
    records = np.concatenate(chunks)
    # at rest at the end: a tenth of a second, or what the duration asks for beyond the program
    settle = max(int(round(0.1 / config.timing.period_s)), int(round(duration_s / config.timing.period_s)) - len(records))
    pos = np.vstack((records["position"], np.tile(records["position"][-1], (settle, 1))))
    vel = np.vstack((records["velocity"], np.zeros((settle, len(names)))))
    return Trajectory(kind, pos, vel)


def run(program: ControlProgram, config: MachineConfig, kind: str = "circle", duration_s: float = 1.0,
        budget_ns: float | None = None) -> TrialResult:
    """Run `program` on a fresh simulated plant along trajectory `kind`; stop at its first failure
    (an exception, a non-finite or missing command, `[control] budget_overruns` periods in a row
    over `budget_ns` of CPU time: the servo's own rule). As in the servo process, the cyclic
    garbage collector does not run meanwhile: a pass over the caller's heap (a millisecond in a
    large process) would be counted to the program."""
    was_collecting = gc.isenabled()
    gc.disable()
    try:
        return _run(program, config, kind, duration_s, budget_ns)
    finally:
        if was_collecting:
            gc.enable()


def _run(program: ControlProgram, config: MachineConfig, kind: str, duration_s: float,
         budget_ns: float | None) -> TrialResult:
    board = SimBoard(config)
    n, dt = board.n_axes, config.timing.period_s
    start = [board.position_mm(i) for i in range(n)]
    traj = trajectory(kind, config, start, duration_s)
    inputs_hw = BoardInputs(n)
    res = [a.encoder_resolution_mm for a in config.axes]
    vpm = [a.volts_per_mm_s for a in config.axes]
    vmax = [a.drive_full_scale_v for a in config.axes]
    board.read_inputs(inputs_hw)
    offset = [start[i] - inputs_hw.encoder_counts[i] * res[i] for i in range(n)]  # homed where it stands
    inp = ControlInputs(n)
    count = len(traj)
    fe = np.zeros((count, n))
    ce = np.zeros(count)
    used = np.zeros(count, dtype=np.int64)
    pending = [0.0] * n
    v_prev = [0.0] * n
    actual_prev = list(start)
    name = f"{type(program).__name__}"
    result = TrialResult(name, kind, 0, fe, ce, used)
    try:
        program._started()
    except Exception as exc:  # noqa: BLE001 - the user's code
        result.failure, result.failed_at = f"start_control raised {type(exc).__name__}: {exc}", 0
        return _cut(result, 0)
    mask = (1 << n) - 1
    overruns, over_budget = config.control.budget_overruns, 0
    for k in range(count):
        board.read_inputs(inputs_hw)
        actual = [inputs_hw.encoder_counts[i] * res[i] + offset[i] for i in range(n)]
        board.write_outputs(pending, mask, 0)  # last period's command: the output delay
        sp, sv = traj.position[k], traj.velocity[k]
        for i in range(n):
            e = float(sp[i]) - actual[i]
            inp.error_mm[i] = e
            fe[k, i] = e
            inp.setpoint_mm[i] = float(sp[i])
            inp.setpoint_velocity_mm_s[i] = float(sv[i])
            inp.setpoint_accel_mm_s2[i] = (float(sv[i]) - v_prev[i]) / dt
            v_prev[i] = float(sv[i])
            inp.actual_mm[i] = actual[i]
            inp.velocity_mm_s[i] = (actual[i] - actual_prev[i]) / dt
        actual_prev = actual
        inp.dt_s, inp.moving = dt, bool(np.any(sv != 0.0))
        t0 = time.thread_time_ns()
        try:
            u = program.control(inp)
            used[k] = time.thread_time_ns() - t0
            program._counted(dt)
            why = outputs_problem(u, config.axis_names)
        except Exception as exc:  # noqa: BLE001
            used[k] = time.thread_time_ns() - t0
            why = f"raised {type(exc).__name__}: {exc}"
        if budget_ns is not None:
            over_budget = over_budget + 1 if used[k] > budget_ns else 0
            if not why and over_budget >= overruns:
                why = (f"used {used[k] / 1000:.0f} us of CPU in a period, over its budget of {budget_ns / 1000:.0f} us"
                       f" ({over_budget} period{'s' if over_budget != 1 else ''} in a row)")
        if why:
            result.failure, result.failed_at = why, k
            return _cut(result, k + 1)
        speed = math.hypot(*(float(x) for x in sv[:2])) if n >= 2 else abs(float(sv[0]))
        if speed > DIRECTION_MM_S and n >= 2:  # the error's component normal to the direction of motion
            ce[k] = (fe[k, 0] * float(sv[1]) - fe[k, 1] * float(sv[0])) / speed
        pending = [max(-vmax[i], min(vmax[i], float(u[i]) * vpm[i])) for i in range(n)]
        board.advance(dt)
    try:
        program.stop_control()
    except Exception as exc:  # noqa: BLE001
        result.failure, result.failed_at = f"stop_control raised {type(exc).__name__}: {exc}", count - 1
    return _cut(result, count)


def _cut(result: TrialResult, periods: int) -> TrialResult:
    result.periods = periods
    result.following_error_mm = result.following_error_mm[:periods]
    result.contour_error_mm = result.contour_error_mm[:periods]
    result.control_ns = result.control_ns[:periods]
    return result
