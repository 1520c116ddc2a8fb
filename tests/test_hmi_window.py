"""The operator screen against a real controller on the virtual clock (pytest-qt, offscreen): the
automatic cycle commanded from the screen, alarms in the list and the history, a procedure walked,
the connection lost and regained, read-only without the lock, and `waterjet hmi --screenshot`.

Each test saves screenshots of the screens it passes through to tests/screenshots/ (or
$HMI_SCREENSHOTS), not committed, for a person to look at.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QPushButton, QWidget

from cnc.alarms.catalogue import AlarmAction, AlarmLevel
from cnc.alarms.history import AlarmHistory
from cnc.bus.keys import Keys
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from hmi.controls import STOP_ALL_KEY
from hmi.model import Screen
from hmi.session import OperatorScreen

from .conftest import NEAR_HOME, REPO, free_port, logic, machine_config
from .test_hmi_model import start_controller
from .test_zenoh_interface import PART

pytest.importorskip("pytestqt")
SHOTS = Path(os.environ.get("HMI_SCREENSHOTS", REPO / "tests" / "screenshots"))
WAIT_MS = 30000

BAD_PART = "G21 G90\nG0 X100 Y100\nG1 X20 Y20 X30 F100\nM2\n"  # two X words on line 3, column 12


def shot(widget: QWidget, name: str) -> Path:
    """Save what the operator sees now."""
    SHOTS.mkdir(parents=True, exist_ok=True)
    path = SHOTS / f"{name}.png"
    assert widget.grab().save(str(path)), f"cannot write {path}"
    return path


def open_screen(qtbot, config, station: str = "panel") -> OperatorScreen:
    screen = OperatorScreen([config.zenoh.listen[0]], config.zenoh.key_prefix, config.machine.name, station)
    screen.window.show()
    qtbot.waitExposed(screen.window)
    return screen


def click(qtbot, screen: OperatorScreen, button: QPushButton, ok: bool | None = True):
    """Click an enabled button and wait for the controller's answer to the command it sent (`ok`:
    what it must say; None: either)."""
    qtbot.waitUntil(button.isEnabled, timeout=WAIT_MS)
    with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS) as blocker:
        qtbot.mouseClick(button, Qt.MouseButton.LeftButton)
    label, reply = blocker.args
    assert ok is None or reply.ok == ok, f"{label}: {reply.reason}"
    return reply


def _screen_on(qtbot, sup):
    """A screen on `sup`'s controller, once it is reachable and has the procedure catalogue."""
    s = open_screen(qtbot, sup.config)
    qtbot.waitUntil(lambda: s.model.reachable and s.model.catalogue != [], timeout=WAIT_MS)
    yield s
    s.close()


@pytest.fixture
def screen(qtbot, plc_controller):
    yield from _screen_on(qtbot, plc_controller)


@pytest.fixture
def library_screen(qtbot, library_controller):
    """A screen on a controller whose program library checks the stored programs."""
    yield from _screen_on(qtbot, library_controller)


def take_lock(qtbot, screen: OperatorScreen) -> None:
    click(qtbot, screen, screen.window.bar.lock_button)
    qtbot.waitUntil(lambda: screen.model.holds_lock and screen.window.banner_text == "", timeout=WAIT_MS)


