"""Element limits: axis limits projected on the direction, arcs turning within a share of them."""

from __future__ import annotations

import math

import pytest

from gcode.canon import ARC, LINE

from cnc.planner.limits import LimitCalculator
from cnc.planner.path import Element

from .conftest import machine_config


def element(kind, start, end, center=None, cw=False, feed=math.inf):
    return Element(kind, start, end, center, cw, 0, feed, 0.05, False, 0, 0, 0, 1)


@pytest.fixture
def limits():
    return LimitCalculator(machine_config())


def test_a_move_along_one_axis_gets_that_axis_limits(limits):
    lim = limits.of(element(LINE, (0, 0, 0), (100, 0, 0)))
    assert (lim.velocity, lim.acceleration, lim.jerk) == (500.0, 5000.0, 200000.0)


def test_a_diagonal_may_go_faster_than_either_axis_alone(limits):
    lim = limits.of(element(LINE, (0, 0, 0), (100, 100, 0)))
    assert lim.velocity == pytest.approx(500.0 * math.sqrt(2)) and lim.acceleration == pytest.approx(5000.0 * math.sqrt(2))


def test_the_programmed_feed_caps_the_velocity(limits):
    assert limits.of(element(LINE, (0, 0, 0), (100, 0, 0), feed=40.0)).velocity == 40.0


def test_small_arcs_are_slowed_by_centripetal_acceleration_and_its_jerk(limits):
    big = limits.of(element(ARC, (10, 0, 0), (0, 10, 0), center=(0, 0)))  # R = 10 mm
    assert big.velocity == pytest.approx(min(math.sqrt(0.5 * 5000 * 10), (0.5 * 200000 * 100) ** (1 / 3)))
    assert big.acceleration == 2500.0 and big.jerk == 100000.0
    small = limits.of(element(ARC, (1, 0, 0), (0, 1, 0), center=(0, 0)))  # R = 1 mm
    assert small.velocity < big.velocity
    huge = limits.of(element(ARC, (1000, 0, 0), (0, 1000, 0), center=(0, 0)))
    assert huge.velocity == 500.0, "a gentle arc runs at the axis limit"


def test_a_move_along_an_axis_the_machine_lacks_is_refused_with_its_line(limits):
    with pytest.raises(ValueError, match="line 1: the move runs along Z, an axis the machine lacks"):
        limits.of(element(LINE, (0, 0, 0), (0, 0, 5)))
