"""The servo's own controlled stop: the jerk-limited stop profile and the brake along the queued path."""

from __future__ import annotations

import math
import random

import pytest

from cnc.brake import PathBrake, PathPoint, StopProfile, stop_distance_bound_mm

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

A, J, DT = 5000.0, 200000.0, 0.001


def _sampled(profile: StopProfile, dt: float = 1e-5) -> list[tuple[float, float, float, float]]:
    out, t = [], 0.0
    while t <= profile.duration + dt:
        out.append((t, *profile.at(t)))
        t += dt
    return out


def _check_limits(profile: StopProfile, accel: float = A, jerk: float = J) -> None:
    samples = _sampled(profile)
    for (t0, s0, v0, a0), (t1, s1, v1, a1) in zip(samples, samples[1:]):
        assert all(math.isfinite(x) for x in (s1, v1, a1))
        assert s1 >= s0 - 1e-12, "never backwards"
        assert v1 >= 0.0
        assert abs(a1) <= accel + 1e-6
        if t1 < profile.duration:
            assert abs(a1 - a0) / (t1 - t0) <= jerk * (1 + 1e-6) + 1e-3
    end = profile.at(profile.duration + 1.0)
    assert end == (pytest.approx(profile.distance), 0.0, 0.0), "at rest after the stop"


def test_a_stop_from_full_speed_takes_the_braking_distance_of_the_bound():
    p = StopProfile(500.0, 0.0, A, J)
    assert p.distance == pytest.approx(500.0 ** 2 / (2 * A) + 500.0 * A / (2 * J), rel=1e-12)  # 31.25 mm
    assert p.duration == pytest.approx(500.0 / A + A / J, rel=1e-12)
    _check_limits(p)


def test_a_slow_stop_never_reaches_full_deceleration_and_is_shorter_than_the_bound():
    p = StopProfile(25.0, 0.0, A, J)
    assert p.distance == pytest.approx(25.0 * math.sqrt(25.0 / J), rel=1e-12)
    assert p.distance < 25.0 ** 2 / (2 * A) + 25.0 * A / (2 * J)
    _check_limits(p)


def test_a_stop_that_begins_while_accelerating_first_eases_the_acceleration_off():
    p = StopProfile(300.0, 4000.0, A, J)
    peak = max(v for _, _, v, _ in _sampled(p))
    assert peak == pytest.approx(300.0 + 4000.0 ** 2 / (2 * J), rel=1e-6), "the speed rises while the jerk turns it round"
    _check_limits(p)


def test_a_stop_already_braking_harder_than_needed_ends_at_rest_at_once():
    p = StopProfile(10.0, -A, A, J)  # below the boundary v = a^2 / 2J: the speed reaches 0 before the deceleration does
    assert p.duration < 3 * DT and p.distance < 0.02
    assert p.at(p.duration)[1] == 0.0


def test_random_stops_end_at_rest_within_the_limits():
    rng = random.Random(20261125)
    for _ in range(60):
        v0, a0 = rng.uniform(0.0, 600.0), rng.uniform(-A, A)
        p = StopProfile(v0, a0, A, J)
        if v0 < a0 * a0 / (2 * J) and a0 < 0:
            continue  # the degenerate case above: it ends with a step of the deceleration to 0
        _check_limits(p)
        # accelerating when it begins, the stop first turns the acceleration round (a0 / J), faster all the while
        turn_s, peak = max(a0, 0.0) / J, v0 + max(a0, 0.0) ** 2 / (2 * J)
        assert p.distance <= stop_distance_bound_mm(peak, turn_s, A, J)


def test_the_stop_bound_is_the_detection_run_plus_the_braking_plus_a_millimetre():
    assert stop_distance_bound_mm(500.0, 0.002, A, J) == pytest.approx(1.0 + 25.0 + 6.25 + 1.0)


class _Queue:
    def __init__(self, points: list[PathPoint]) -> None:
        self.points = list(points)

    def next_point(self) -> PathPoint | None:
        return self.points.pop(0) if self.points else None


def _arc_points(radius: float, speed: float, n: int) -> list[PathPoint]:
    """Setpoints 1 ms apart along a circle at `speed`, starting at (radius, 0) counter-clockwise."""
    step = speed * DT / radius
    return [PathPoint((radius * math.cos(k * step), radius * math.sin(k * step)), speed) for k in range(1, n + 1)]


def test_the_brake_follows_the_queued_arc_and_stops_after_the_profiles_distance():
    radius, speed = 40.0, 300.0
    queue = _Queue(_arc_points(radius, speed, 400))
    brake = PathBrake([radius, 0.0], [0.0, speed], 0.0, A, J, DT, queue)
    worst = 0.0
    for _ in range(1000):
        (x, y), v = brake.step()
        worst = max(worst, abs(math.hypot(x, y) - radius))
        if brake.done:
            break
    assert brake.done and v == [0.0, 0.0]
    assert brake.s == pytest.approx(StopProfile(speed, 0.0, A, J).distance, rel=1e-9)
    chord = speed * DT
    assert worst <= chord * chord / (8 * radius) + 1e-9, "on the path, within the chords' sagitta"
    angle = math.atan2(y, x)
    assert angle * radius == pytest.approx(brake.s, rel=1e-4), "the arc length run is the profile's"


def test_where_the_queue_runs_out_the_brake_goes_straight_on():
    queue = _Queue([PathPoint((0.5 * k, 0.0), 500.0) for k in range(1, 5)])  # 2 mm queued
    brake = PathBrake([0.0, 0.0], [500.0, 0.0], 0.0, A, J, DT, queue)
    while not brake.done:
        (x, y), _ = brake.step()
    assert brake.straight and y == 0.0
    assert x == pytest.approx(31.25, rel=1e-9)


def test_a_queued_point_at_rest_ends_the_brake_there():
    """An exact-stop corner: the path turns where the planner came to rest; the brake never passes it."""
    points = [PathPoint((0.1 * k, 0.0), 100.0) for k in range(1, 20)] + [PathPoint((2.0, 0.0), 0.0)]
    points += [PathPoint((2.0, 0.5 * k), 500.0) for k in range(1, 50)]  # the next side of the corner
    brake = PathBrake([0.0, 0.0], [100.0, 0.0], 0.0, A, J, DT, _Queue(points))
    while not brake.done:
        (x, y), _ = brake.step()
    assert brake.s < 2.0 + 1e-9 and y == 0.0