def test_operator_runs_the_automatic_cycle_end_to_end_from_the_screen(qtbot, plc_controller, screen, tmp_path):
    sup, w, model = plc_controller, screen.window, screen.model
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    other_session = open_client([sup.config.zenoh.listen[0]])
    other = OperatorStation(other_session, keys, "other")
    assert other.take_lock().ok
    qtbot.waitUntil(lambda: "Read-only: station 'other' holds the command lock" in w.banner_text, timeout=WAIT_MS)
    assert not w.bar.reset.isEnabled() and not w.pages[Screen.MANUAL].home_all.isEnabled(), "read-only: greyed"
    assert w.bar.lock_button.isEnabled()
    shot(w, "01_read_only_manual")
    assert other.release_lock().ok
    other.close()
    other_session.close()

    take_lock(qtbot, screen)
    assert w.current_screen is Screen.MANUAL
    click(qtbot, screen, w.bar.reset)
    qtbot.waitUntil(lambda: all(a.drive_enabled for a in model.status.axes), timeout=WAIT_MS)
    manual = w.pages[Screen.MANUAL]
    click(qtbot, screen, manual.home_all)
    qtbot.waitUntil(lambda: model.status.machine_state == "READY" and w.panels.lamps["homed"].state == "yes",
                    timeout=WAIT_MS)

    x0 = model.status.axes[0].commanded_mm
    manual.jog.step.setCurrentIndex(manual.jog.step.findData(1.0))
    click(qtbot, screen, manual.jog.buttons[("x", 1)])
    qtbot.waitUntil(lambda: abs(model.status.axes[0].commanded_mm - (x0 + 1.0)) < 1e-3
                    and model.status.machine_state == "READY", timeout=WAIT_MS)
    manual.jog.step.setCurrentIndex(0)  # continuous: the arrow key held, then released
    w.activateWindow()
    qtbot.waitUntil(w.isActiveWindow, timeout=WAIT_MS)
    y0 = model.status.axes[1].commanded_mm
    sent: list[str] = []
    screen.commands.replied.connect(lambda label, reply: sent.append(label))
    qtbot.keyPress(w, Qt.Key.Key_Up)
    # held: the pad refreshes the jog (the controller's dead-man stops a jog nobody refreshes)
    qtbot.waitUntil(lambda: sent.count("Jog held") >= 2, timeout=WAIT_MS)
    qtbot.keyRelease(w, Qt.Key.Key_Up)
    qtbot.waitUntil(lambda: "Stop jogging" in sent, timeout=WAIT_MS)
    assert sent[0] == "Jog Y+ at 50 mm/s" and sent[-1] == "Stop jogging"
    assert set(sent[1:-1]) == {"Jog held"} and not manual.jog._refresh.isActive(), "released: no more refreshes"
    qtbot.waitUntil(lambda: model.status.axes[1].commanded_mm > y0 and model.status.machine_state == "READY"
                    and model.status.planner_state == "IDLE", timeout=WAIT_MS)

    click(qtbot, screen, w.bar.auto)
    qtbot.waitUntil(lambda: w.current_screen is Screen.AUTO, timeout=WAIT_MS)
    auto = w.pages[Screen.AUTO]
    bad = tmp_path / "bad.ngc"
    bad.write_text(BAD_PART)
    with qtbot.waitSignal(auto.program.uploaded, timeout=WAIT_MS) as refused:
        auto.program.load_file(bad)
    assert not refused.args[0].ok
    assert "bad.ngc:3:12" in auto.program.error.text() and "X" in auto.program.error.text()
    assert auto.program.highlighted_line() == 3 and auto.program.text.textCursor().positionInBlock() == 11
    shot(w, "02_program_error_highlighted")

    good = tmp_path / "part.ngc"
    good.write_text(PART)
    with qtbot.waitSignal(auto.program.uploaded, timeout=WAIT_MS) as loaded:
        auto.program.load_file(good)
    assert loaded.args[0].ok, loaded.args[0].reason
    qtbot.waitUntil(lambda: auto.program.text.toPlainText() == PART, timeout=WAIT_MS)  # the controller's copy
    assert model.program.segments == 6 and auto.program.error.isHidden()
    # the model takes the program on the connection's thread; the screen draws it when its queued
    # signal is handled, which may come after the text: wait for the drawing, not only the model
    drawn = (0.0, 140.0, 0.0, 140.0)  # from the program origin
    qtbot.waitUntil(lambda: (b := w.contour.path_bounds()) is not None and b == pytest.approx(drawn, abs=1e-6),
                    timeout=WAIT_MS)

    click(qtbot, screen, auto.cycle_start)
    qtbot.waitUntil(lambda: w.current_screen is Screen.PROCEDURE, timeout=WAIT_MS)
    procedure = w.pages[Screen.PROCEDURE].procedure
    qtbot.waitUntil(lambda: "Press the button at the transport station" in procedure.instruction.text(), timeout=WAIT_MS)
    assert procedure.title.text() == "TRANSPORT PHASE"
    lines = procedure.step_lines()
    assert len(lines) == 11 and all("(done)" in line for line in lines[:10]) and "(awaited)" in lines[10]
    assert not w.pages[Screen.PROCEDURE].manual.isVisibleTo(w), "in AUTO the steps are actions at the machine"
    shot(w, "03_transport_procedure")
    qtbot.waitUntil(lambda: w.tabs.isTabVisible(w._sim_tab), timeout=WAIT_MS)  # a simulated machine: its panel
    click(qtbot, screen, w.simulator.controls["transport_button"])  # the operator at the transport station

    heads: list[tuple[float, float] | None] = []
    screen.adapter.position.connect(lambda: heads.append(w.contour.head_position()))  # after the window drew it
    qtbot.waitUntil(lambda: w.contour.progress >= 2 and w.panels.lamps["jet"].state.startswith("ON"), timeout=WAIT_MS)
    assert w.current_screen is Screen.AUTO and w.panels.values["phase"].text() == "CUTTING"
    assert w.panels.progress.value() > 0 and w.panels.values["block"].text().startswith("N")
    qtbot.waitUntil(lambda: 5 <= auto.program.highlighted_line() <= 8, timeout=WAIT_MS)  # the block being cut: a G1
    click(qtbot, screen, auto.hold)
    qtbot.waitUntil(lambda: model.status.machine_state == "HOLD" and not model.status.jet_on, timeout=WAIT_MS)
    shot(w, "04_cutting_held")
    click(qtbot, screen, auto.resume)
    qtbot.waitUntil(lambda: logic(sup)["cycles_done"] == 1 and model.status.cycle_phase == "NONE", timeout=60000)
    qtbot.waitUntil(lambda: w.contour.progress == 6, timeout=WAIT_MS)
    assert len({h for h in heads if h is not None}) > 1, "the head cross moved"
    qtbot.waitUntil(lambda: w.contour.head_position() == pytest.approx((60.0, 60.0), abs=0.01), timeout=WAIT_MS)
    qtbot.waitUntil(lambda: any("3001" in line for line in w.messages.entries()), timeout=WAIT_MS)
    shot(w, "05_cycle_done")

    # a second cut, the door opened from the simulator panel: the fault page, the door closed, reset, cut again
    panel = w.simulator
    w.tabs.setCurrentWidget(panel)
    shot(w, "05b_simulator_panel")

    def start_and_press() -> None:
        click(qtbot, screen, auto.cycle_start)
        qtbot.waitUntil(lambda: "Press the button at the transport station" in procedure.instruction.text(),
                        timeout=WAIT_MS)
        click(qtbot, screen, panel.controls["transport_button"])
        qtbot.waitUntil(lambda: model.status.cycle_phase == "CUTTING" and model.status.jet_on, timeout=60000)

    start_and_press()
    click(qtbot, screen, panel.controls["doors_open"])
    qtbot.waitUntil(lambda: w.current_screen is Screen.FAULT and "Safety door open" in w.faults.entries()
                    and not model.status.jet_on and panel.controls["doors_open"].isChecked(), timeout=WAIT_MS)
    shot(w, "05c_door_opened_from_the_panel")
    click(qtbot, screen, panel.controls["doors_open"])
    # the reset once the door is shut and the axes stand still (a reset while their stop runs out
    # is refused, saying so): the stop is machine time, which a busy host may stretch
    qtbot.waitUntil(lambda: "Safety door open" not in w.faults.entries()
                    and not panel.controls["doors_open"].isChecked() and model.status.servo_state != "STOPPING",
                    timeout=WAIT_MS)
    click(qtbot, screen, w.bar.reset)
    qtbot.waitUntil(lambda: model.status.machine_state == "READY" and w.current_screen is Screen.AUTO, timeout=WAIT_MS)
    cycles = model.status.cycles_done
    start_and_press()
    qtbot.waitUntil(lambda: model.status.cycles_done == cycles + 1 and model.status.cycle_phase == "NONE",
                    timeout=60000)
    history = [e.detail for e in model.history_view() if e.code == 3004]
    assert any("transport_button set to 1" in d for d in history) and any("doors_open set to 0" in d for d in history)
    shot(w, "05d_cut_again")
    model.apply_sim_inputs(None)  # what a controller on a real board answers (it refuses <root>/sim): no panel
    qtbot.waitUntil(lambda: not w.tabs.isTabVisible(w._sim_tab), timeout=WAIT_MS)


