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

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import MachineConfig
from ..hw.board import BoardInputs
from ..hw.sim_board import SimBoard
from .program import ControlInputs, ControlProgram, outputs_problem

TRAJECTORIES = ("hold", "step", "ramp", "circle", "fig10")
FIG10 = Path(__file__).with_name("fig10_contour.ngc")
STEP_MM = 0.2  # the position step
RAMP_MM_S = 50.0  # the ramp's speed
CIRCLE_RADIUS_MM, CIRCLE_MM_MIN = 20.0, 12000.0
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


# one pass of each trajectory on the machine (`run_text`): its G-code and about how long it takes
STEP_PASS = ("G91 G1 X{step} F{fast}\nG4 P0.25\nG1 X-{step}\nG4 P0.25\n", 0.5)
RAMP_PASS = ("G91 G1 X20 F{ramp}\nG1 X-20\n", 0.8)
CIRCLE_PASS = ("G91 G2 X0 Y0 I-{r} J0 F{circle}\n", 2.0 * math.pi * CIRCLE_RADIUS_MM / (CIRCLE_MM_MIN / 60.0))
FIG10_PASS_S = 4.7
MAX_PASSES = 100000


def run_text(kind: str, duration_s: float, config: MachineConfig) -> str:
    """The G-code of a timed control run on the machine (`ControlRun`): `kind` from where the head
    stands (hold; step, ramp and circle on X and Y; fig10 at the contour's own place), repeated
    (an O-word repeat) for at least `duration_s`; the commander stops it on the path when the
    time is up. No jet: a control run cuts nothing. ValueError names what is wrong."""
    if kind not in TRAJECTORIES:
        raise ValueError(f"trajectory {kind!r} is not one of: {', '.join(TRAJECTORIES)}")
    if not (math.isfinite(duration_s) and 0.1 <= duration_s <= 3600.0):
        raise ValueError(f"duration_s {duration_s!r} is out of range: 0.1 to 3600 s")
    head = "(control run: {kind} for {d:g} s)\nG21 G17 G40 G64 P0.005\n".format(kind=kind, d=duration_s)
    if kind == "hold":
        return head + f"G4 P{duration_s:.3f}\nM2\n"
    fast = min(a.max_velocity_mm_s for a in config.axes) * 60.0
    if kind == "fig10":
        body = "\n".join(line for line in FIG10.read_text().splitlines()
                          if line.strip() and not line.lstrip().startswith(("M2", "M30", "%")))
        body, one = "G90\n" + body + "\n", FIG10_PASS_S
    else:
        text, one = {"step": STEP_PASS, "ramp": RAMP_PASS, "circle": CIRCLE_PASS}[kind]
        body = text.format(step=STEP_MM, fast=f"{fast:.0f}", ramp=f"{RAMP_MM_S * 60.0:.0f}", r=f"{CIRCLE_RADIUS_MM:g}",
                           circle=f"{CIRCLE_MM_MIN:.0f}")
    passes = min(MAX_PASSES, int(math.ceil(duration_s / one)) + 1)
    return head + f"o100 repeat [{passes}]\n{body}o100 endrepeat\nG90\nM2\n"


def run(program: ControlProgram, config: MachineConfig, kind: str = "circle", duration_s: float = 1.0,
        budget_ns: float | None = None) -> TrialResult:
    """Run `program` on a fresh simulated plant along trajectory `kind`; stop at its first failure
    (an exception, a non-finite or missing command, a period over `budget_ns` of CPU time)."""
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
        if not why and budget_ns is not None and used[k] > budget_ns:
            why = f"used {used[k] / 1000:.0f} us of CPU in a period, over its budget of {budget_ns / 1000:.0f} us"
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
