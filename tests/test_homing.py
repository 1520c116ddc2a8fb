"""Homing through the planner on the simulated board: search the switch, latch the index pulse, set the position, park."""

from __future__ import annotations

import pytest

from cnc.bus.messages import Home, Stop
from cnc.config import ConfigError
from cnc.hw.board import AxisIn
from cnc.data.layout import PlannerState, ServoFault, ServoState
from cnc.runtime.supervisor import MOTION_ONLY, Supervisor

from .conftest import ask, enable_and_hold, home, machine_config, wait_planner_idle

# The simulated encoders count from power-up: X's counter reads 0 at machine X123, Y's at Y-7.
SIM = {
    "sim.axes.x.encoder_zero_mm": 123.0, "sim.axes.x.start_position_mm": 31.0,
    "sim.axes.y.encoder_zero_mm": -7.0, "sim.axes.y.start_position_mm": 44.0,
}


def test_homing_puts_every_axis_in_machine_coordinates_and_parks_it():
    config = machine_config(**SIM)
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        unhomed = enable_and_hold(sup)
        assert unhomed == pytest.approx([31.0 - 123.0, 44.0 + 7.0]), "before homing: the counters' frames"
        home(sup)
        sup.pause_virtual_clock()  # read the servo and the board at the same tick
        s, hw = sup.servo(), sup.hw()
        assert s["homed_mask"] == 0b11 and s["fault"] == ServoFault.NONE
        # the table is where the servo says, in machine coordinates: counter frame + its power-up zero
        true_position = [hw["encoder_counts"][0] * 0.001 + 123.0, hw["encoder_counts"][1] * 0.001 - 7.0]
        assert s["actual_mm"] == pytest.approx(true_position, abs=1e-9)
        assert s["underruns"] == 0
        sup.resume_virtual_clock()
        sup.wait_until(
            lambda: all(abs(p - 5.0) < 0.005 for p in sup.servo()["actual_mm"]), 5.0, "the axes to settle at the park position"
        )
        assert sup.servo()["state"] == ServoState.HOLDING


def test_homing_starts_by_backing_off_when_the_axis_is_already_on_its_switch():
    config = machine_config(**{**SIM, "sim.axes.x.start_position_mm": -3.0})
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        assert sup.hw()["axis_inputs"][0] & AxisIn.HOME
        home(sup, ["x"])
        sup.pause_virtual_clock()
        s, hw = sup.servo(), sup.hw()
        assert s["homed_mask"] == 0b01
        assert s["actual_mm"][0] == pytest.approx(hw["encoder_counts"][0] * 0.001 + 123.0, abs=1e-9)


def test_a_missing_home_switch_is_reported_naming_the_axis_and_nothing_is_homed():
    # searching the wrong way, from near the far end of the travel (the limit switch comes soon)
    config = machine_config(**{**SIM, "axis.x.home_search_velocity_mm_s": 40.0, "sim.axes.x.start_position_mm": 1560.0})
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        ask(sup, Home(["x"]))
        m = wait_planner_idle(sup)
        # the search runs onto the limit switch: the servo trips (its commander reports the trip) and
        # the planner says why the homing ended
        assert "axis X" in m["error"] and ("HARD_LIMIT" in m["error"] or "home switch not found" in m["error"])
        assert not sup.servo()["homed_mask"] & 1


def test_homing_is_refused_with_the_drives_off_or_an_unknown_axis():
    with Supervisor(machine_config(**SIM), clock="virtual", processes=MOTION_ONLY) as sup:
        reply = sup.planner.request(Home())
        assert not reply.ok and "the drives are not enabled" in reply.reason
        enable_and_hold(sup)
        reply = sup.planner.request(Home(["q"]))
        assert not reply.ok and "no axis 'q'" in reply.reason