def test_an_alarm_shows_in_the_list_faults_messages_and_history_and_is_acknowledged_and_reset(
        qtbot, plc_controller, screen):
    sup, w, model = plc_controller, screen.window, screen.model
    take_lock(qtbot, screen)
    sup.set_sim(doors_open=1)
    qtbot.waitUntil(lambda: any(r[1] == "2292" for r in w.alarms.rows()) and "Safety door open" in w.faults.entries()
                    and w.panels.lamps["reset"].state == "reset needed", timeout=WAIT_MS)
    [row] = [r for r in w.alarms.rows() if r[1] == "2292"]
    assert row[0] == "ERROR" and row[5] == "present" and row[6] == "no"
    # the lamp shows the status, which comes at its own rate: the alarm's event may be there first
    qtbot.waitUntil(lambda: w.panels.lamps["doors"].state == "OPEN", timeout=WAIT_MS)
    qtbot.waitUntil(lambda: any("2292" in line and "raised" in line for line in w.messages.entries()), timeout=WAIT_MS)
    qtbot.waitUntil(lambda: w.current_screen is Screen.FAULT, timeout=WAIT_MS)
    fault_page = w.pages[Screen.FAULT]
    shot(w, "06_fault_door_open")

    fault_page.alarms.table.selectRow(0)
    click(qtbot, screen, fault_page.alarms.acknowledge)
    qtbot.waitUntil(lambda: [r[6] for r in w.alarms.rows() if r[1] == "2292"] == ["yes"], timeout=WAIT_MS)
    reply = click(qtbot, screen, w.bar.reset)
    assert "still present: 2292" in reply.reason, "not reset while the cause is present"
    assert "the drives stay off while a door is open" in reply.reason, reply.reason
    assert w.command_line.text().startswith("✔ Reset: ") and "still present: 2292" in w.command_line.text()
    sup.set_sim(doors_open=0)
    qtbot.waitUntil(lambda: [r[5] for r in w.alarms.rows() if r[1] == "2292"] == ["cleared, reset needed"]
                    and "Safety door open" not in w.faults.entries(), timeout=WAIT_MS)
    # the first reset, the door still open, left the drives off (on, they would have tripped at once and
    # this reset been refused until their stop ran out): one reset now, and it is taken
    click(qtbot, screen, w.bar.reset)
    qtbot.waitUntil(lambda: model.active_alarms == [] and w.alarms.rows() == [], timeout=WAIT_MS)
    qtbot.waitUntil(lambda: w.current_screen is Screen.MANUAL, timeout=WAIT_MS)
    with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS) as esc:
        qtbot.keyClick(w, Qt.Key.Key_Escape)
    assert esc.args[0] == "Stop", "Esc is STOP on every page"

    w.show_history()
    h = w.history
    qtbot.waitExposed(h)
    h.set_filter(codes="2292")
    qtbot.waitUntil(lambda: [r[4] for r in reversed(h.rows())] == ["raised", "acknowledged", "cleared", "reset"],
                    timeout=WAIT_MS)
    h.set_filter(text="DOOR", levels=["error"])
    assert h.rows() and all(r[3] == "ERROR" for r in h.rows())
    h.set_filter(levels=["info"], codes="2292")
    assert h.rows() == []
    h.set_filter(codes="22x")
    assert "'22x' is not an alarm code" in h.count.text()
    h.set_filter()
    assert len(h.rows()) == len(model.history_view())
    h.set_filter(text="door", codes="2292")
    with qtbot.waitSignal(h._found, timeout=WAIT_MS):
        qtbot.mouseClick(h.search_button, Qt.MouseButton.LeftButton)
    assert h.searched and [r[4] for r in h.rows()] == ["reset", "cleared", "acknowledged", "raised"]
    assert "found in the controller's whole history" in h.count.text()
    shot(h, "07_message_history")

    # the servo three ticks late: a warning in the list, the timing lamp says so until the episode ends
    sup.stall_servo(3)
    qtbot.waitUntil(lambda: any(r[1] == "1015" and r[0] == "WARNING" for r in w.alarms.rows())
                    and w.panels.lamps["timing"].state.startswith("LATE NOW: "), timeout=WAIT_MS)
    qtbot.waitUntil(lambda: w.panels.lamps["timing"].state.endswith("ticks late since start")
                    and not w.panels.lamps["timing"].state.startswith("LATE"), timeout=WAIT_MS)


