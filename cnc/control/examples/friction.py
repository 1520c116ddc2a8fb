"""Friction feed-forward: the PI-P plus the speed command that Coulomb friction takes away.

The drive's P velocity loop leaves a speed deficit proportional to the friction it works
against: with a drive lag tau and a dry friction deceleration c, the axis runs tau * c slower
than commanded. The PI-P's integral makes up for it, but only after the error has built up,
and at every velocity reversal the friction changes sign and the integral has to swing the
other way: the following error peaks there (the "quadrant glitches" on a circle). This program
adds the deficit ahead of time, with the sign of the setpoint velocity, smoothed through zero:

    u = PI-P + friction_mm_s * tanh(v_ref / velocity_band_mm_s)

`friction_mm_s` is tau * c per axis (identify it from a slow ramp: the integral term's level).
"""

from __future__ import annotations

import math

from ..pip import PIP
from ..program import ControlInputs


class FrictionFeedForward(PIP):
    """PI-P with Coulomb-friction feed-forward on the setpoint velocity's sign."""

    description = "PI-P plus Coulomb friction feed-forward (lower following error at velocity reversals)"

    def __init__(self, machine) -> None:  # noqa: ANN001 - a MachineConfig
        super().__init__(machine)
        self.register_parameter("friction_mm_s", 0.15, "mm/s", (0.0, 1000.0),
                                "speed command the dry friction takes away (drive lag x friction deceleration)",
                                per_axis=True)
        self.register_parameter("velocity_band_mm_s", 0.5, "mm/s", (0.001, 100.0),
                                "setpoint speed over which the feed-forward changes sign (smoothly)")
        self.register_log_variable("friction_ff", "mm/s", "the friction feed-forward added to the command", per_axis=True)

    def control(self, inputs: ControlInputs) -> list[float]:
        out = super().control(inputs)
        band, ff = self.velocity_band_mm_s, self.friction_ff
        for i in range(len(out)):
            ff[i] = self.friction_mm_s[i] * math.tanh(inputs.setpoint_velocity_mm_s[i] / band)
            out[i] += ff[i]
        return out
