"""The planner process in the running controller: programs, the operator's commands and their refusals, progress."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading

import numpy as np
import pytest

from cnc.bus.keys import Keys
from cnc.bus.messages import GoTo, Hold, Jog, JogRefresh, JogStop, LoadProgram, Override, Resume, Start, Status, Stop, decode
from cnc.bus.session import open_client
from cnc.data.layout import PlannerState, RunResult, ServoState
from cnc.runtime.supervisor import MOTION_ONLY, Supervisor

from .conftest import MACHINE_FILE, REPO, ask, enable_and_hold, machine_config, wait_planner_idle

PART = """G21 G90 G64 P0.05
G0 X100 Y100
M3
G1 X300 Y100 F6000
G3 X350 Y150 R50
G1 X350 Y300
M5
G0 X120 Y120
M2
"""


def write(tmp_path, text: str, name: str = "part.ngc") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def refused(sup, command) -> str:
    reply = sup.planner.request(command)
    assert not reply.ok, f"{command} was accepted"
    return reply.reason


def test_a_program_runs_to_its_end_in_its_planned_time_and_its_progress_reaches_the_status(homed, tmp_path):
    sup = homed
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    seen: list[Status] = []
    session = open_client([f"tcp/127.0.0.1:{sup.config.zenoh.listen[0].rsplit(':', 1)[1]}"])
    got = threading.Event()

    def on_status(sample) -> None:
        st = decode(sample.payload.to_bytes(), Status)
        seen.append(st)
        if st.program and st.program.result == "DONE":
            got.set()

    sub = session.declare_subscriber(keys.status, on_status)
    try:
        ask(sup, LoadProgram(write(tmp_path, PART)))
        m = sup.motion()
        assert m["program_name"] == "part.ngc" and m["planned_s"] > 0 and len(m["program_hash"]) == 64
        pushed = m["records_pushed"]
        ask(sup, Start())
        m = wait_planner_idle(sup)
        assert m["run_result"] == RunResult.DONE and m["error"] == ""
        assert (m["records_pushed"] - pushed) * sup.config.timing.period_s == pytest.approx(m["planned_s"], abs=1e-9)
        assert m["done_mm"] == pytest.approx(m["total_mm"]) and m["eta_s"] == 0.0
        sup.wait_until(lambda: sup.servo()["actual_mm"] == pytest.approx([120.0, 120.0], abs=0.005), 5.0, "the end point")
        assert got.wait(10.0), "the status showed the run done"
    finally:
        sub.undeclare()
        session.close()
    running = [st for st in seen if st.planner_state == "RUNNING" and st.program and st.program.segment >= 0]
    assert running, "the status showed the run under way"
    lines = [st.program.line for st in running]
    assert lines == sorted(lines) and set(lines) <= {2, 4, 5, 6, 8}, "source lines of moves, in order"
    etas = [st.program.eta_s for st in running]
    assert etas[0] > etas[-1] >= 0.0 and all(0.0 <= st.program.progress <= 1.0 for st in running)
    assert any(st.jet_on for st in running) and max(st.feed_commanded_mm_s for st in running) > 99.0


def test_start_is_refused_before_homing_naming_the_axes(tmp_path):
    with Supervisor(machine_config(), clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        ask(sup, LoadProgram(write(tmp_path, PART)))
        assert "part.ngc cannot start: axis X, Y not homed" in refused(sup, Start())
        assert sup.fifo.fill() == 0 and sup.servo()["commanded_velocity_mm_s"] == [0.0, 0.0], "nothing moved"


def test_a_program_beyond_the_travel_is_refused_at_load_on_a_homed_machine_naming_its_line_and_axis(homed, tmp_path):
    far = write(tmp_path, "G0 X100 Y100\nG1 X1700 F3000\nM2\n", "far.ngc")
    loaded = homed.motion()["program_seq"], homed.motion()["program_name"]
    assert "far.ngc:2: X reaches 1700.000 mm, outside the travel 0 to 1600 mm" in refused(homed, LoadProgram(far))
    assert (homed.motion()["program_seq"], homed.motion()["program_name"]) == loaded, "the refused program replaced nothing"


def test_a_program_with_an_error_is_refused_at_load_with_its_line_and_column(homed, tmp_path):
    reason = refused(homed, LoadProgram(write(tmp_path, "G0 X10 Y10\nG1 X20 Y20 X30 F100\nM2\n", "bad.ngc")))
    assert "bad.ngc:2:12: error: multiple X words on one line" in reason
    assert "cannot read the program" in refused(homed, LoadProgram(str(tmp_path / "missing.ngc")))


def test_every_command_is_refused_with_a_reason_when_it_does_not_fit(homed, tmp_path):
    sup = homed
    assert "out of range: 0 to 200 %" in refused(sup, Override(250.0))
    assert "nothing to hold" in refused(sup, Hold())
    assert "nothing to resume" in refused(sup, Resume())
    assert "nothing to stop" in refused(sup, Stop())
    assert "not jogging" in refused(sup, JogStop())
    assert "no axis 'q'" in refused(sup, Jog("q"))
    assert "jog speed 900 mm/s is out of range" in refused(sup, Jog("x", 900.0))
    assert "outside the travel" in refused(sup, GoTo({"x": 2000.0}))
    assert "outside the travel" in refused(sup, Jog("y", 10.0, distance_mm=-500.0))
    ask(sup, LoadProgram(write(tmp_path, PART)))
    sup.pause_virtual_clock()
    try:
        ask(sup, Start())
        sup.run_ticks(300)
        assert "cannot load a program while RUNNING" in refused(sup, LoadProgram(write(tmp_path, PART)))
        assert "cannot jog while RUNNING" in refused(sup, Jog("x"))
        assert "cannot start while RUNNING" in refused(sup, Start())
        ask(sup, Stop())
    finally:
        sup.resume_virtual_clock()
    assert wait_planner_idle(sup)["run_result"] == RunResult.ABORTED


def test_a_malformed_command_is_refused_and_the_planner_carries_on(homed):
    sup = homed
    key = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name).planner("override")
    for payload in (b"not json", b'{"percent": "fast", "version": 1}', b'{"percent": 50, "version": 99}'):
        replies = list(sup.router.get(key, payload=payload, timeout=10.0))
        body = json.loads(replies[0].ok.payload.to_bytes())
        assert body["ok"] is False and "override: malformed command" in body["reason"]
    ask(sup, Override(100.0))


def test_feed_hold_stops_on_the_path_and_resume_finishes_the_program(homed, tmp_path):
    sup = homed
    ask(sup, LoadProgram(write(tmp_path, PART)))
    planned = sup.motion()["planned_s"]
    sup.pause_virtual_clock()
    try:
        ask(sup, Start())
        sup.run_ticks(1500)  # on the first cut, at 100 mm/s
        ask(sup, Hold())
        sup.run_ticks(200)
        assert sup.motion()["state"] == PlannerState.HELD
        s = sup.servo()
        x, y = s["commanded_mm"]
        assert 100.0 < x < 300.0 and y == pytest.approx(100.0, abs=1e-9), "stopped on the programmed line"
        assert s["state"] == ServoState.HOLDING and not s["setpoint_flags"] & 1, "the jet closed while held"
        sup.run_ticks(500)
        assert sup.servo()["commanded_mm"] == [x, y], "and stays there"
        ask(sup, Resume())
    finally:
        sup.resume_virtual_clock()
    m = wait_planner_idle(sup)
    assert m["run_result"] == RunResult.DONE and sup.servo()["underruns"] == 0
    assert (m["run_end_tick"] - m["run_start_tick"]) * 0.001 > planned + 0.5, "the hold and the re-pierce took their time"


def test_a_feed_override_reaches_the_setpoints_within_50_ms(homed, tmp_path):
    sup = homed
    ask(sup, LoadProgram(write(tmp_path, "G0 X100 Y500\nG1 X1000 F12000\nM2\n", "long.ngc")))
    sup.pause_virtual_clock()
    try:
        ask(sup, Start())
        sup.run_ticks(2500)  # cruising at 200 mm/s
        assert math.hypot(*sup.servo()["commanded_velocity_mm_s"]) == pytest.approx(200.0, abs=1e-6)
        sup.set_tracing(True)
        sup.trace.drain()
        ask(sup, Override(50.0))
        sup.run_ticks(200)
        trace = sup.trace.drain()
        sup.set_tracing(False)
        ask(sup, Override(100.0))
        ask(sup, Stop())
    finally:
        sup.resume_virtual_clock()
    wait_planner_idle(sup)
    speed = np.hypot(*trace["velocity"].T)
    first = int(np.flatnonzero(speed < 200.0 - 1e-6)[0])
    assert first < 50, f"the new override reached the servo after {first} ms"
    assert speed[-1] == pytest.approx(100.0, abs=1e-6) and first + 100 < len(speed), "100 mm/s reached, jerk-limited"


def test_jog_continuous_and_incremental_and_go_to_move_through_the_planner(homed):
    sup = homed
    ask(sup, GoTo({"x": 400.0, "y": 300.0}))
    wait_planner_idle(sup)
    sup.wait_until(lambda: sup.servo()["actual_mm"] == pytest.approx([400.0, 300.0], abs=0.005), 5.0, "the go-to target")
    ask(sup, Jog("y", 10.0, distance_mm=-25.5))
    wait_planner_idle(sup)
    assert sup.servo()["commanded_mm"] == pytest.approx([400.0, 274.5], abs=1e-9)
    sup.pause_virtual_clock()
    try:
        ask(sup, Jog("x", -40.0))
        for _ in range(10):  # a held key: the station refreshes the jog every 100 ms (the dead-man)
            sup.run_ticks(100)
            ask(sup, JogRefresh())
        assert sup.motion()["state"] == PlannerState.JOGGING
        assert sup.servo()["commanded_velocity_mm_s"][0] == pytest.approx(-40.0)
        ask(sup, JogStop())
        sup.run_ticks(300)
    finally:
        sup.resume_virtual_clock()
    wait_planner_idle(sup)
    x = sup.servo()["commanded_mm"][0]
    assert 355.0 < x < 362.0 and sup.servo()["commanded_velocity_mm_s"] == [0.0, 0.0]


def test_go_to_is_refused_on_an_unhomed_axis():
    with Supervisor(machine_config(), clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        assert "axis X is not homed" in refused(sup, GoTo({"x": 100.0}))
        ask(sup, Jog("x", 30.0, distance_mm=12.0))  # jogging needs no home
        wait_planner_idle(sup)
        assert sup.servo()["commanded_mm"][0] == pytest.approx(812.0, abs=1e-9)


def test_waterjet_simulate_reports_every_figure_and_plots_the_run(tmp_path):
    prog = write(tmp_path, PART)
    out_json, out_png = tmp_path / "run.json", tmp_path / "run.png"
    res = subprocess.run(
        [sys.executable, "-m", "cnc.cli", "simulate", prog, "--machine", str(MACHINE_FILE), "--json", str(out_json),
         "--plot", str(out_png)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )
    assert res.returncode == 0, res.stderr
    figures = json.loads(out_json.read_text())
    for key in ("cycle_time_s", "path_deviation_max_mm", "tracking_error_max_mm", "tracking_error_rms_mm",
                "contour_error_max_mm", "following_error_max_mm", "peak_velocity_mm_s", "peak_accel_mm_s2",
                "peak_jerk_mm_s3", "fifo_min_fill", "underruns", "overruns"):
        assert key in figures, key
    assert figures["cycle_time_s"] == pytest.approx(figures["planned_cycle_time_s"], abs=1e-9)
    assert figures["path_deviation_max_mm"] <= 0.05 and figures["contour_error_max_mm"] < 0.02
    assert figures["underruns"] == 0 and figures["fifo_min_fill"] > 0
    assert all(v <= 5000.0 * (1 + 1e-6) for v in figures["peak_accel_mm_s2"].values())
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "cycle time" in res.stdout and "contour error" in res.stdout


def test_waterjet_simulate_refuses_a_broken_program_with_its_line(tmp_path):
    prog = write(tmp_path, "G0 X10 Y10\nG2 X20 Y10 R2\nM2\n", "arc.ngc")
    res = subprocess.run(
        [sys.executable, "-m", "cnc.cli", "simulate", prog, "--machine", str(MACHINE_FILE)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )
    assert res.returncode == 1 and "arc.ngc:2:" in res.stderr and "radius" in res.stderr


def test_waterjet_check_prints_the_planned_cycle_time_the_controller_runs(tmp_path):
    prog = write(tmp_path, "G0 X0 Y0\n" + PART)
    res = subprocess.run(
        [sys.executable, "-m", "cnc.cli", "check", prog, "--machine", str(MACHINE_FILE)], cwd=REPO, capture_output=True, text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    line = next(ln for ln in res.stdout.splitlines() if "cycle time" in ln)
    assert float(line.split()[2]) > 3.0 and "planned at 100 % override" in line


def test_a_long_restart_is_timed_in_the_background_and_its_eta_counts_down_to_its_end(homed, tmp_path):
    """A restart longer than the runs timed before they move (`TIMED_AT_LOAD_SEGMENTS`) starts on
    its first steps, its cycle time made meanwhile in a process of its own, as a long program's
    after a load: its ETA shows once that is done (it stayed unknown to the end before) and is the
    time the run then still takes."""
    from cnc.bus.messages import RestartAt
    from cnc.planner.process import TIMED_AT_LOAD_SEGMENTS
    from cnc.planner.steps import STEPS_AHEAD

    sup = homed
    moves, parts = [], TIMED_AT_LOAD_SEGMENTS // 10 + 10  # a cut of 10 moves a part: more segments than that
    assert parts > STEPS_AHEAD, "more parts than the steps a run makes ahead: the end is not made early"
    for k in range(parts):
        moves += ["M3", *(f"G1 X{100.0 + 3.0 * (j % 2):.1f} Y{100.0 + 2.0 * k + 0.2 * j:.1f}" for j in range(10)), "M5"]
    ask(sup, LoadProgram(write(tmp_path, "\n".join(["G21 G90 G64 P0.05", "G0 X100 Y100", "F12000", *moves,
                                                    "G0 X120 Y120", "M2", ""]), "zigzag.ngc")))
    ask(sup, Start(restart=RestartAt("line", number=10)))
    assert sup.motion()["event"].startswith("restart: run from line 10")
    dt = sup.config.timing.period_s
    sup.pause_virtual_clock()
    try:
        for _ in range(200_000):  # tick by tick until the ETA is known
            sup.run_ticks(1)
            m = sup.motion()
            if m["eta_s"] > 0.0 or m["state"] != PlannerState.RUNNING:
                break
        assert m["state"] == PlannerState.RUNNING and m["eta_s"] > 0.0, "the restart's ETA came while it ran"
        eta, tick = m["eta_s"], sup.hw()["tick"]
    finally:
        sup.resume_virtual_clock()
    m = wait_planner_idle(sup)
    assert m["run_result"] == RunResult.DONE and m["eta_s"] == 0.0
    took = (m["run_end_tick"] - tick) * dt
    assert eta == pytest.approx(took, rel=1e-3, abs=10 * dt), (eta, took)
    # known early: the steps the run makes ahead (`STEPS_AHEAD`) reach the end only near it
    assert took > 0.5 * (m["run_end_tick"] - m["run_start_tick"]) * dt, "the ETA came while most of the run was ahead"
