"""Point-to-point moves as setpoint records: a jerk-limited, time-synchronised profile per move.

Used to command straight positioning moves (the demo, tests, and the manual go-to) with
the axis limits of the machine file. All axes arrive together (ruckig's time
synchronisation), so the head travels on the straight line between the points.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Trajectory

from .config import MachineConfig
from .data.fifo import SetpointFlag, setpoint_dtype


class MoveError(ValueError):
    """A requested move is not possible (outside travel, bad number)."""


def move_setpoints(
    config: MachineConfig,
    start: Sequence[float],
    target: Sequence[float],
    flags: int = 0,
    segment: int = 0,
    line: int = 0,
    velocity_scale: float = 1.0,
) -> np.ndarray:
    """Setpoints at the servo period from `start` to `target` (mm), both at rest.

    Every record but the last carries IN_MOTION; the last sits exactly on the target.
    """
    axes = config.axes
    n = len(axes)
    if len(start) != n or len(target) != n:
        raise MoveError(f"a move needs {n} coordinates ({', '.join(config.axis_names)})")
    for name, a, p in zip(config.axis_names, axes, target):
        if not math.isfinite(p) or not a.travel_min_mm <= p <= a.travel_max_mm:
            raise MoveError(
                f"target {name.upper()}{p:g} is outside the travel {a.travel_min_mm:g} to {a.travel_max_mm:g} mm"
            )
    if not 0.0 < velocity_scale <= 1.0:
        raise MoveError(f"velocity scale {velocity_scale:g} must be in (0, 1]")
    dt = config.timing.period_s
    otg = Ruckig(n)
    inp = InputParameter(n)
    inp.current_position = list(start)
    inp.target_position = list(target)
    inp.max_velocity = [a.max_velocity_mm_s * velocity_scale for a in axes]
    inp.max_acceleration = [a.max_accel_mm_s2 for a in axes]
    inp.max_jerk = [a.max_jerk_mm_s3 for a in axes]
    traj = Trajectory(n)
    result = otg.calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise MoveError(f"no trajectory from {list(start)} to {list(target)}: {result}")
    steps = max(1, math.ceil(traj.duration / dt))
    out = np.zeros(steps, dtype=setpoint_dtype(n))
    for k in range(steps):
        pos, vel, _ = traj.at_time((k + 1) * dt)
        out[k]["position"] = pos
        out[k]["velocity"] = vel
    out["position"][-1] = target
    out["velocity"][-1] = 0.0
    out["flags"] = flags | SetpointFlag.IN_MOTION
    out["flags"][-1] = flags
    out["flags"][0] |= SetpointFlag.SEGMENT_START
    out["segment"] = segment
    out["line"] = line
    return out