def test_walking_a_procedure_with_confirmations_and_manual_steps_from_the_procedure_window(qtbot, screen):
    w, model = screen.window, screen.model
    take_lock(qtbot, screen)
    manual = w.pages[Screen.MANUAL]
    manual.procedures.setCurrentIndex(manual.procedures.findData("pump_warmup"))
    click(qtbot, screen, manual.procedure_start)
    qtbot.waitUntil(lambda: w.current_screen is Screen.PROCEDURE, timeout=WAIT_MS)
    page = w.pages[Screen.PROCEDURE]
    proc = page.procedure
    qtbot.waitUntil(lambda: proc.confirm.isEnabled(), timeout=WAIT_MS)
    assert proc.title.text() == "PUMP WARM-UP" and "catcher" in proc.instruction.text()
    assert page.manual.isVisibleTo(w), "in MANUAL the controls a step asks for are beside the procedure"
    shot(w, "08_procedure_confirm_step")
    click(qtbot, screen, proc.confirm)
    qtbot.waitUntil(lambda: "Switch the pump on" in proc.instruction.text(), timeout=WAIT_MS)
    assert not proc.confirm.isEnabled(), "a condition step is not confirmed by hand"
    click(qtbot, screen, page.manual.pump_on)
    qtbot.waitUntil(lambda: "jet test" in proc.instruction.text() and proc.confirm.isEnabled(), timeout=WAIT_MS)
    assert [line.endswith("(done)") for line in proc.step_lines()] == [True, True, True, True, False]
    qtbot.waitUntil(lambda: w.panels.lamps["pump"].state == "running", timeout=WAIT_MS)
    click(qtbot, screen, proc.confirm)
    qtbot.waitUntil(lambda: model.procedure.state == "done" and proc.end.isEnabled(), timeout=WAIT_MS)
    assert not proc.stop.isEnabled()
    shot(w, "09_procedure_done")
    click(qtbot, screen, proc.end)
    qtbot.waitUntil(lambda: w.current_screen is Screen.MANUAL, timeout=WAIT_MS)
    click(qtbot, screen, manual.pump_off)

    manual.procedures.setCurrentIndex(manual.procedures.findData("startup"))
    click(qtbot, screen, manual.procedure_start)
    qtbot.waitUntil(lambda: w.current_screen is Screen.PROCEDURE and proc.stop.isEnabled(), timeout=WAIT_MS)
    click(qtbot, screen, proc.stop)
    qtbot.waitUntil(lambda: proc.state.text() == "PROCEDURE STOPPED" and proc.end.isEnabled(), timeout=WAIT_MS)
    click(qtbot, screen, proc.end)
    qtbot.waitUntil(lambda: w.current_screen is Screen.MANUAL, timeout=WAIT_MS)