def test_stopping_a_homing_brings_the_axis_to_rest_and_reports_it():
    with Supervisor(machine_config(**SIM), clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        sup.pause_virtual_clock()
        ask(sup, Home(["x"]))
        sup.run_ticks(400)  # searching at 20 mm/s
        assert sup.motion()["state"] == PlannerState.HOMING and abs(sup.servo()["commanded_velocity_mm_s"][0]) > 10.0
        ask(sup, Stop())
        sup.run_ticks(600)
        s = sup.servo()
        assert s["state"] == ServoState.HOLDING and s["commanded_velocity_mm_s"][0] == 0.0 and s["underruns"] == 0
        m = sup.motion()
        assert m["state"] == PlannerState.IDLE and "stopped by the operator" in m["error"] and not s["homed_mask"]
        # the control logic's own stop (a safe stop) says its cause, not the operator
        ask(sup, Home(["x"]))
        sup.run_ticks(400)
        ask(sup, Stop(reason="safe stop: estop: the e-stop is pressed"))
        sup.run_ticks(600)
        m = sup.motion()
        assert m["state"] == PlannerState.IDLE and m["error"] == "homing stopped: safe stop: estop: the e-stop is pressed"


def test_a_safe_stop_during_homing_is_reported_with_its_cause_not_as_the_operator(plc_controller):
    from cnc.alarms import AlarmHistory

    from .conftest import reset_and_home

    sup = plc_controller
    reset_and_home(sup, sup.logic.request)
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.HOMING, 30.0, "the homing under way")
    sup.set_sim(estop_pressed=1)
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE and sup.motion()["error"], 30.0, "the homing ended")
    error = sup.motion()["error"]
    # whichever the planner sees first, the servo's trip or the logic's safe stop, it names the e-stop
    assert "operator" not in error and ("homing stopped: safe stop: estop" in error or "(ESTOP)" in error), error

    def entries() -> list:
        with AlarmHistory(sup.history_path, readonly=True) as history:
            return history.query(limit=50).entries
    sup.wait_until(lambda: any(e.id == "estop" for e in entries()), 10.0, "the e-stop in the alarm history")
    if error.startswith("homing stopped"):  # the logic's stop came first: its record names the cause
        sup.wait_until(lambda: any(error in e.detail for e in entries()), 10.0, "the homing's end in the alarm history")
    assert not [e.detail for e in entries() if "by the operator" in e.detail]


@pytest.mark.parametrize("divisor, low_ms, high_ms", [(5, 41.0, 62.0), (10, 88.5, 228.5)])
def test_a_planner_waking_every_20_or_40_ms_homes_without_running_the_fifo_dry(divisor, low_ms, high_ms):
    """250 Hz, the planner every 5th tick (20 ms): a FIFO refilled below 10 ms ran dry while homing
    (the servo tripped: FIFO underrun), and the machine file took it; now fifo_low_ms must be more than
    two planner periods (`test_config`), and homing keeps that much in the FIFO too. Every 10th tick
    (40 ms): homing pushed one 20 ms chunk a wake, half of what ran meanwhile, and ran dry; it now
    pushes chunks until the FIFO holds its lead."""
    with pytest.raises(ConfigError, match=r"\[planner\] fifo_low_ms: 10 ms must be more than twice the planner's period"):
        machine_config(**SIM, **{"timing.base_rate_hz": 250.0, "planner.fifo_low_ms": 10.0, "planner.fifo_high_ms": 100.0})
    config = machine_config(**SIM, **{"timing.base_rate_hz": 250.0, "planner.divisor": divisor,
                                      "planner.fifo_low_ms": low_ms, "planner.fifo_high_ms": high_ms})
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        home(sup)
        s = sup.servo()
        assert s["homed_mask"] == 0b11 and s["fault"] == ServoFault.NONE and s["underruns"] == 0


@pytest.mark.parametrize("lead_ms", [(20.0, 40.0), (300.0, 600.0), (2000.0, 4000.0)])
def test_homing_sees_its_switch_within_a_chunk_whatever_the_fifo_lead(lead_ms):
    """Homing pushes its search in chunks of 20 ms and looks at the switches between them. It used
    to push the next chunk whenever the FIFO held less than `[planner] fifo_low_ms`: with the
    lead a busy real-time host needs (300 ms), the search ran 300 ms past the home switch, into
    the hard limit (found where the two-hosts test deepened its FIFO)."""
    low, high = lead_ms
    config = machine_config(**SIM, **{"planner.fifo_low_ms": low, "planner.fifo_high_ms": high})
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        home(sup)
        s = sup.servo()
        assert s["homed_mask"] == 0b11 and s["fault"] == ServoFault.NONE and s["underruns"] == 0
