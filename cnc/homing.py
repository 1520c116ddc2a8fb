"""Homing an axis: search the home switch, back off it onto the encoder's index pulse, set the position.

Incremental encoders count from wherever the machine was switched on, so each axis must be
homed before positions mean anything (and before soft limits or programs apply):

1. search: run towards the switch at `home_search_velocity_mm_s` until it is active;
2. stop, jerk-limited;
3. latch: back off at `home_latch_velocity_mm_s` until the switch releases, then on until the
   encoder's index pulse; the count the board latched at that pulse is the reference;
4. set the position: that count is `home_index_position_mm` (the servo shifts its frame
   at a tick boundary without moving the table), then park at `home_final_position_mm`.

Homing is a sequence of steps the FIFO's producer (the planner process) carries out between
its refills: push these setpoints (short chunks, so that a switch is seen within one), or
apply this position reference. The sequence checks the switches each time it is resumed,
which is once its last chunk has nearly run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Trajectory

from .config import MachineConfig
from .data.fifo import SetpointFlag, setpoint_dtype
from .hw.board import AxisIn
from .data.layout import ServoFault, ServoState

CHUNK_S = 0.02  # setpoints pushed per step: a switch is seen within this much motion


class HomingError(RuntimeError):
    """Homing could not be completed; the message says which axis and why."""


@dataclass
class Push:
    """Stream these setpoints; resume the sequence when they have nearly run."""

    records: np.ndarray


@dataclass
class Reference:
    """Encoder count `counts` of `axis` is machine position `position_mm`; resume once the servo applied it."""

    axis: int
    counts: int
    position_mm: float


@dataclass
class Unhome:
    """`axis` loses its position reference (homing it again: its soft limits no longer apply, and a
    homing that fails leaves it unhomed); resume once the servo applied it."""

    axis: int


@dataclass
class Settle:
    """Resume once every setpoint pushed so far has run and the servo holds (positions are then current)."""


HomingStep = Push | Reference | Unhome | Settle


class Homing:
    """Homes the axes of one machine; `hw()` and `servo()` read the hardware image and the servo block."""

    def __init__(self, config: MachineConfig, hw: Callable[[], dict], servo: Callable[[], dict]) -> None:
        self.config, self.hw, self.servo = config, hw, servo
        self.n = len(config.axis_names)
        self.dt = config.timing.period_s
        self.axis = -1  # the axis being homed

    def steps(self, axes: list[str] | None = None) -> Iterator[HomingStep]:
        """The whole homing, axis by axis in the order given (all axes by default)."""
        names = axes or list(self.config.axis_names)
        for name in names:
            if name not in self.config.axis:
                raise HomingError(f"no axis {name!r} on this machine (axes: {', '.join(self.config.axis_names)})")
        for name in names:
            self.axis = self.config.axis_names.index(name)
            yield from self.home_axis(self.axis)
        yield Settle()  # done once the last park move has run
        self.axis = -1

    def home_axis(self, i: int) -> Iterator[HomingStep]:
        name = self.config.axis_names[i].upper()
        a = self.config.axis[self.config.axis_names[i]]
        yield Settle()  # the previous axis' park move has run: the commanded position is where it ends
        self._check_servo(name)
        if self.servo()["homed_mask"] >> i & 1:
            yield Unhome(i)  # homing again: the search travels beyond the travel end, onto the switch
        position = list(self.servo()["commanded_mm"])
        # 1-2. search the switch (unless already on it), then stop
        search = a.home_search_velocity_mm_s
        limit_mm = (a.travel_max_mm - a.travel_min_mm) * 1.2 + 50.0
        if not self._on_switch(i):
            position = yield from self._run(i, position, search, lambda: self._on_switch(i), limit_mm, "the home switch")
        # 3. back off the switch, then on to the next index pulse
        back = -math.copysign(a.home_latch_velocity_mm_s, search)
        position = yield from self._run(i, position, back, lambda: not self._on_switch(i), limit_mm, "the switch to release")
        released = self.hw()["index_latch_seq"][i]
        pitch_guard = 50.0  # mm: several index pitches
        position = yield from self._run(
            i, position, back, lambda: self.hw()["index_latch_seq"][i] != released, pitch_guard, "the encoder index pulse",
        )
        counts = self.hw()["index_latch_counts"][i]
        # 4. set the position, park
        yield Reference(i, counts, a.home_index_position_mm)
        yield Push(self._park(i, list(self.servo()["commanded_mm"]), a.home_final_position_mm))
        self._check_servo(name)

    # -----------------------------------------------------------------------------------
    def _run(self, i: int, position: list[float], velocity: float, until, max_mm: float, what: str):
        """Accelerate to `velocity` along axis i, hold it until `until()`, stop; return where the stop ends."""
        name = self.config.axis_names[i].upper()
        travelled, v = 0.0, 0.0
        while True:
            chunk, v = self._ramp(i, position, v, velocity, CHUNK_S)
            yield Push(chunk)
            travelled += abs(chunk["position"][-1][i] - position[i])
            position = list(chunk["position"][-1])
            self._check_servo(name)
            if until():
                break
            if travelled > max_mm:
                yield from self._stop(i, position, v)
                raise HomingError(f"axis {name}: {what} not found within {max_mm:.0f} mm")
        return (yield from self._stop(i, position, v))

    def _stop(self, i: int, position: list[float], v: float):
        chunk, _ = self._ramp(i, position, v, 0.0, None)
        if len(chunk):
            yield Push(chunk)
        return list(chunk["position"][-1]) if len(chunk) else position

    def _ramp(self, i: int, position: list[float], v0: float, v1: float, hold_s: float | None):
        """Setpoints for a jerk-limited change of axis i's velocity from v0 to v1, then `hold_s` at v1."""
        traj = self._solve(i, position[i], v0, target_velocity=v1)
        if traj is None:
            raise HomingError(f"axis {self.config.axis_names[i].upper()}: no velocity ramp from {v0:g} to {v1:g} mm/s")
        ramp_steps = math.ceil(traj.duration / self.dt) if v0 != v1 else 0
        hold_steps = 0 if hold_s is None else max(1, round(hold_s / self.dt))
        out = self._sample(traj, i, position, ramp_steps, hold_steps)
        end = out["position"][ramp_steps - 1, i] if ramp_steps else position[i]
        for k in range(hold_steps):
            out["position"][ramp_steps + k, i] = end + v1 * (k + 1) * self.dt
            out["velocity"][ramp_steps + k, i] = v1
        if v1 == 0.0 and len(out):
            out["flags"][-1] = 0
            out["velocity"][-1] = 0.0
        return out, v1

    def _park(self, i: int, position: list[float], target: float) -> np.ndarray:
        """A jerk-limited move of axis i alone to `target` (the other axes may not be homed yet)."""
        traj = self._solve(i, position[i], 0.0, target_position=target)
        if traj is None:
            raise HomingError(f"axis {self.config.axis_names[i].upper()}: no move to the park position {target:g} mm")
        out = self._sample(traj, i, position, max(1, math.ceil(traj.duration / self.dt)))
        out["position"][-1, i], out["velocity"][-1] = target, 0.0
        out["flags"][-1] = 0
        return out

    def _solve(self, i: int, p0: float, v0: float, target_velocity: float | None = None, target_position: float | None = None):
        """Ruckig's time-optimal trajectory for axis i alone (velocity target, or position target at rest); None if none."""
        a = self.config.axis[self.config.axis_names[i]]
        otg, inp, traj = Ruckig(1), InputParameter(1), Trajectory(1)
        inp.current_position, inp.current_velocity, inp.current_acceleration = [p0], [v0], [0.0]
        if target_position is None:
            inp.control_interface = ControlInterface.Velocity
            inp.target_velocity, inp.target_acceleration = [target_velocity], [0.0]
        else:
            inp.target_position, inp.target_velocity = [target_position], [0.0]
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = [a.max_velocity_mm_s], [a.max_accel_mm_s2], [a.max_jerk_mm_s3]
        return traj if otg.calculate(inp, traj) in (Result.Working, Result.Finished) else None

    def _sample(self, traj, i: int, position: list[float], steps: int, extra: int = 0) -> np.ndarray:
        """`steps` setpoints along `traj` for axis i (the others stay at `position`), room for `extra` more."""
        out = np.zeros(steps + extra, dtype=setpoint_dtype(self.n))
        out["position"][:] = position
        for k in range(steps):
            p, vel, _ = traj.at_time(min((k + 1) * self.dt, traj.duration))
            out["position"][k, i], out["velocity"][k, i] = p[0], vel[0]
        out["flags"] = SetpointFlag.IN_MOTION
        return out

    def _on_switch(self, i: int) -> bool:
        return bool(self.hw()["axis_inputs"][i] & AxisIn.HOME)

    def _check_servo(self, name: str) -> None:
        s = self.servo()
        if s["state"] == ServoState.FAULT:
            raise HomingError(f"axis {name}: homing stopped, the servo tripped ({ServoFault(s['fault']).name})")
        if s["state"] == ServoState.DISABLED:
            raise HomingError(f"axis {name}: the drives are off; enable them before homing")