def test_losing_the_controller_shows_the_banner_disables_commands_and_reconnecting_catches_up(qtbot, tmp_path):
    config = machine_config(**NEAR_HOME)
    sup = start_controller(config, tmp_path)
    screen = open_screen(qtbot, config)
    w, model = screen.window, screen.model
    try:
        qtbot.waitUntil(lambda: model.reachable and model.catalogue != [], timeout=WAIT_MS)
        take_lock(qtbot, screen)
        assert w.bar.reset.isEnabled()
        sup.stop()
        qtbot.waitUntil(lambda: w.banner_text.startswith("CONTROLLER UNREACHABLE at tcp/127.0.0.1:"), timeout=WAIT_MS)
        assert w.current_screen is Screen.OFFLINE and not w.bar.reset.isEnabled() and not w.bar.lock_button.isEnabled()
        assert w.panels.lamps["network"].state == "NO (controller unreachable)"
        shot(w, "10_controller_unreachable")
        with AlarmHistory(tmp_path / "history.sqlite") as history:
            history.append(stamp_ns=time.time_ns(), code=9999, id="offline_entry", level=AlarmLevel.WARNING,
                           action=AlarmAction.RAISED, text="Written while the screen was away")
        sup = start_controller(config, tmp_path)
        qtbot.waitUntil(lambda: model.reachable and w.current_screen is Screen.MANUAL, timeout=WAIT_MS)
        qtbot.waitUntil(lambda: any("9999" in line for line in w.messages.entries()), timeout=WAIT_MS)
        assert [e.seq for e in model.history_view()] == list(range(model.last_seq, 0, -1)), "nothing missed"
        qtbot.waitUntil(lambda: w.banner_text.startswith("Read-only"), timeout=WAIT_MS)  # a new controller: a new lock
        take_lock(qtbot, screen)
        out = tmp_path / "cli.png"
        cli = subprocess.run(
            [sys.executable, "-m", "cnc.cli", "hmi", "--connect", config.zenoh.listen[0], "--machine",
             config.machine.name, "--station", "doc", "--screenshot", str(out)],
            capture_output=True, text=True, timeout=60, env={**os.environ, "QT_QPA_PLATFORM": "offscreen"},
        )
        assert cli.returncode == 0, cli.stderr
        assert "(manual, reachable)" in cli.stdout and out.stat().st_size > 10000
    finally:
        screen.close()
        sup.stop()


