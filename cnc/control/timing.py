"""The control program's CPU time per period from the servo's 1 us histogram (`control_timing`
block): QMotor 2.0's control benchmark, as the screen shows it live and each log run records it."""

from __future__ import annotations

import numpy as np


def histogram_figures(hist: np.ndarray) -> tuple[float, float, float]:
    """p50, p99 and max in us of a 1 us histogram (each a bin's upper edge); -1 when it is empty."""
    total = int(hist.sum())
    if total <= 0:
        return -1.0, -1.0, -1.0
    cum = np.cumsum(hist)
    p50 = int(np.searchsorted(cum, 0.5 * total)) + 1
    p99 = int(np.searchsorted(cum, 0.99 * total)) + 1
    peak = int(np.flatnonzero(hist)[-1]) + 1
    return float(p50), float(p99), float(peak)
