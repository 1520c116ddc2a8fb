"""Jerk-limited motion along a section: limits held at every period, no stop-and-go, exact stop."""

from __future__ import annotations

import random

import numpy as np
import pytest

from cnc.planner.profile import SectionMotion, Zone, braking_distance

DT, A, J = 0.001, 5000.0, 200000.0


def check(samples: np.ndarray, zones: list[Zone]) -> None:
    s, v, a = samples[:, 0], samples[:, 1], samples[:, 2]
    assert np.isfinite(samples).all()
    assert s[-1] == pytest.approx(zones[-1].end_mm, abs=1e-9) and abs(v[-1]) < 1e-9, "at rest exactly at the end"
    assert (np.diff(s) >= -1e-12).all(), "never backwards"
    assert (np.abs(a) <= A * (1 + 1e-9)).all()
    jerk = np.diff(np.concatenate(([0.0], a))) / DT
    assert (np.abs(jerk) <= J * (1 + 1e-6)).all()
    starts = np.array([z.start_mm for z in zones])
    limit = np.array([z.v_max_mm_s for z in zones])[np.maximum(np.searchsorted(starts, s, side="right") - 1, 0)]
    assert (v <= limit * (1 + 1e-9) + 1e-9).all(), "within the limit of the zone it is in"


def test_a_long_line_accelerates_cruises_and_stops_exactly_at_its_end():
    zones = [Zone(0.0, 300.0, 500.0)]
    samples = SectionMotion(zones, A, J, DT).run()
    check(samples, zones)
    assert samples[:, 1].max() == pytest.approx(500.0)


def test_a_slow_zone_is_entered_at_its_speed_and_left_at_once():
    zones = [Zone(0.0, 100.0, 500.0), Zone(100.0, 110.0, 50.0), Zone(110.0, 300.0, 500.0)]
    samples = SectionMotion(zones, A, J, DT).run()
    check(samples, zones)
    in_slow = (samples[:, 0] >= 100.0) & (samples[:, 0] < 110.0)
    assert samples[in_slow, 1].max() <= 50.0 + 1e-9 and samples[:, 1].max() == pytest.approx(500.0)


def test_a_cam_polyline_runs_at_speed_without_stop_and_go():
    rng = random.Random(2)
    edges = np.cumsum([0.0] + [rng.uniform(0.2, 1.5) for _ in range(400)])
    zones = [Zone(float(a), float(b), 300.0) for a, b in zip(edges[:-1], edges[1:])]
    samples = SectionMotion(zones, A, J, DT).run()
    check(samples, zones)
    middle = (samples[:, 0] > 60.0) & (samples[:, 0] < edges[-1] - 60.0)
    assert samples[middle, 1].min() == pytest.approx(300.0), "full speed across hundreds of element boundaries"


@pytest.mark.parametrize("seed", range(25))
def test_seeded_random_sections_keep_every_limit_and_end_at_rest(seed):
    rng = random.Random(seed)
    edges = np.cumsum([0.0] + [rng.choice([rng.uniform(0.1, 2.0), rng.uniform(5.0, 60.0)]) for _ in range(60)])
    zones = [Zone(float(a), float(b), rng.choice([20.0, 80.0, 250.0, 500.0])) for a, b in zip(edges[:-1], edges[1:])]
    check(SectionMotion(zones, A, J, DT).run(), zones)


def test_braking_distance_is_never_short():
    # against a fine simulation of the same jerk-limited stop
    for v0, a0, v1 in [(500.0, 0.0, 0.0), (300.0, 2000.0, 50.0), (100.0, -3000.0, 0.0), (20.0, 0.0, 10.0)]:
        from ruckig import ControlInterface, InputParameter, Result, Ruckig, Trajectory

        inp, traj = InputParameter(1), Trajectory(1)
        inp.control_interface = ControlInterface.Velocity
        inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [v0], [a0]
        inp.target_velocity, inp.target_acceleration = [v1], [0.0]
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = [1e6], [A], [J]
        assert Ruckig(1).calculate(inp, traj) in (Result.Working, Result.Finished)
        real = traj.at_time(traj.duration)[0][0]
        assert braking_distance(v0, a0, v1, A, J) >= real - 1e-9, (v0, a0, v1)
