"""The control program's CPU time per period, as the screen shows it live: p50, p99 and max over
the last second, from the servo's 1 us histogram (`control_timing` block), beside its budget.

The servo only counts (one histogram bin per period, `cnc.servo._record_control`); the gateway
keeps a snapshot of the histogram per status message and reads the difference across a second,
so the figures follow what the program does now, not since the controller started.
"""

from __future__ import annotations

import collections
import time

import numpy as np

from ..bus.messages import ControlLaw
from ..config import MachineConfig
from ..control.loader import build
from ..control.timing import histogram_figures
from ..data.dataserver import SharedArea

WINDOW_S = 1.0


class ControlTiming:
    """The `ControlLaw` part of the status."""

    def __init__(self, config: MachineConfig, area: SharedArea, clock=time.monotonic) -> None:  # noqa: ANN001
        self.program = f"{config.control.program} ({type(build(config)).__name__})"
        self.budget_us = config.control.budget_share * config.timing.period_s * 1e6
        self.hist = area.blocks["control_timing"].array[0]["hist"]
        self.clock = clock
        self.snapshots: collections.deque[tuple[float, np.ndarray]] = collections.deque()

    def law(self, servo: dict) -> ControlLaw:
        now, hist = self.clock(), self.hist.astype(np.int64)  # a copy: the servo counts on meanwhile
        self.snapshots.append((now, hist))
        while len(self.snapshots) > 1 and now - self.snapshots[1][0] >= WINDOW_S:
            self.snapshots.popleft()
        window = hist - self.snapshots[0][1] if len(self.snapshots) > 1 else hist
        p50, p99, peak = histogram_figures(window)
        return ControlLaw(self.program, p50, p99, peak, self.budget_us, int(servo["control_failures"]),
                          servo["control_failure"])

