"""The pump pressure followed by the control logic: a set point counts as reached only on a
reading the PLC took after it had the set point, so the floor the tick holds the pump to never
rises above a pressure that is still on its way."""

from __future__ import annotations

import pytest

from cnc.config import PumpConfig
from cnc.logic.pressure import PlcView, PressureWatch

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

PUMP = PumpConfig(cut_pressure_bar=3800.0, pierce_pressure_bar=1200.0, tolerance_bar=150.0, ramp_timeout_s=20.0,
                  drop_bar=600.0)


class Link:
    """The PLC link as the logic sees it: output images sent in full, input images read."""

    def __init__(self) -> None:
        self.sent = 0
        self.inputs = 0
        self.pressure = 0.0

    def view(self) -> PlcView:
        return PlcView(True, self.sent, self.inputs, self.pressure)

    def exchange(self, image: int, pressure: float) -> None:
        """One exchange: read the inputs (the pressure before the write), then write `image`."""
        self.inputs += 1
        self.pressure = pressure
        self.sent = image


def reach(watch: PressureWatch, link: Link, bar: float, image: int, now: float) -> None:
    watch.follow(bar, True, image, link.view(), now)
    link.exchange(image, bar)  # the write; the reading was taken before it
    watch.follow(bar, True, image, link.view(), now)
    link.exchange(image, bar)
    watch.follow(bar, True, image, link.view(), now)
    assert watch.reached_at(bar)


def test_a_stale_reading_at_the_old_pressure_does_not_count_as_the_new_set_point_reached():
    watch, link = PressureWatch(PUMP), Link()
    reach(watch, link, 3800.0, image=1, now=0.0)
    assert watch.floor_bar() == 3200.0
    # the jet closes: low pressure for the next pierce, then the cutting pressure again, both
    # before the PLC has been sent either; every reading still says 3800
    watch.follow(1200.0, True, 2, link.view(), 0.1)
    assert watch.floor_bar() == 600.0, "lowered on purpose: the floor falls with it at once"
    watch.follow(3800.0, True, 3, link.view(), 0.2)
    for _ in range(3):
        watch.follow(3800.0, True, 3, link.view(), 0.3)
    assert not watch.reached_at(3800.0), "a reading from before the PLC had the set point"
    assert watch.floor_bar() == 600.0
    link.exchange(2, 3800.0)  # the PLC gets the low set point; the pump turns down
    watch.follow(3800.0, True, 3, link.view(), 0.4)
    link.exchange(3, 2200.0)  # read at 2200 and falling, then sent the cutting pressure
    watch.follow(3800.0, True, 3, link.view(), 0.5)
    assert not watch.reached_at(3800.0) and watch.floor_bar() == 600.0
    assert watch.fault(2200.0, 0.5) is None, "the pressure on its way is no fault"
    link.exchange(3, 2900.0)  # the first reading taken after the PLC had 3800: rising, not there yet
    watch.follow(3800.0, True, 3, link.view(), 0.6)
    assert not watch.reached_at(3800.0)
    link.exchange(3, 3750.0)
    watch.follow(3800.0, True, 3, link.view(), 0.7)
    assert watch.reached_at(3800.0) and watch.floor_bar() == 3200.0


def test_the_set_point_counts_as_reached_once_read_after_the_write_and_within_tolerance():
    watch, link = PressureWatch(PUMP), Link()
    link.pressure = 1200.0
    watch.follow(1200.0, True, 1, link.view(), 0.0)
    assert not watch.reached_at(1200.0), "the PLC has not been sent the set point"
    link.exchange(1, 1200.0)
    watch.follow(1200.0, True, 1, link.view(), 0.0)
    assert not watch.reached_at(1200.0), "the inputs of that exchange were read before the write"
    link.exchange(1, 1100.0)
    watch.follow(1200.0, True, 1, link.view(), 0.0)
    assert watch.reached_at(1200.0) and not watch.reached_at(3800.0)


def test_a_lost_link_confirms_nothing_and_the_pump_off_forgets_what_was_reached():
    watch, link = PressureWatch(PUMP), Link()
    reach(watch, link, 3800.0, image=1, now=0.0)
    watch.follow(1200.0, True, 2, link.view(), 1.0)
    link.exchange(2, 1200.0)
    link.exchange(2, 1200.0)
    watch.follow(1200.0, True, 2, PlcView(False, link.sent, link.inputs, 1200.0), 1.1)
    assert not watch.reached_at(1200.0), "readings are not trusted while the link is not OK"
    watch.follow(0.0, False, 3, link.view(), 2.0)
    assert watch.floor_bar() == 0.0


def test_a_fall_below_the_floor_and_a_ramp_that_never_arrives_are_faults():
    watch, link = PressureWatch(PUMP), Link()
    reach(watch, link, 3800.0, image=1, now=0.0)
    assert watch.fault(3300.0, 1.0) is None
    assert watch.fault(3100.0, 1.0) == "pressure fell to 3100 bar while cutting at 3800 bar"
    watch.follow(3500.0, True, 2, link.view(), 5.0)
    assert watch.fault(3500.0, 24.0) is None
    assert "did not reach 3500 bar within 20 s" in watch.fault(3500.0, 25.1)
