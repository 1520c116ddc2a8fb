"""The data logger process (QMotor's log variables, watch and plots over Zenoh).

A timer client of the hardware server every `[logger] wake_divisor` ticks. At each wake it drains
the servo's trace ring (the servo writes one record per tick and never waits: a full ring drops
and counts), computes the log variables for those ticks (`logvars`), keeps the latest values for
the watch window and, while a run records, feeds them to the run (`logrun`). About ten times a
second it publishes `log/live`: the latest values and the samples taken since the last message.

Runs are started and stopped over Zenoh (`log/start` with the variables' settings, `log/stop`);
a run whose variables are all timed ends by itself. A finished run keeps its samples, its
settings and the control parameters in force at its start, at its end and every change between,
in memory and as a JSON file beside the alarm history (`runs/run-<n>.json`), so that plots and
exports (`log/runs/<n>`, `waterjet log export`) outlive the logger and the controller. Logging
never moves the machine, so it needs no command lock.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import OrderedDict
from pathlib import Path

import msgspec
import numpy as np
import zenoh

from ..bus.keys import Keys
from ..bus.messages import (
    LogColumn, LogLive, LogRunData, LogRunSummary, LogSamples, LogStart, LogState, LogStop, Reply, decode, encode,
)
from ..bus.service import CommandRefused, CommandService, Request, Route, report_to_logic
from ..config import MachineConfig
from ..control.loader import build as build_program
from ..control.timing import histogram_figures
from ..data.dataserver import SharedArea
from ..data.injection import injected_bugs
from ..data.layout import Proc
from .logrun import LogRun, LogSettingError
from .logvars import BlockSampler, log_variables, trace_columns
from ..params import registry
from ..data.trace import TraceRing

log = logging.getLogger(__name__)

WRITE_PIECE_BYTES = 1 << 20  # a finished run goes to disk in pieces of this size ...
WRITE_PAUSE_S = 0.002  # ... with this pause between them


class Logger:
    """The logger's state and work; `run()` is its loop."""

    def __init__(self, config: MachineConfig, area: SharedArea, trace: TraceRing, session: zenoh.Session, timer,
                 runs_dir: str | os.PathLike) -> None:
        self.config, self.trace, self.timer = config, trace, timer
        self.cfg = config.logger
        self.period_s = config.timing.period_s
        self.variables = log_variables(config)
        self.sampler = BlockSampler(config, area)
        self.params_r = area.reader("params")
        # the control benchmark of each run: the servo's histogram of the program's CPU time, at its start and end
        self.control_hist = area.blocks["control_timing"].array[0]["hist"]
        self.control_program = f"{config.control.program} ({type(build_program(config)).__name__})"
        self.param_names = [p.name for p in registry(config)]
        self.keys = Keys(config.zenoh.key_prefix, config.machine.name)
        self.shutdown = area.blocks["supervisor"].array["shutdown"]
        hb = area.blocks["heartbeat"].array[0]
        self.beat = hb["beat"]
        hb["pid"][Proc.LOGGER] = os.getpid()
        self.service = CommandService(session, self.keys, "logger", report_to_logic(session, self.keys, "logger"),
                                      inject=injected_bugs(area, config))
        self.service.serve(
            Route("state", self.keys.log("state"), lambda _request: self.state(), read=True, what=lambda _key: "log state"),
            Route("start", self.keys.log("start"), lambda request: self.start_run(request.message), LogStart,
                  what=lambda _key: "log start"),
            Route("stop", self.keys.log("stop"), lambda _request: self.stop_run("stopped on request"), LogStop,
                  what=lambda _key: "log stop", bare=True),
            Route("runs", self.keys.log("runs/**"), self._run_data, read=True, what=lambda key: key),
        )
        self.live_pub = session.declare_publisher(self.keys.log("live"), encoding=zenoh.Encoding.APPLICATION_JSON,
                                                  congestion_control=zenoh.CongestionControl.DROP)
        self.token = session.liveliness().declare_token(self.keys.alive("logger"))
        self.runs_dir = Path(runs_dir)
        self.runs: OrderedDict[int, LogRunData] = OrderedDict()
        self._writer: threading.Thread | None = None
        self._load_runs()
        self.next_run = max(self.runs, default=0) + 1
        self.run_obj: LogRun | None = None
        self.run_info: dict = {}
        self.seen: dict[str, int] = {}  # samples of each variable already sent live
        self.last_record: np.ndarray | None = None  # the newest trace record drained
        self.last_tick = 0
        self.live_seq = 0
        self.next_live = 0.0

    # -- the loop -----------------------------------------------------------------------------

    def run(self) -> None:
        my_bit = 1 << Proc.LOGGER
        while not self.shutdown[0] & my_bit:
            woke = self.timer.wait_tick(0.02)
            if woke:
                while self.timer.wake.acquire(False):
                    pass
                try:
                    self.on_wake()
                finally:
                    self.timer.tick_done()
            self.handle_queries()
            now = time.monotonic()
            if now >= self.next_live:
                self.next_live = now + 1.0 / self.cfg.live_rate_hz
                self.publish_live()
            self.beat[Proc.LOGGER] += 1

    def on_wake(self) -> None:
        """Drain the trace; the ticks into the run under way. Without a run only the newest record
        is kept (for the watch values, computed when the live message goes out)."""
        records = self.trace.drain()
        if not len(records):
            return
        self.last_record = records[-1:]
        self.last_tick = int(records["tick"][-1])
        run = self.run_obj
        if run is None:
            return
        ticks = records["tick"].astype(np.int64)
        columns = trace_columns(records, self.config)
        for name, value in self.sampler.sample().items():
            columns[name] = np.full(len(ticks), value)
        self._note_param_changes(ticks[-1])
        run.feed(ticks, columns)
        if run.complete:
            self.stop_run("every timed variable is complete")

    def _latest(self) -> dict[str, float]:
        """The watch values: every variable at the newest tick drained."""
        if self.last_record is None:
            return {}
        values = {name: float(col[-1]) for name, col in trace_columns(self.last_record, self.config).items()}
        values.update(self.sampler.sample())
        return values

    def close(self) -> None:
        if self.run_obj is not None:
            self.stop_run("the logger stopped")
        if self._writer is not None:
            self._writer.join()
        self.service.close()
        self.live_pub.undeclare()
        self.token.undeclare()

    # -- queries ------------------------------------------------------------------------------

    def handle_queries(self) -> None:
        self.service.poll()

    def _run_data(self, request: Request) -> LogRunData:
        tail = request.key.rsplit("/", 1)[-1]
        if not tail.isdigit() or int(tail) not in self.runs:
            raise CommandRefused("no such log run")
        return self.runs[int(tail)]

    def state(self) -> LogState:
        summaries = [self._summary(data) for data in self.runs.values()]
        if self.run_obj is not None:
            summaries.append(self._running_summary())
        return LogState(self.variables.all, self.period_s, self.run_info.get("run", 0) if self.run_obj else 0, summaries)

    # -- runs ---------------------------------------------------------------------------------

    def start_run(self, msg: LogStart) -> Reply:
        if self.run_obj is not None:
            return Reply(False, f"log run {self.run_info['run']} is recording: stop it first")
        tick0 = self.last_tick + 1
        try:
            run = LogRun(msg.variables, self.variables.names, self.period_s, tick0, self.cfg.max_samples)
        except LogSettingError as exc:
            raise CommandRefused(str(exc)) from None
        params = self._params()
        self.run_obj, self.seen = run, {s.name: 0 for s in msg.variables}
        self.run_info = {"run": self.next_run, "title": msg.title, "started_ns": time.time_ns(), "tick0": tick0,
                         "params_start": params, "params_now": dict(params), "changes": [],
                         "change_seq": self.params_r.read_dict()["change"],
                         "control_hist": self.control_hist.astype(np.int64)}
        self.next_run += 1
        names = ", ".join(f"{s.name} ({s.mode})" for s in msg.variables)
        log.info("logger: run %d started at tick %d: %s", self.run_info["run"], tick0, names)
        return Reply(True, f"log run {self.run_info['run']} started at tick {tick0}: {names}")

    def stop_run(self, why: str) -> Reply:
        run = self.run_obj
        if run is None:
            return Reply(False, "no log run is recording")
        info = self.run_info
        began = time.perf_counter()
        columns, units = {}, self.variables.units
        for s in run.settings:
            t, v = run.samples(s.name)
            columns[s.name] = LogColumn(t.astype("<f8").tobytes(), v.astype("<f8").tobytes())
        data = LogRunData(
            info["run"], info["title"], info["started_ns"], time.time_ns(), self.period_s, run.settings, columns,
            {s.name: units[s.name] for s in run.settings}, info["params_start"], self._params(), info["changes"],
            run.truncated, self.control_program,
            list(histogram_figures(self.control_hist.astype(np.int64) - info["control_hist"])),
        )
        self.run_obj = None
        self._keep(data)
        samples = sum(run.count(s.name) for s in run.settings)
        log.info("logger: run %d ended (%s): %d samples, kept in %.0f ms", data.run, why, samples,
                 1000 * (time.perf_counter() - began))
        return Reply(True, f"log run {data.run} ended ({why}): {samples} samples")

    def _keep(self, data: LogRunData) -> None:
        """Keep the run in memory at once, and on disk from a writer thread, in pieces: a run of
        hundreds of thousands of samples is megabytes, and one burst of page-cache copies can hold
        up a core that the servo shares on a small machine."""
        self.runs[data.run] = data
        while len(self.runs) > self.cfg.runs_kept:
            old, _ = self.runs.popitem(last=False)
            (self.runs_dir / f"run-{old}.json").unlink(missing_ok=True)
        if self._writer is not None:
            self._writer.join()
        self._writer = threading.Thread(target=self._write, args=(data,), name="logger-keep", daemon=False)
        self._writer.start()

    def _write(self, data: LogRunData) -> None:
        try:
            self.runs_dir.mkdir(parents=True, exist_ok=True)
            tmp = self.runs_dir / f".run-{data.run}.json.part"
            payload = memoryview(encode(data))
            with tmp.open("wb") as f:
                for at in range(0, len(payload), WRITE_PIECE_BYTES):
                    f.write(payload[at:at + WRITE_PIECE_BYTES])
                    time.sleep(WRITE_PAUSE_S)
            os.replace(tmp, self.runs_dir / f"run-{data.run}.json")
        except OSError as exc:  # the run stays in memory; the engineer learns it is not on disk
            log.error("logger: cannot keep run %d in %s: %s", data.run, self.runs_dir, exc)

    def _load_runs(self) -> None:
        """The runs a previous logger kept (newest `runs_kept`)."""
        files = sorted(self.runs_dir.glob("run-*.json"), key=lambda p: int(p.stem.split("-")[1]))
        for path in files[-self.cfg.runs_kept:]:
            try:
                data = decode(path.read_bytes(), LogRunData)
            except (OSError, ValueError, msgspec.ValidationError, msgspec.DecodeError) as exc:
                log.warning("logger: %s cannot be read, skipped: %s", path, exc)
                continue
            self.runs[data.run] = data

    def _params(self) -> dict[str, float]:
        values = self.params_r.read_dict()["values"]
        return {name: float(values[k]) for k, name in enumerate(self.param_names)}

    def _note_param_changes(self, tick: int) -> None:
        info = self.run_info
        change = self.params_r.read_dict()["change"]
        if change == info["change_seq"]:
            return
        info["change_seq"] = change
        now = self._params()
        t = float((int(tick) - info["tick0"]) * self.period_s)
        for name, value in now.items():
            if value != info["params_now"][name]:
                info["changes"].append((t, name, value))
        info["params_now"] = now

    def _summary(self, data: LogRunData) -> LogRunSummary:
        samples = sum(len(c.v) // 8 for c in data.columns.values())
        ends = [np.frombuffer(c.t, "<f8")[-1] for c in data.columns.values() if len(c.t)]
        return LogRunSummary(data.run, data.title, data.started_ns, data.ended_ns, float(max(ends, default=0.0)),
                             list(data.columns), samples, "done")

    def _running_summary(self) -> LogRunSummary:
        run, info = self.run_obj, self.run_info
        return LogRunSummary(info["run"], info["title"], info["started_ns"], 0,
                             max(0.0, (self.last_tick - info["tick0"] + 1) * self.period_s),
                             [s.name for s in run.settings], sum(run.count(s.name) for s in run.settings), "running")

    # -- live ---------------------------------------------------------------------------------

    def publish_live(self) -> None:
        """The watch values, and the run's samples since the last message (thinned to `live_points`).
        Nothing goes out before the first trace record: an empty message would blank the screen's
        watch values instead of saying anything."""
        if self.last_record is None:
            return
        samples = {}
        run = self.run_obj
        if run is not None:
            for name, seen in self.seen.items():
                t, v, total = run.since(name, seen)
                self.seen[name] = total
                if len(t) > self.cfg.live_points:
                    keep = np.linspace(0, len(t) - 1, self.cfg.live_points).round().astype(int)
                    t, v = t[keep], v[keep]
                if len(t):
                    samples[name] = LogSamples(t.tolist(), v.tolist())
        self.live_seq += 1
        run_id = self.run_info.get("run", 0) if run is not None else 0
        self.live_pub.put(encode(LogLive(self.live_seq, self.last_tick, self._latest(), run_id, samples)))
