"""The waterjet paper's PI-P: a PI position loop with velocity and acceleration feed-forward.

The P velocity loop is in the drive; this program is the position loop. Per axis

    u = velocity_ff * v_ref + accel_ff_s * a_ref + kp * e + ki * integral(e)    [mm/s]

with e = setpoint - actual, the integral clamped so that its term stays within
`integral_limit_mm_s`. The acceleration feed-forward makes up for the drive's lag and the
one-period output delay, which keeps the following error small on curves, not only on
straights. Its gains are the machine file's `[axis.<a>]` options, tuned online as before.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .program import ControlInputs, ControlProgram

if TYPE_CHECKING:
    from ..config import MachineConfig

GAINS = ("kp_1_s", "ki_1_s2", "velocity_ff", "accel_ff_s", "integral_limit_mm_s")


class PIP(ControlProgram):
    """PI position loop + velocity and acceleration feed-forward, per axis (the shipped law)."""

    description = "PI position loop with velocity and acceleration feed-forward (the waterjet paper's PI-P)"

    def __init__(self, machine: "MachineConfig") -> None:
        super().__init__(machine)
        for option in GAINS:
            self.register_parameter(option, 0.0, per_axis=True, option=option)
        self._integral = [0.0] * self.n_axes
        self._out = [0.0] * self.n_axes

    def start_control(self) -> None:
        self._integral = [0.0] * self.n_axes

    def position_referenced(self, axis: int) -> None:
        self._integral[axis] = 0.0

    def control(self, inputs: ControlInputs) -> list[float]:
        dt, out, integral = inputs.dt_s, self._out, self._integral
        kp, ki, kv, ka, i_lim = self.kp_1_s, self.ki_1_s2, self.velocity_ff, self.accel_ff_s, self.integral_limit_mm_s
        error, velocity, accel = inputs.error_mm, inputs.setpoint_velocity_mm_s, inputs.setpoint_accel_mm_s2
        for i in range(len(out)):
            e = error[i]
            integ = integral[i] + e * dt
            lim = i_lim[i] / ki[i] if ki[i] > 0.0 else 0.0
            integ = lim if integ > lim else -lim if integ < -lim else integ
            integral[i] = integ
            out[i] = kv[i] * velocity[i] + ka[i] * accel[i] + kp[i] * e + ki[i] * integ
        return out