def test_waterjet_hmi_refuses_bad_options_naming_them():
    def run(*args: str) -> subprocess.CompletedProcess:
        env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")}
        return subprocess.run([sys.executable, "-m", "cnc.cli", "hmi", *args], capture_output=True, text=True,
                              timeout=60, env=env)

    bad = run("--machine", "wj/../x", "--screenshot", "x.png")
    assert bad.returncode == 2 and "--machine 'wj/../x'" in bad.stderr
    bad = run("--after", "-1", "--screenshot", "x.png")
    assert bad.returncode == 2 and "--after -1: give 0 to 3600 seconds" in bad.stderr
    bad = run("--station", "a b", "--screenshot", "x.png")
    assert bad.returncode == 2 and "--station 'a b'" in bad.stderr
    bad = run("--credentials", "/nonexistent/creds")
    assert bad.returncode == 2 and "--credentials /nonexistent/creds" in bad.stderr
    headless = run("--connect", "tcp/127.0.0.1:1")
    assert headless.returncode == 2 and "no display" in headless.stderr and "--screenshot" in headless.stderr


def test_a_screenshot_of_an_unreachable_controller_is_rendered_after_the_latest_wait_and_says_so(tmp_path):
    """`--screenshot` waits for the screen to catch up with the controller; with none there it
    renders at `--after` and the screen says the controller is unreachable."""
    out = tmp_path / "away.png"
    cli = subprocess.run(
        [sys.executable, "-m", "cnc.cli", "hmi", "--connect", f"tcp/127.0.0.1:{free_port()}", "--screenshot", str(out),
         "--after", "0.5"],
        capture_output=True, text=True, timeout=60, env={**os.environ, "QT_QPA_PLATFORM": "offscreen"},
    )
    assert cli.returncode == 0, cli.stderr
    assert "(offline, controller unreachable)" in cli.stdout and out.stat().st_size > 10000


def test_a_program_file_that_is_not_utf8_text_is_refused_before_it_is_sent_naming_line_and_column(tmp_path):
    from hmi.program import ProgramError, read_program

    path = tmp_path / "scan.ngc"
    path.write_bytes(b"G21 G90\nG1 X1 (caf\xe9)\n")
    with pytest.raises(ProgramError, match=r"scan.ngc:2:11: not UTF-8 text \(byte 0xe9\)"):
        read_program(path)
    with pytest.raises(ProgramError, match="missing.ngc: cannot read"):
        read_program(tmp_path / "missing.ngc")
    path.write_text("G1 X1 (café)\n", encoding="utf-8")
    assert read_program(path) == "G1 X1 (café)\n"


def test_stop_all_is_enabled_without_the_lock_and_its_key_stops_everything(qtbot, plc_controller, screen):
    """A read-only station (another holds the lock) greys STOP but not stop all: the prominent
    control and its shortcut send it, and the alarm names this station."""
    sup, w = plc_controller, screen.window
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    other_session = open_client([sup.config.zenoh.listen[0]])
    other = OperatorStation(other_session, keys, "other")
    assert other.take_lock().ok
    qtbot.waitUntil(lambda: not w.bar.stop.isEnabled() and w.bar.stop_all.isEnabled(), timeout=WAIT_MS)
    assert "Not the emergency stop" in w.bar.stop_all.toolTip() and "software" in w.bar.stop_all.text()
    assert STOP_ALL_KEY == "Ctrl+Shift+Space" and STOP_ALL_KEY in w.bar.stop_all.toolTip()
    with qtbot.waitSignal(screen.commands.replied, timeout=WAIT_MS) as blocker:
        qtbot.keyClick(w, Qt.Key.Key_Space, Qt.KeyboardModifier.ControlModifier | Qt.KeyboardModifier.ShiftModifier)
    label, reply = blocker.args
    assert (label, reply.ok) == ("Stop all", True), reply.reason
    assert w.command_line.text().startswith("✔ Stop all: everything stopped")
    qtbot.waitUntil(lambda: any(r[1] == "1097" for r in w.alarms.rows()), timeout=WAIT_MS)
    with AlarmHistory(sup.history_path, readonly=True) as history:
        [raised] = [e for e in history.after(0, 1000).entries if e.code == 1097 and e.action == "raised"]
    assert raised.detail.startswith("stop all from station ") and "(local)" in raised.detail
    other.close()
    other_session.close()


