"""The servo engineer at the operator screen against a real controller (pytest-qt, offscreen): tune
the X gain online while the following error is logged, watched and plotted, save the gains into the
machine file, and export the run to MATLAB. Screenshots go where test_hmi_window's go."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from PySide6.QtCore import Qt

from cnc.bus.messages import ControlRun, ControlSelect, GoTo, Reply, SetMode
from cnc.config import load_machine
from cnc.data.layout import PlannerState
from cnc.logic.states import MachineState
from hmi.model import Screen

from .conftest import MACHINE_FILE, MID_TRAVEL, NEAR_HOME, free_port, full_controller, logic
from .test_hmi_window import WAIT_MS, click, home_from_the_screen, open_screen, shot, take_lock

pytest.importorskip("pytestqt")

# The continuous logs below keep their last LOG_WINDOW_S: longer than all the waits between a log's
# start and its stop could take (each up to WAIT_MS), so that what a test asserts of a run (the moves,
# the circle) is in it however slowly a busy host runs the steps after it. With 5 s, a busy host's
# wait for the jog's end, a screenshot and the stop once took longer than that, and the ring held
# only the head at rest (a following error of 0).
LOG_WINDOW_S = 600.0


@pytest.fixture
def machine_copy(tmp_path):
    """The shipped machine file copied, so that saving the parameters writes the copy."""
    machine = tmp_path / "machine.toml"
    shutil.copy(MACHINE_FILE, machine)
    return machine


def exported_mat(qtbot, screen, log, run: int, path) -> dict:  # noqa: ANN001
    """Export log run `run` from the log panel to a .mat file, and read it back."""
    from scipy.io import loadmat

    with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS) as exported:
        log.export(run, path, "mat")
    assert exported.args[1].ok, exported.args[1].reason
    return loadmat(path, simplify_cells=True)


def test_an_engineer_tunes_x_while_watching_the_following_error_and_exports_the_run_to_matlab(qtbot, machine_copy, tmp_path):
    config = load_machine(machine_copy, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **MID_TRAVEL, **NEAR_HOME})
    with full_controller(config, tmp_path / "history.sqlite"):
        screen = open_screen(qtbot, config)
        w, tuning = screen.window, screen.tuning
        try:
            qtbot.waitUntil(lambda: screen.model.reachable and bool(tuning.params) and bool(tuning.variables), timeout=WAIT_MS)
            take_lock(qtbot, screen)
            click(qtbot, screen, w.bar.reset)
            qtbot.waitUntil(lambda: w.current_screen is Screen.MANUAL and screen.model.status.axes[0].drive_enabled,
                            timeout=WAIT_MS)
            qtbot.mouseClick(w.bar.tuning, Qt.MouseButton.LeftButton)
            eng = w.engineering
            qtbot.waitExposed(eng)
            params, log, watch, scope = eng.params, eng.log, eng.watch, eng.scope
            qtbot.waitUntil(lambda: params.table.rowCount() == len(tuning.params) == 20, timeout=WAIT_MS)

            log.choose("x.following_error", "continuous", window_s=LOG_WINDOW_S)
            log.choose("x.speed_cmd", "continuous", divisor=2, window_s=LOG_WINDOW_S)
            log.title.setText("X gain")
            click(qtbot, screen, log.start)
            qtbot.waitUntil(lambda: tuning.running > 0 and log.stop.isEnabled(), timeout=WAIT_MS)
            run = tuning.running
            window = scope.add_window(["x.following_error"])
            watch.watch(["x.following_error", "x.position", "fifo_fill"])

            manual = w.pages[Screen.MANUAL]
            manual.jog.step.setCurrentIndex(manual.jog.step.findData(100.0))
            click(qtbot, screen, manual.jog.buttons[("x", 1)])
            qtbot.waitUntil(lambda: window.point_counts().get("x.following_error", 0) > 200, timeout=WAIT_MS)
            assert watch.values()["x.position"] != "-" and set(watch.values()) == {"x.following_error", "x.position",
                                                                                    "fifo_fill"}
            shot(eng, "11_tuning_scope_live")

            with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS) as out:
                params.set_value("axis.x.kp_1_s", "20000")
            assert not out.args[1].ok and "out of range" in params.note.text()
            with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS) as done:
                params.set_value("axis.x.kp_1_s", "150")
            assert done.args[1].ok and "applied by the servo at tick" in params.note.text(), params.note.text()
            qtbot.waitUntil(lambda: params.value_of("axis.x.kp_1_s") == "150", timeout=WAIT_MS)
            qtbot.waitUntil(lambda: screen.model.status.planner_state == "IDLE"
                            and screen.model.status.machine_state != "JOGGING", timeout=WAIT_MS)
            click(qtbot, screen, manual.jog.buttons[("x", -1)])  # the same move back with the new gain
            qtbot.waitUntil(lambda: screen.model.status.planner_state == "IDLE"
                            and abs(screen.model.status.axes[0].velocity_mm_s) < 1e-3, timeout=WAIT_MS)
            shot(eng, "12_tuning_parameters")

            click(qtbot, screen, log.stop)
            qtbot.waitUntil(lambda: tuning.running == 0 and any(r.run == run and r.state == "done" for r in tuning.runs),
                            timeout=WAIT_MS)
            qtbot.waitUntil(lambda: log.runs.rowCount() >= 1, timeout=WAIT_MS)
            log.select_run(run)
            assert log.selected_run() == run
            qtbot.mouseClick(log.plot, Qt.MouseButton.LeftButton)
            qtbot.waitUntil(lambda: scope.source.currentData() == run, timeout=WAIT_MS)
            finished = window.point_counts()["x.following_error"]
            assert finished > 1000, "the whole run, not the live thinning"
            shot(eng, "13_tuning_run_plotted")
            window.x_axis.setCurrentText("x.speed_cmd")  # one variable against another
            assert window.plot.getAxis("bottom").labelText == "x.speed_cmd"

            click(qtbot, screen, params.save)
            qtbot.waitUntil(lambda: "saved 1 parameter(s)" in params.note.text(), timeout=WAIT_MS)
            assert load_machine(machine_copy).axis["x"].kp_1_s == 150.0

            mat = exported_mat(qtbot, screen, log, run, tmp_path / "tuning.mat")
            fe = np.atleast_1d(mat["log"]["x_following_error"]["v"])
            assert len(fe) == finished and np.abs(fe).max() > 0.001, "the following error of the two moves"
            assert mat["params_start"]["axis_x_kp_1_s"] == 100.0 and mat["params_end"]["axis_x_kp_1_s"] == 150.0
            assert mat["param_changes"]["name"] == "axis.x.kp_1_s" and mat["title"] == "X gain"
            eng.tabs.setCurrentWidget(log)
            shot(eng, "14_log_runs")
        finally:
            screen.close()


def test_an_engineer_selects_an_example_program_on_the_screen_then_runs_tunes_logs_and_exports_it(qtbot, machine_copy,
                                                                                                   tmp_path):
    """QMotor's loop with a program of one's choice: chosen in the tuning window (checked on the
    simulated plant, named in the machine file), running from the controller's next start, its own
    gain tuned online, run alone for a set duration while its log variable and CPU time are
    logged, and the run exported to MATLAB with its parameters and its control benchmark."""
    def started(history: str):  # noqa: ANN202 - the controller and a screen on it, its lock taken
        config = load_machine(machine_copy, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **MID_TRAVEL, **NEAR_HOME})
        return full_controller(config, tmp_path / history), config

    controller, config = started("history.sqlite")
    with controller:
        screen = open_screen(qtbot, config)
        try:
            w = screen.window
            qtbot.waitUntil(lambda: screen.model.reachable, timeout=WAIT_MS)
            take_lock(qtbot, screen)
            qtbot.mouseClick(w.bar.tuning, Qt.MouseButton.LeftButton)
            eng = w.engineering
            qtbot.waitExposed(eng)
            eng.tabs.setCurrentWidget(eng.control)
            control = eng.control
            qtbot.waitUntil(lambda: control.listing is not None, timeout=WAIT_MS)
            assert control.state.text() == "Running: pip" and control.listing.budget_us == 500.0
            listed = {p.name: p for p in control.listing.programs}
            assert {"pip", "friction_ff", "cross_coupled", "fault_injection"} <= set(listed)
            assert [p.name for p in listed["pip"].parameters][:2] == ["kp_1_s", "ki_1_s2"]
            names = [control.programs.item(i).data(Qt.ItemDataRole.UserRole) for i in range(control.programs.count())]
            control.programs.setCurrentRow(names.index("cross_coupled"))
            assert "contour_gain_1_s = 80 1/s" in control.details.text() and "control.contour_error" in control.details.text()
            click(qtbot, screen, control.select)
            qtbot.waitUntil(lambda: control.state.text() == "Running: pip; from the next start: cross_coupled",
                            timeout=WAIT_MS)
            shot(eng, "15_control_program_selected")
            with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS):
                refused = screen.commands.send(ControlSelect("nothing")).result(timeout=30.0)
            assert not refused.ok and "'nothing' is neither a shipped program" in refused.reason
        finally:
            screen.close()
    assert load_machine(machine_copy).control.program == "cross_coupled"

    controller, config = started("history2.sqlite")
    with controller as sup:  # the next start: the program chosen runs
        screen = open_screen(qtbot, config)
        w, tuning = screen.window, screen.tuning
        try:
            qtbot.waitUntil(lambda: screen.model.reachable and bool(tuning.params) and bool(tuning.variables), timeout=WAIT_MS)
            assert "control.contour_gain_1_s" in [p.name for p in tuning.params]
            assert "control.contour_error" in [v.name for v in tuning.variables]
            home_from_the_screen(qtbot, screen)  # the command lock, reset, homing
            qtbot.mouseClick(w.bar.tuning, Qt.MouseButton.LeftButton)
            eng = w.engineering
            qtbot.waitExposed(eng)
            qtbot.waitUntil(lambda: eng.law.text().startswith("Control program cross_coupled (CrossCoupled): CPU per "
                                                              "period p50"), timeout=WAIT_MS)
            params, log, control = eng.params, eng.log, eng.control
            eng.tabs.setCurrentWidget(control)
            qtbot.waitUntil(lambda: control.state.text() == "Running: cross_coupled", timeout=WAIT_MS)
            qtbot.waitUntil(lambda: params.value_of("control.contour_gain_1_s") == "80", timeout=WAIT_MS)
            with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS) as done:
                params.set_value("control.contour_gain_1_s", "120")
            assert done.args[1].ok and "applied by the servo at tick" in params.note.text(), params.note.text()
            log.choose("control.contour_error", "continuous", window_s=LOG_WINDOW_S)
            log.choose("control_time", "continuous", window_s=LOG_WINDOW_S)
            for axis in "xy":  # the head's path, every tick of the run
                log.choose(f"{axis}.setpoint", "continuous", window_s=LOG_WINDOW_S)
            click(qtbot, screen, log.start)
            qtbot.waitUntil(lambda: tuning.running > 0, timeout=WAIT_MS)
            run = tuning.running
            def ask(msg) -> Reply:  # noqa: ANN001 - its answer taken before the next command's
                with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS):
                    reply = screen.commands.send(msg).result(timeout=30.0)
                return reply

            for msg, why in ((ControlRun("spiral", 1.0), "trajectory 'spiral' is not one of: hold, step, ramp, circle, fig10"),
                             (ControlRun("hold", 0.01), "duration_s 0.01 is out of range"),
                             (ControlRun("circle", 1.0), "outside the travel 0 to 1600 mm")):  # near home: no room
                reply = ask(msg)
                assert not reply.ok and why in reply.reason, reply.reason
            assert ask(SetMode("AUTO")).ok
            assert "wrong operation mode" in ask(ControlRun("hold", 1.0)).reason
            assert ask(SetMode("MANUAL")).ok
            assert ask(GoTo({"x": 100.0, "y": 100.0})).ok  # room for the circle
            qtbot.waitUntil(lambda: screen.model.status.planner_state == "IDLE"
                            and abs(screen.model.status.axes[0].commanded_mm - 100.0) < 1e-9, timeout=WAIT_MS)
            control.trajectory.setCurrentIndex(control.trajectory.findData("circle"))
            control.duration.setValue(1.0)
            x0, y0 = sup.servo()["commanded_mm"][:2]
            click(qtbot, screen, control.start_run)
            qtbot.waitUntil(lambda: "control run: its time is up" in logic(sup)["message"]
                            and logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                            timeout=WAIT_MS)
            assert "control run: its time is up" in logic(sup)["message"]
            shot(eng, "16_control_run")
            click(qtbot, screen, log.stop)
            qtbot.waitUntil(lambda: any(r.run == run and r.state == "done" for r in tuning.runs), timeout=WAIT_MS)
            mat = exported_mat(qtbot, screen, log, run, tmp_path / "control.mat")
            contour = np.atleast_1d(mat["log"]["control_contour_error"]["v"])
            cpu = np.atleast_1d(mat["log"]["control_time"]["v"])
            assert np.abs(contour).max() > 0.0, "the circle's contour error, as the program logged it"
            xs, ys = (np.atleast_1d(mat["log"][f"{axis}_setpoint"]["v"]) for axis in "xy")
            there = np.flatnonzero(np.hypot(xs - x0, ys - y0) < 1e-9)
            assert len(there), "the go-to's end, then the control run from there"
            xs, ys = xs[there[0]:], ys[there[0]:]
            radius = np.hypot(xs - (x0 - 20.0), ys - y0)
            assert np.abs(radius - 20.0).max() < 0.01, "on the circle from the head, all along"
            moving = np.flatnonzero(np.hypot(np.diff(xs), np.diff(ys)) > 0.0)
            assert len(moving) > 20 and math.dist((xs[-1], ys[-1]), (x0, y0)) > 1.0, "it went round part of the circle"
            seconds = (moving[-1] - moving[0] + 1) * config.timing.period_s
            assert 0.9 <= seconds <= 1.5, f"ran {seconds:.3f} s of machine time for a 1 s run (then a stop on the path)"
            assert cpu.max() > 0.0 and mat["log"]["control_time"]["unit"] == "us"
            assert mat["params_start"]["control_contour_gain_1_s"] == 120.0
            assert mat["control"]["program"] == "cross_coupled (CrossCoupled)", "each run says which law ran ..."
            assert 0.0 < mat["control"]["p50_us"] <= mat["control"]["p99_us"] <= mat["control"]["max_us"], "... at what cost"
        finally:
            screen.close()
