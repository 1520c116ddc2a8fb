"""What the tuning and logging windows show, in pure Python: the control parameters, the logger's
variables and runs, the latest value of every variable (watch) and the live samples of the run
under way (scope), fed by the Zenoh connection."""

from __future__ import annotations

import numpy as np

from cnc.bus.messages import LogLive, LogRunSummary, LogState, LogVariable, ParamInfo, ParamList

from .observable import Observable

TUNING_TOPICS = ("params", "logstate", "live")
LIVE_KEPT = 200_000  # samples per variable kept for the live plots (the oldest go first)


class TuningModel(Observable):
    """Updated by `apply_*` from bus messages; observers as in `Observable` (topics TUNING_TOPICS)."""

    def __init__(self) -> None:
        super().__init__(TUNING_TOPICS)
        self._params: list[ParamInfo] = []
        self._change = -1
        self._log: LogState | None = None
        self._latest: dict[str, float] = {}
        self._live_run = 0
        self._live: dict[str, tuple[list[np.ndarray], list[np.ndarray], int]] = {}

    # -- applying ---------------------------------------------------------------------------

    def apply_params(self, params: ParamList) -> None:
        with self._lock:
            changed = params.params != self._params or params.seq != self._change
            self._params, self._change = list(params.params), params.seq
        if changed:
            self._notify(["params"])

    def apply_log_state(self, state: LogState) -> None:
        with self._lock:
            changed = state != self._log
            self._log = state
        if changed:
            self._notify(["logstate"])

    def apply_live(self, live: LogLive) -> None:
        """The latest values; the run's new samples appended (a new run starts the buffers afresh)."""
        with self._lock:
            self._latest = dict(live.latest)
            if live.run != self._live_run:
                self._live_run, self._live = live.run, {}
            for name, s in live.samples.items():
                ts, vs, n = self._live.get(name, ([], [], 0))
                ts.append(np.asarray(s.t, float))
                vs.append(np.asarray(s.v, float))
                n += len(s.t)
                if n > 2 * LIVE_KEPT:  # compact once in a while, keeping the newest
                    t, v = np.concatenate(ts)[-LIVE_KEPT:], np.concatenate(vs)[-LIVE_KEPT:]
                    ts, vs, n = [t], [v], len(t)
                self._live[name] = (ts, vs, n)
        self._notify(["live"])

    # -- reading ----------------------------------------------------------------------------

    @property
    def params(self) -> list[ParamInfo]:
        with self._lock:
            return list(self._params)

    @property
    def variables(self) -> list[LogVariable]:
        with self._lock:
            return list(self._log.variables) if self._log is not None else []

    @property
    def runs(self) -> list[LogRunSummary]:
        with self._lock:
            return list(self._log.runs) if self._log is not None else []

    @property
    def running(self) -> int:
        """The log run under way (0 none)."""
        with self._lock:
            return self._log.running if self._log is not None else 0

    @property
    def period_s(self) -> float:
        with self._lock:
            return self._log.period_s if self._log is not None else 0.001

    @property
    def latest(self) -> dict[str, float]:
        with self._lock:
            return dict(self._latest)

    @property
    def live_run(self) -> int:
        with self._lock:
            return self._live_run

    def live_series(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(t, v) of the live samples of `name` in the run under way (the newest LIVE_KEPT)."""
        with self._lock:
            entry = self._live.get(name)
            if entry is None:
                return np.zeros(0), np.zeros(0)
            ts, vs, _ = entry
            t, v = np.concatenate(ts), np.concatenate(vs)
            self._live[name] = ([t], [v], len(t))
        return t[-LIVE_KEPT:], v[-LIVE_KEPT:]
