"""A PI-P that misbehaves on request: the control-program supervision proved on the machine.

Its parameter `fault` (tuned online like any other) makes it fail the way a broken program
would: 1 raises an exception, 2 returns NaN commands, 3 uses more CPU time than its budget every
period, 4 never returns (only the hardware server's watchdog can stop that: a category 0 stop).
At 0 it is the PI-P. The fault-injection runs (`cnc.sim.faultinject`, `bench/faults.py`) select
it to show the servo's reaction; an integrator can do the same when commissioning a machine.
"""

from __future__ import annotations

import math
import time

from ..pip import PIP
from ..program import ControlInputs

NONE, RAISE, NAN, OVERRUN, HANG = range(5)


class Faulty(PIP):
    """The PI-P, or a chosen failure (`fault` 1 to 4)."""

    description = "PI-P that fails on request (fault = 1 raise, 2 NaN, 3 over budget, 4 never returns): fault injection"

    def __init__(self, machine) -> None:  # noqa: ANN001 - a MachineConfig
        super().__init__(machine)
        self.register_parameter("fault", 0.0, "", (0.0, 4.0),
                                "0 none; 1 raise, 2 return NaN, 3 overrun the budget, 4 never return")

    def control(self, inputs: ControlInputs) -> list[float]:
        mode = int(self.fault)
        if mode == RAISE:
            raise RuntimeError("fault injected (fault = 1)")
        if mode == NAN:
            return [math.nan] * self.n_axes
        if mode == OVERRUN:
            until = time.thread_time_ns() + int(2e9 * self.period_s)  # two periods of CPU
            while time.thread_time_ns() < until:
                pass
        if mode == HANG:
            while True:
                pass
        return super().control(inputs)