def home_from_the_screen(qtbot, screen: OperatorScreen) -> None:
    w, model = screen.window, screen.model
    take_lock(qtbot, screen)
    click(qtbot, screen, w.bar.reset)
    qtbot.waitUntil(lambda: all(a.drive_enabled for a in model.status.axes), timeout=WAIT_MS)
    click(qtbot, screen, w.pages[Screen.MANUAL].home_all)
    qtbot.waitUntil(lambda: model.status.machine_state == "READY" and model.status.planner_state == "IDLE",
                    timeout=WAIT_MS)


def test_mdi_typed_on_the_manual_page_runs_and_a_refusal_points_at_its_column(qtbot, plc_controller, screen):
    """Lines typed in the MDI box run with Ctrl+Enter; the arrow keys move the cursor there, they
    do not jog; a refused entry shows why, its line highlighted and the cursor at the column."""
    w, model = screen.window, screen.model
    home_from_the_screen(qtbot, screen)
    mdi = w.pages[Screen.MANUAL].mdi
    sent: list[str] = []
    screen.commands.replied.connect(lambda label, reply: sent.append(label))
    w.activateWindow()
    qtbot.waitUntil(w.isActiveWindow, timeout=WAIT_MS)
    mdi.editor.setFocus()
    qtbot.waitUntil(mdi.editor.hasFocus, timeout=WAIT_MS)
    qtbot.keyClicks(mdi.editor, "G0 X50 Y45")
    qtbot.keyClick(mdi.editor, Qt.Key.Key_Left)
    qtbot.keyClick(mdi.editor, Qt.Key.Key_Up)
    with qtbot.waitSignal(mdi.answered, timeout=WAIT_MS) as blocker:
        qtbot.keyClick(mdi.editor, Qt.Key.Key_Return, Qt.KeyboardModifier.ControlModifier)
    assert blocker.args[0].ok, blocker.args[0].reason
    assert not any(label.startswith("Jog") for label in sent), f"the arrow keys jogged while typing: {sent}"
    assert "MDI: G0 X50 Y45" in sent
    qtbot.waitUntil(lambda: model.status.machine_state == "READY" and model.status.planner_state == "IDLE"
                    and abs(model.status.axes[0].commanded_mm - 50.0) < 1e-6
                    and abs(model.status.axes[1].commanded_mm - 45.0) < 1e-6, timeout=WAIT_MS)
    assert mdi.recent.itemData(1) == "G0 X50 Y45", "the entry is kept to run again"

    mdi.editor.setPlainText("G0 X60\nG1 X70 Q5 F100")
    with qtbot.waitSignal(mdi.answered, timeout=WAIT_MS) as blocker:
        qtbot.mouseClick(mdi.run, Qt.MouseButton.LeftButton)
    assert not blocker.args[0].ok
    assert mdi.error.isVisible() and mdi.error.text().startswith("MDI:2:8:")
    assert mdi.error_position() == (2, 8) and len(mdi.editor.extraSelections()) == 1
    assert abs(model.status.axes[0].commanded_mm - 50.0) < 1e-6, "nothing moved"
    shot(w, "manual_mdi_refused")


