"""Homing on the simulated board: search the switch, latch the index pulse, set the position, park."""

from __future__ import annotations

import pytest

from cnc.homing import Homing, HomingError, SupervisorPort, home_machine
from cnc.hw.board import AxisIn
from cnc.layout import ServoFault, ServoState
from cnc.supervisor import Supervisor

from .conftest import enable_and_hold, machine_config

# The simulated encoders count from power-up: X's counter reads 0 at machine X123, Y's at Y-7.
SIM = {
    "sim.axes.x.encoder_zero_mm": 123.0, "sim.axes.x.start_position_mm": 31.0,
    "sim.axes.y.encoder_zero_mm": -7.0, "sim.axes.y.start_position_mm": 44.0,
}


def test_homing_puts_every_axis_in_machine_coordinates_and_parks_it():
    config = machine_config(**SIM)
    with Supervisor(config, clock="virtual") as sup:
        unhomed = enable_and_hold(sup)
        assert unhomed == pytest.approx([31.0 - 123.0, 44.0 + 7.0]), "before homing: the counters' frames"
        home_machine(sup)
        s, hw = sup.servo(), sup.hw()
        assert s["homed_mask"] == 0b11 and s["state"] == ServoState.HOLDING and s["fault"] == ServoFault.NONE
        # the table is where the servo says, in machine coordinates: counter frame + its power-up zero
        true_position = [hw["encoder_counts"][0] * 0.001 + 123.0, hw["encoder_counts"][1] * 0.001 - 7.0]
        assert s["actual_mm"] == pytest.approx(true_position, abs=1e-9)
        assert s["underruns"] == 0
        sup.wait_until(
            lambda: all(abs(p - 5.0) < 0.005 for p in sup.servo()["actual_mm"]), 5.0, "the axes to settle at the park position"
        )


def test_homing_starts_by_backing_off_when_the_axis_is_already_on_its_switch():
    config = machine_config(**{**SIM, "sim.axes.x.start_position_mm": -3.0})
    with Supervisor(config, clock="virtual") as sup:
        enable_and_hold(sup)
        assert sup.hw()["axis_inputs"][0] & AxisIn.HOME
        home_machine(sup, ["x"])
        s, hw = sup.servo(), sup.hw()
        assert s["homed_mask"] == 0b01
        assert s["actual_mm"][0] == pytest.approx(hw["encoder_counts"][0] * 0.001 + 123.0, abs=1e-9)


def test_a_missing_home_switch_is_an_error_naming_the_axis():
    config = machine_config(**{**SIM, "axis.x.home_search_velocity_mm_s": 40.0})  # searching the wrong way
    with Supervisor(config, clock="virtual") as sup:
        enable_and_hold(sup)
        port = SupervisorPort(sup)
        try:
            with pytest.raises(HomingError, match="axis X: homing stopped, the servo tripped .HARD_LIMIT.|axis X: the home switch not found"):
                Homing(config, port).home(["x"])
        finally:
            port.close()
        assert not sup.servo()["homed_mask"] & 1


def test_homing_needs_the_drives_on():
    with Supervisor(machine_config(**SIM), clock="virtual") as sup:
        with pytest.raises(HomingError, match="the drives are off"):
            home_machine(sup)
