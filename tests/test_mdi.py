"""MDI: G-code typed by hand runs in MANUAL on a homed machine, from where the head stands, checked
as a program (errors with line and column) and against the travel before anything moves; the jet
opens only where the lines ask and the pump and the interlocks allow; a door closes it in the
tick; stop, hold and the override act on it as on a program. In the whole controller with the
PLC simulator over a real pty, on the virtual clock."""

from __future__ import annotations

from cnc.bus.messages import Hold, Mdi, Override, Pump, Reset, Resume, SetMode, Stop
from cnc.data.layout import PlannerState, ServoFault, ServoState
from cnc.logic.states import MachineState
from cnc.runtime.supervisor import Supervisor

from .conftest import logic, reset_and_home
from .test_logic_process import Events, command, jet_open, refusal


def homed_in_manual(sup: Supervisor) -> None:
    reset_and_home(sup, sup.logic.request)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                   60.0, "homing")


def pump_at_pressure(sup: Supervisor, bar: float = 2000.0) -> None:
    """Pump on at `bar`, until the controller reads that pressure from the PLC (not only the PLC
    simulator: the link delivers it a cycle or two later)."""
    command(sup, Pump(True, pressure_bar=bar))
    index = [v.id for v in sup.config.plc.inputs()].index("pump_pressure")
    plc = sup.area.reader("plc")
    sup.wait_until(lambda: abs(plc.read_dict()["inputs"][index] - bar) < 50, 20.0, f"the controller to read {bar:g} bar")


def at_rest(sup: Supervisor) -> bool:
    return (logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE
            and sup.servo()["state"] == ServoState.HOLDING)


def head(sup: Supervisor) -> tuple[float, float]:
    x, y = sup.servo()["commanded_mm"][:2]
    return round(float(x), 3), round(float(y), 3)


def run_mdi(sup: Supervisor, text: str) -> list[int]:
    """Send `text`, insist it is accepted, wait until it has run; the machine states seen meanwhile."""
    seen = []
    command(sup, Mdi(text))
    sup.wait_until(lambda: seen.append(logic(sup)["state"]) or (MachineState.MDI in seen and at_rest(sup)), 60.0,
                   f"the MDI {text!r} to run")
    # the planner ends the run when the FIFO is empty: the servo's block may still be the tick before
    # the last setpoint's; a few ticks more and it has taken every one
    tick = sup.servo()["tick"]
    sup.wait_until(lambda: sup.servo()["tick"] > tick + 3 and at_rest(sup), 20.0, "the servo past the last setpoint")
    return seen


def test_mdi_runs_typed_lines_from_where_the_head_stands_and_stop_and_hold_end_it_on_the_path(plc_controller):
    sup = plc_controller
    homed_in_manual(sup)
    seen = run_mdi(sup, "G21 G90 G0 X50 Y40\nG1 X60 F3000")
    assert MachineState.MDI in seen, "the machine says MDI while the lines run"
    assert head(sup) == (60.0, 40.0)
    run_mdi(sup, "G91 G1 X-5 Y7.5 F3000")  # incremental from where the head now is
    assert head(sup) == (55.0, 47.5)
    assert sup.motion()["run_result"] == 0, "an MDI is not a program run: nothing for the job history"
    for stop, target in ((Stop(), 1000.0), (Hold(), 1500.0)):
        start = head(sup)[0]
        command(sup, Mdi(f"G1 X{target:g} F3000"))
        sup.wait_until(lambda: abs(sup.servo()["commanded_mm"][0] - start) > 5.0, 30.0, "the MDI to move")
        command(sup, stop)
        sup.wait_until(lambda: at_rest(sup), 30.0, f"the MDI to end after a {type(stop).__name__.lower()}")
        assert abs(head(sup)[0] - target) > 1.0 and abs(head(sup)[0] - start) > 5.0, "ended on the way, not at the end"
        assert sup.servo()["fault"] == ServoFault.NONE, "a controlled stop, no trip"


def test_mdi_is_refused_with_the_reason_and_nothing_moves(plc_controller):
    sup = plc_controller
    why = refusal(sup, Mdi("G0 X10"))
    assert "switch the drives on and home the machine" in why, why
    homed_in_manual(sup)
    before = head(sup)

    reply = sup.logic.request(Mdi("G0 X10\nG1 X20 Q5 F100"))
    assert not reply.ok and reply.errors, reply
    diag = reply.errors[0]
    assert (diag.line, diag.column) == (2, 8) and "Q word" in diag.message, diag  # the Q, on line 2
    assert reply.reason.startswith("MDI:2:8:"), reply.reason

    y_max = sup.config.axis["y"].travel_max_mm
    why = refusal(sup, Mdi(f"G0 X10\nG1 Y{y_max + 50:g} F1000"))
    assert "MDI:2" in why and "Y" in why, why
    assert "M0" in refusal(sup, Mdi("G0 X10\nM0\nG0 X20"))
    assert "still running" in refusal(sup, Mdi("O100 while [1]\nO100 endwhile")), "an endless loop typed by hand"
    command(sup, SetMode("AUTO"))
    assert "MANUAL" in refusal(sup, Mdi("G0 X10"))
    command(sup, SetMode("MANUAL"))
    assert head(sup) == before and sup.motion()["state"] == PlannerState.IDLE, "nothing moved"
    assert command(sup, Mdi("G21 G90 (nothing to move)")).startswith("nothing to move")


