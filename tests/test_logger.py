"""The data logger on a real controller: each logging mode during a cut, parameter changes noted in
the run, the live stream, runs kept across a restarted logger, and export to MATLAB and CSV."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cnc.bus.messages import CycleStart, LogLive, LogRunData, LogSetting, LogStart, LogState, Reply, SetMode
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.bus.messages import decode, encode
from cnc.data.layout import PlannerState
from cnc.bus.logexport import columns, read_csv
from cnc.logic.states import MachineState

from .conftest import MACHINE_FILE, REPO, logic, press_button_when_asked, reset_and_home
from .test_zenoh_interface import PART


def ask(session, key: str, kind, payload=None):
    options = {"payload": encode(payload)} if payload is not None else {}
    replies = list(session.get(key, timeout=10.0, **options))
    assert replies and replies[0].ok is not None, replies[0].err.payload.to_string() if replies else f"no answer on {key}"
    return decode(replies[0].ok.payload.to_bytes(), kind)


@pytest.fixture
def station(plc_controller):
    session = open_client([plc_controller.config.zenoh.listen[0]])
    op = OperatorStation(session, plc_controller.keys, "engineer")
    yield session, op
    op.close()
    session.close()


def test_each_logging_mode_records_what_it_should_during_a_cut_and_notes_parameter_changes(plc_controller, station, tmp_path):
    sup, (session, op) = plc_controller, station
    keys, dt = sup.keys, sup.config.timing.period_s
    live: list[LogLive] = []
    sub = session.declare_subscriber(keys.log("live"), lambda s: live.append(decode(s.payload.to_bytes(), LogLive)))
    assert op.take_lock().ok
    reset_and_home(sup, op.request)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 60.0, "homing")
    assert op.upload("part.ngc", PART).ok and op.request(SetMode("AUTO")).ok

    state = ask(session, keys.log("state"), LogState)
    assert {"x.following_error", "y.speed_cmd", "fifo_fill", "tick_latency", "jet", "pump_pressure"} <= \
        {v.name for v in state.variables} and state.running == 0
    bad = ask(session, keys.log("start"), Reply, LogStart([LogSetting("x.wobble")]))
    assert not bad.ok and "no log variable 'x.wobble'" in bad.reason
    settings = [
        LogSetting("x.following_error", "timed", divisor=1, start_s=0.0, duration_s=0.5),
        LogSetting("y.position", "continuous", divisor=5, window_s=0.2),
        LogSetting("x.speed_cmd", "triggered", divisor=2, enable_when="jet"),
        LogSetting("jet", "triggered", divisor=2, enable_when="jet"),
    ]
    started = ask(session, keys.log("start"), Reply, LogStart(settings, "tuning X"))
    assert started.ok and "log run" in started.reason, started.reason
    run = int(started.reason.split()[2])
    assert not ask(session, keys.log("start"), Reply, LogStart(settings)).ok, "one run at a time"

    assert op.request(CycleStart(1)).ok
    press_button_when_asked(sup, lambda: sup.motion()["state"] == PlannerState.RUNNING, 60.0, "the cut")
    assert op.set_param("axis.x.kp_1_s", 140.0).ok
    press_button_when_asked(sup, lambda: logic(sup)["cycles_done"] == 1, 60.0, "the cycle's end")
    stopped = ask(session, keys.log("stop"), Reply)
    assert stopped.ok, stopped.reason
    sub.undeclare()

    data = ask(session, keys.log(f"runs/{run}"), LogRunData)
    cols = columns(data)
    t, fe = cols["x.following_error"]
    assert len(t) == 500 and t[0] == 0.0 and t[-1] == pytest.approx(0.499), "timed: 0.5 s at every tick"
    t, _ = cols["y.position"]
    assert len(t) == 40 and np.allclose(np.diff(t), 5 * dt), "continuous: the last 0.2 s at every 5th tick"
    t_jet, jet = cols["jet"]
    t_cmd, _ = cols["x.speed_cmd"]
    assert len(jet) > 50 and set(jet) == {1.0}, "triggered: only while the jet is on"
    assert np.array_equal(t_jet, t_cmd) and np.allclose(np.round(t_jet / dt) % 2, 0)
    assert data.params_start["axis.x.kp_1_s"] == sup.config.axis["x"].kp_1_s and data.params_end["axis.x.kp_1_s"] == 140.0
    [(t_change, name, value)] = data.param_changes
    assert name == "axis.x.kp_1_s" and value == 140.0 and t_jet[0] - 1.0 < t_change
    assert data.title == "tuning X" and data.units["x.following_error"] == "mm"
    assert live and all(m.latest for m in live) and any("jet" in m.samples for m in live), "watch values and live samples"
    assert sum(len(m.samples["jet"].v) for m in live if "jet" in m.samples) == len(jet), "live saw every sample"

    # export, by the command line, to MATLAB and CSV: both read back exactly
    env = {**os.environ}
    for fmt in ("mat", "csv"):
        out = tmp_path / f"run.{fmt}"
        res = subprocess.run([sys.executable, "-m", "cnc.cli", "log", "--machine", str(MACHINE_FILE), "--connect",
                              sup.config.zenoh.listen[0], "export", str(run), "--out", str(out)],
                             cwd=REPO, capture_output=True, text=True, timeout=60, env=env)
        assert res.returncode == 0, res.stderr
        assert f"run {run}: 4 variables" in res.stdout
    from scipy.io import loadmat

    mat = loadmat(tmp_path / "run.mat", simplify_cells=True)
    for name, (t, v) in cols.items():
        key = name.replace(".", "_")
        assert np.array_equal(np.atleast_1d(mat["log"][key]["t"]), t) and np.array_equal(np.atleast_1d(mat["log"][key]["v"]), v)
    assert mat["params_end"]["axis_x_kp_1_s"] == 140.0 and mat["params_start"]["axis_y_ki_1_s2"] == sup.config.axis["y"].ki_1_s2
    assert mat["param_changes"]["name"] == "axis.x.kp_1_s" and mat["settings"]["jet"]["mode"] == "triggered"
    back = read_csv(tmp_path / "run.csv")
    for name, (t, v) in cols.items():
        assert np.array_equal(back[name][0], t) and np.array_equal(back[name][1], v)
    params_csv = (tmp_path / "run_params.csv").read_text()
    assert "axis.x.kp_1_s,100.0,140.0," in params_csv


def test_a_timed_run_ends_by_itself_and_the_runs_outlive_a_killed_logger(plc_controller, station):
    sup, (session, _) = plc_controller, station
    keys = sup.keys
    started = ask(session, keys.log("start"), Reply, LogStart([LogSetting("fifo_fill", "timed", divisor=10, duration_s=0.3),
                                                               LogSetting("tick_latency", "timed", duration_s=0.1)]))
    run = int(started.reason.split()[2])
    sup.wait_until(lambda: ask(session, keys.log("state"), LogState).running == 0, 30.0, "the run to end by itself")
    before = ask(session, keys.log(f"runs/{run}"), LogRunData)
    assert {n: len(c.v) // 8 for n, c in before.columns.items()} == {"fifo_fill": 30, "tick_latency": 100}
    kept = Path(sup.history_path).parent / "runs" / f"run-{run}.json"
    sup.wait_until(kept.exists, 10.0, "the run on disk")  # written by the logger's writer thread
    old = sup.children["logger"].process.pid
    os.kill(old, signal.SIGKILL)
    sup.wait_until(lambda: "logger" in sup.children and sup.children["logger"].process.pid != old, 30.0, "a new logger")
    after = ask(session, keys.log(f"runs/{run}"), LogRunData)
    assert after == before, "kept on disk, read back by the new logger"
    again = ask(session, keys.log("start"), Reply, LogStart([LogSetting("fifo_fill", duration_s=0.01)]))
    assert again.ok and int(again.reason.split()[2]) == run + 1, "numbering goes on"


def test_importing_the_plot_module_does_not_import_matplotlib():
    """The logger and `waterjet log` import the run plots; matplotlib only when a plot is drawn
    (a fresh interpreter: this one has it already)."""
    code = "import sys, cnc.logger.plots; sys.exit('matplotlib' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], cwd=REPO, timeout=120).returncode == 0
