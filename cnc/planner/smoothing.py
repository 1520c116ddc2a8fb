"""Moving average over a stream of samples: the planner's jerk limiter and geometric smoother.

The mean of the last n inputs, fed in batches of any size, with the n - 1 previous inputs
kept between batches, so a stream cut anywhere gives the same output as one long batch. A
trajectory starting from rest starts with its history full of the start value, so the first
outputs are exact. Sums are taken relative to the first value of each batch (cumulative sums
of small numbers), so 1000 mm positions do not lose the nanometres that third differences,
the jerk, are made of.
"""

from __future__ import annotations

import numpy as np


class MovingAverage:
    """Streaming mean of the last `n` inputs (scalars or vectors)."""

    def __init__(self, n: int, initial: np.ndarray | float) -> None:
        if n < 1:
            raise ValueError(f"a moving average needs at least 1 sample, got {n}")
        self.n = n
        first = np.atleast_1d(np.asarray(initial, dtype=float))
        self.history = np.repeat(first[None, :], n - 1, axis=0)

    def push(self, x: np.ndarray) -> np.ndarray:
        """Outputs for these inputs (same shape as `x`: (m,) or (m, d))."""
        scalar = x.ndim == 1
        block = x[:, None] if scalar else x
        if self.n == 1:
            return x.copy()
        ext = np.concatenate((self.history, block))
        origin = ext[0]
        c = np.concatenate((np.zeros((1, ext.shape[1])), np.cumsum(ext - origin, axis=0)))
        out = (c[self.n:] - c[:-self.n]) / self.n + origin
        self.history = ext[len(ext) - (self.n - 1):]
        return out[:, 0] if scalar else out

    def converged(self, value: np.ndarray | float, tol: float = 0.0) -> bool:
        """Is every remembered input within `tol` of `value` (so the output equals it from now on)?"""
        return bool(np.all(np.abs(self.history - np.atleast_1d(value)) <= tol))

    def snapshot(self) -> np.ndarray:
        return self.history.copy()

    def restore(self, history: np.ndarray) -> None:
        self.history = history.copy()