def test_mdi_opens_the_jet_only_where_the_lines_ask_and_the_pump_allows_and_the_override_holds_it(plc_controller):
    sup = plc_controller
    homed_in_manual(sup)
    jetted = "G0 X40 Y40\nM3\nG1 X60 F1200\nM5\nG0 X30"
    why = refusal(sup, Mdi(jetted))
    assert "MDI:3: the jet would be open" in why and "switch the pump on" in why, why  # the first move with the jet
    assert not jet_open(sup) and sup.motion()["state"] == PlannerState.IDLE

    pump_at_pressure(sup)
    opened = []
    command(sup, Mdi(jetted))
    sup.wait_until(lambda: opened.append((jet_open(sup), head(sup)[0])) or (len(opened) > 5 and at_rest(sup)), 60.0,
                   "the MDI with the jet to run")
    xs_with_jet = [x for on, x in opened if on]
    assert xs_with_jet, "the jet opened where the lines asked"
    assert min(xs_with_jet) >= 40.0 - 1e-6 and max(xs_with_jet) <= 60.0 + 1e-6, "and only there"
    assert not jet_open(sup) and head(sup) == (30.0, 40.0)

    run_mdi(sup, "G0 X45 Y45")
    assert not jet_open(sup), "lines that do not ask for the jet never open it"

    # the feed override at 0 % holds a cut by hand and closes the jet; resume pierces and finishes it
    y = head(sup)[1]
    command(sup, Mdi("M3\nG1 X200 F2400\nM5\nG0 X50"))
    sup.wait_until(lambda: jet_open(sup) and sup.servo()["commanded_mm"][0] > 40.0, 30.0, "cutting by hand")
    command(sup, Override(0.0))
    sup.wait_until(lambda: not jet_open(sup) and sup.servo()["state"] == ServoState.HOLDING
                   and max(map(abs, sup.servo()["commanded_velocity_mm_s"])) == 0.0, 30.0, "held, the jet closed")
    held_at = head(sup)[0]
    assert 40.0 < held_at < 200.0 and logic(sup)["state"] == MachineState.MDI
    assert "0 %" in refusal(sup, Resume())
    command(sup, Override(100.0))
    command(sup, Resume())
    sup.wait_until(lambda: at_rest(sup), 60.0, "the MDI to finish")
    assert head(sup) == (50.0, y) and not jet_open(sup)
    command(sup, Override(0.0))
    assert "0 %" in refusal(sup, Mdi("G0 X60"))
    command(sup, Override(100.0))
    command(sup, Pump(False))


def test_a_door_opened_during_an_mdi_with_the_jet_closes_it_in_the_tick(plc_controller):
    sup = plc_controller
    events = Events(sup)
    homed_in_manual(sup)
    pump_at_pressure(sup)
    command(sup, Mdi("M3\nG1 X250 F3000\nM5"))
    sup.wait_until(lambda: jet_open(sup) and sup.servo()["commanded_mm"][0] > 40.0, 30.0, "cutting by hand")
    start = sup.pause_virtual_clock()
    sup.set_sim(doors_open=1)
    jet_off_at = None
    for _ in range(50):
        tick = sup.run_ticks(1)
        if not jet_open(sup):
            jet_off_at = tick
            break
    sup.resume_virtual_clock()
    assert jet_off_at is not None and jet_off_at - start <= 2, "the jet closed within a tick of the door"
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT and sup.motion()["state"] == PlannerState.IDLE,
                   30.0, "the controlled stop")
    assert sup.servo()["fault"] == ServoFault.DOORS and sup.servo()["brake_distance_mm"] > 0.0
    sup.wait_until(lambda: 2292 in events.codes(), 5.0, "the door alarm")
    sup.set_sim(doors_open=0)
    sup.wait_until(lambda: 2292 in events.codes("cleared"), 5.0, "the door alarm to clear")
    command(sup, Reset())
    sup.wait_until(lambda: at_rest(sup), 20.0, "READY after the reset")
    events.close()