def test_the_program_library_lists_previews_loads_and_deletes_from_the_screen(qtbot, library_controller, library_screen,
                                                                              tmp_path):
    sup, screen = library_controller, library_screen
    w, model = screen.window, screen.model
    programs = tmp_path / "programs"  # the controller's program directory, beside its history
    programs.mkdir(exist_ok=True)
    (programs / "square.ngc").write_text(PART)
    (programs / "broken.ngc").write_text(BAD_PART)
    take_lock(qtbot, screen)
    click(qtbot, screen, w.bar.auto)
    qtbot.waitUntil(lambda: w.current_screen is Screen.AUTO, timeout=WAIT_MS)
    auto = w.pages[Screen.AUTO]
    library = auto.library
    auto.tabs.setCurrentWidget(library)

    def listed() -> dict[str, list[str]]:
        return {library.table.item(r, 0).data(Qt.ItemDataRole.UserRole):
                [library.table.item(r, c).text() for c in range(library.table.columnCount())]
                for r in range(library.table.rowCount())}
    qtbot.waitUntil(lambda: set(listed()) == {"square.ngc", "broken.ngc"}
                    and all("checking…" not in row for row in listed().values()), timeout=120000)
    square = listed()["square.ngc"]
    assert square[2] == "11" and square[3].endswith(" m") and ":" in square[4] and square[5] == "never", square
    assert listed()["broken.ngc"][2] == "refused"

    assert library.select("square.ngc")
    with qtbot.waitSignal(library.previewed, timeout=WAIT_MS):
        qtbot.mouseClick(library.preview_button, Qt.MouseButton.LeftButton)
    assert library.text.toPlainText() == PART and library.info.text().startswith("Preview of square.ngc (not loaded)")
    assert w.contour.path_bounds() is not None, "the preview's path is drawn"
    assert sup.motion()["program_name"] == "", "a preview loads nothing"

    assert library.select("broken.ngc")
    with qtbot.waitSignal(library.previewed, timeout=WAIT_MS):
        library.preview_selected()
    assert "refused at line 3, column 12" in library.info.text()
    shot(w, "auto_library_preview_refused")

    assert library.select("square.ngc")
    click(qtbot, screen, library.load_button)
    qtbot.waitUntil(lambda: model.program is not None and model.program.name == "square.ngc", timeout=WAIT_MS)
    qtbot.waitUntil(lambda: listed().get("square.ngc", [""])[0] == "square.ngc  (loaded)", timeout=WAIT_MS)

    library.confirm = lambda name: name == "broken.ngc"  # the operator says yes to this one
    assert library.select("broken.ngc")
    click(qtbot, screen, library.delete_button)
    qtbot.waitUntil(lambda: set(listed()) == {"square.ngc"}, timeout=WAIT_MS)
    assert not (programs / "broken.ngc").exists()
    shot(w, "auto_library")


def test_continue_cut_part_and_line_are_sent_from_the_auto_page_and_a_refusal_says_why(qtbot, plc_controller, screen,
                                                                                        tmp_path):
    import hashlib

    from cnc.gateway.jobs import CutPoint, CutPoints, jobs_path

    w = screen.window
    take_lock(qtbot, screen)
    click(qtbot, screen, w.bar.auto)
    qtbot.waitUntil(lambda: w.current_screen is Screen.AUTO, timeout=WAIT_MS)
    auto = w.pages[Screen.AUTO]
    assert auto.interrupted.text() == "" and not auto.continue_cut.isEnabled(), "no program: nothing to continue"
    # the job record kept an interrupted cut of this program (a run before a power loss)
    points = CutPoints(jobs_path(plc_controller.history_path))
    points.save(CutPoint(hashlib.sha256(PART.encode()).hexdigest(), "part.ngc", 3, 121.5, 40.25, 7))
    points.close()
    part = tmp_path / "part.ngc"
    part.write_text(PART)
    with qtbot.waitSignal(auto.program.uploaded, timeout=WAIT_MS) as loaded:
        auto.program.load_file(part)
    assert loaded.args[0].ok, loaded.args[0].reason
    qtbot.waitUntil(lambda: auto.interrupted.text() == "Interrupted cut: line 7, at X 121.500  Y 40.250", timeout=WAIT_MS)
    shot(w, "auto_interrupted_cut")
    reply = click(qtbot, screen, auto.continue_cut, ok=False)
    assert "cannot start while IDLE: switch the drives on and home the machine" in reply.reason
    assert w.command_line.text().startswith("✖ Continue the interrupted cut")
    auto.part.setValue(3)
    click(qtbot, screen, auto.start_part, ok=False)
    assert w.command_line.text().startswith("✖ Start at part 3")
    auto.line.setValue(120)
    click(qtbot, screen, auto.start_line, ok=False)
    assert w.command_line.text().startswith("✖ Start at line 120")
