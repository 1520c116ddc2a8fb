"""Cross-coupled contour control (Koren): the PI-P plus a loop on the contour error.

Per-axis loops see only their own following error; what spoils the cut is the error normal to
the path, the contour error. With t the unit vector of the setpoint velocity (X, Y) and n its
normal, the contour error is the following error's component along n; this program adds a
proportional correction along n to both axes' commands:

    e_c = e . n,    u = PI-P + contour_gain_1_s * e_c * n

so the loop is stiffer across the path than along it, where an error only delays the head a
little. Below `min_speed_mm_s` (at rest, at a stop) the direction is not known and the
correction is off. Axes beyond the first two are left to the PI-P.
"""

from __future__ import annotations

import math

from ..pip import PIP
from ..program import ControlInputs


class CrossCoupled(PIP):
    """PI-P with a cross-coupled correction of the contour error (XY)."""

    description = "PI-P plus cross-coupled contour control (lower contour error on curves)"

    def __init__(self, machine) -> None:  # noqa: ANN001 - a MachineConfig
        super().__init__(machine)
        if self.n_axes < 2:
            from ..program import ControlProgramError  # noqa: PLC0415

            raise ControlProgramError("cross-coupled contour control needs two axes (X and Y)")
        self.register_parameter("contour_gain_1_s", 80.0, "1/s", (0.0, 1000.0),
                                "speed command across the path per mm of contour error")
        self.register_parameter("min_speed_mm_s", 1.0, "mm/s", (0.001, 1000.0),
                                "setpoint speed below which the path direction is unknown (no correction)")
        self.register_log_variable("contour_error", "mm", "following error normal to the path (+: left of it)")

    def control(self, inputs: ControlInputs) -> list[float]:
        out = super().control(inputs)
        vx, vy = inputs.setpoint_velocity_mm_s[0], inputs.setpoint_velocity_mm_s[1]
        speed = math.hypot(vx, vy)
        if speed < self.min_speed_mm_s:
            self.contour_error = 0.0
            return out
        nx, ny = -vy / speed, vx / speed
        ec = inputs.error_mm[0] * nx + inputs.error_mm[1] * ny
        self.contour_error = ec
        k = self.contour_gain_1_s * ec
        out[0] += k * nx
        out[1] += k * ny
        return out
