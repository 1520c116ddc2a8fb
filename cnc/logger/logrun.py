"""One log run: QMotor's logging modes applied to the ticks the logger feeds it, in numpy.

A run starts at a base tick `tick0`; its time is `(tick - tick0) * period`. Each variable is
sampled at every `divisor`-th tick of the run and kept according to its mode:

- timed: the samples from `start_s` for `duration_s`;
- continuous: the last `window_s` seconds, in a ring that is kept when the run ends;
- triggered: while enabled; `enable_when` switches it on, `disable_when` off (without one, it is
  on exactly while `enable_when` holds). Conditions are the control logic's condition language
  over the log variables (`x.following_error > 0.02 and jet`), evaluated at each sample.

The run ends by itself once every variable is timed and complete. A variable stops recording at
`max_samples` and is reported truncated. Nothing here waits or touches shared memory: the
logger process feeds it columns, and tests feed it arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..bus.messages import LogSetting
from ..logic.conditions import Condition, ConditionError, compile_condition

MODES = ("timed", "continuous", "triggered")


class LogSettingError(ValueError):
    """A log setting that cannot be recorded; the text names the variable and the field."""


@dataclass
class _Recorder:
    setting: LogSetting
    capacity: int  # the continuous ring's size, or the sample limit
    enable: Condition | None = None
    disable: Condition | None = None
    ticks: list[np.ndarray] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)
    count: int = 0
    enabled: bool = False
    truncated: bool = False
    ring_ticks: np.ndarray | None = None
    ring_values: np.ndarray | None = None


class LogRun:
    """The samples of one run, per variable (see the module docstring)."""

    def __init__(self, settings: list[LogSetting], known: list[str], period_s: float, tick0: int,
                 max_samples: int = 2_000_000) -> None:
        """LogSettingError for an unknown variable, a bad mode, divisor, time or condition."""
        if not settings:
            raise LogSettingError("a log run needs at least one variable")
        self.period_s, self.tick0, self.max_samples = period_s, tick0, max_samples
        self.settings = list(settings)
        self.recorders: dict[str, _Recorder] = {}
        for k, s in enumerate(settings, start=1):
            where = f"variable {k} ({s.name})"
            if s.name not in known:
                raise LogSettingError(f"{where}: no log variable {s.name!r} (known: {', '.join(known)})")
            if s.name in self.recorders:
                raise LogSettingError(f"{where}: logged twice")
            self.recorders[s.name] = self._recorder(s, known, where)
        self.last_tick = tick0 - 1

    def _recorder(self, s: LogSetting, known: list[str], where: str) -> _Recorder:
        if s.mode not in MODES:
            raise LogSettingError(f"{where}: mode {s.mode!r} is not one of: {', '.join(MODES)}")
        if not isinstance(s.divisor, int) or not 1 <= s.divisor <= 1_000_000:
            raise LogSettingError(f"{where}: divisor {s.divisor!r} must be a whole number of base ticks, 1 or more")
        for name in ("start_s", "duration_s", "window_s"):
            value = getattr(s, name)
            if not math.isfinite(value) or value < 0:
                raise LogSettingError(f"{where}: {name} {value!r} must be 0 or more seconds")
        step = s.divisor * self.period_s
        if s.mode == "continuous":
            if s.window_s <= 0:
                raise LogSettingError(f"{where}: a continuous variable needs window_s > 0")
            size = min(self.max_samples, max(1, math.ceil(s.window_s / step)))
            return _Recorder(s, size, ring_ticks=np.zeros(size, np.int64), ring_values=np.zeros(size))
        if s.mode == "timed" and s.duration_s <= 0:
            raise LogSettingError(f"{where}: a timed variable needs duration_s > 0")
        rec = _Recorder(s, self.max_samples)
        if s.mode == "triggered":
            if not s.enable_when.strip():
                raise LogSettingError(f"{where}: a triggered variable needs enable_when")
            try:
                rec.enable = compile_condition(s.enable_when, known, f"{where} enable_when")
                rec.disable = compile_condition(s.disable_when, known, f"{where} disable_when") if s.disable_when.strip() else None
            except ConditionError as exc:
                raise LogSettingError(str(exc)) from None
        return rec

    # -- feeding ------------------------------------------------------------------------------

    @property
    def conditions_need(self) -> set[str]:
        """The variables the triggered conditions read (the logger must compute them)."""
        return {n for r in self.recorders.values() for c in (r.enable, r.disable) if c is not None for n in c.names}

    def feed(self, ticks: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        """Consecutive base ticks (ascending) and every variable's value at each of them."""
        keep = ticks > self.last_tick  # a tick fed twice (a restarted logger) counts once
        if not keep.all():
            ticks, columns = ticks[keep], {k: v[keep] for k, v in columns.items()}
        if not len(ticks):
            return
        self.last_tick = int(ticks[-1])
        rel = ticks - self.tick0
        for name, rec in self.recorders.items():
            s = rec.setting
            due = (rel >= 0) & (rel % s.divisor == 0)
            if s.mode == "timed":
                t = rel * self.period_s
                due &= (t >= s.start_s - 1e-12) & (t < s.start_s + s.duration_s - 1e-12)
                self._append(rec, ticks[due], columns[name][due])
            elif s.mode == "continuous":
                self._ring(rec, ticks[due], columns[name][due])
            else:
                self._triggered(rec, ticks, due, columns)

    def _append(self, rec: _Recorder, ticks: np.ndarray, values: np.ndarray) -> None:
        room = rec.capacity - rec.count
        if len(ticks) > room:
            ticks, values, rec.truncated = ticks[:room], values[:room], True
        if len(ticks):
            rec.ticks.append(ticks.astype(np.int64))
            rec.values.append(values.astype(np.float64))
            rec.count += len(ticks)

    def _ring(self, rec: _Recorder, ticks: np.ndarray, values: np.ndarray) -> None:
        size = rec.capacity
        if len(ticks) > size:
            ticks, values = ticks[-size:], values[-size:]
        at = (rec.count + np.arange(len(ticks))) % size
        rec.ring_ticks[at], rec.ring_values[at] = ticks, values
        rec.count += len(ticks)

    def _triggered(self, rec: _Recorder, ticks: np.ndarray, due: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        names = rec.enable.names | (rec.disable.names if rec.disable is not None else frozenset())
        keep = np.zeros(len(ticks), dtype=bool)
        for k in np.flatnonzero(due):
            signals = {n: float(columns[n][k]) for n in names}
            if rec.disable is None:
                rec.enabled = rec.enable.evaluate(signals)
            elif rec.enabled and rec.disable.evaluate(signals):
                rec.enabled = False
            elif not rec.enabled and rec.enable.evaluate(signals):
                rec.enabled = True
            keep[k] = rec.enabled
        self._append(rec, ticks[keep], columns[rec.setting.name][keep])

    # -- reading ------------------------------------------------------------------------------

    @property
    def complete(self) -> bool:
        """Every variable is timed and past its window: the run can end by itself."""
        end = (self.last_tick - self.tick0 + 1) * self.period_s
        return all(r.setting.mode == "timed" and (r.truncated or end >= r.setting.start_s + r.setting.duration_s - 1e-9)
                   for r in self.recorders.values())

    def samples(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(seconds since the run's start, values) of one variable, oldest first."""
        rec = self.recorders[name]
        if rec.setting.mode == "continuous":
            n, size = min(rec.count, rec.capacity), rec.capacity
            order = (rec.count - n + np.arange(n)) % size
            ticks, values = rec.ring_ticks[order], rec.ring_values[order]
        elif rec.ticks:
            ticks, values = np.concatenate(rec.ticks), np.concatenate(rec.values)
            rec.ticks, rec.values = [ticks], [values]
        else:
            ticks, values = np.zeros(0, np.int64), np.zeros(0)
        return (ticks - self.tick0) * self.period_s, values.copy()

    def since(self, name: str, seen: int) -> tuple[np.ndarray, np.ndarray, int]:
        """The samples of `name` taken after the first `seen` ones: (t, values, total taken so far).
        A continuous ring only still holds its last window."""
        rec = self.recorders[name]
        total = rec.count
        new = total - seen
        if new <= 0:
            return np.zeros(0), np.zeros(0), total
        t, v = self.samples(name)
        return t[-min(new, len(t)):], v[-min(new, len(v)):], total

    def count(self, name: str) -> int:
        rec = self.recorders[name]
        return min(rec.count, rec.capacity) if rec.setting.mode == "continuous" else rec.count

    @property
    def truncated(self) -> list[str]:
        return [n for n, r in self.recorders.items() if r.truncated]
