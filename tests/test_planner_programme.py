"""Corners passed by a programmed connection: the samples through a gentle corner solved for at once
(`cnc/planner/programme.py`).

Each test runs a program through the real interpreter and the planner's runner and measures the
setpoint records the servo would get: every axis within its limits, every record within G64 P of
the program, the planned cycle time the one run; the corners solved ahead by the planner's worker
give the very records the refill would have made itself; an operator's control in a programmed
connection acts when it ends.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from gcode.canon import LINE
from gcode.interp import interpret

from cnc.config import ConfigError
from cnc.machine_dialect import dialect_for
from cnc.planner import programme
from cnc.planner.runner import ProgramRunner, RunState

from .conftest import machine_config
from .test_planner_motion import LIMITS, run, speed, within_limits, within_tolerance
from .test_planner_overlap import CONTROLS, control_after_committed

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

NO_PROGRAMME = {"planner.corner_programme_ms": 0.0}
LEG_MM = 50.0


def zigzag(interior_deg: tuple[float, ...], feed: float, p: float = 0.05, origin=(600.0, 400.0)) -> str:  # noqa: ANN001
    """Straight legs of LEG_MM meeting at the given interior angles, turning left and right in turn."""
    heading, (x, y) = 0.0, origin
    lines = ["G21 G90 G17 G64 P%g" % p, f"G0 X{x:.4f} Y{y:.4f}", f"F{feed:g}"]
    for k, angle in enumerate((*interior_deg, None)):
        x, y = x + LEG_MM * math.cos(heading), y + LEG_MM * math.sin(heading)
        lines.append(f"G1 X{x:.4f} Y{y:.4f}")
        if angle is not None:
            heading += (-1) ** k * math.radians(180 - angle)
    return "\n".join(lines + ["M2", ""])


ZIGZAG = zigzag((30, 60, 90, 120, 150), 12000.0)
GENTLE = zigzag((150,), 12000.0)  # one turn of 30 degrees: the overlap saves 2 periods there, a programme about 50


@functools.lru_cache(maxsize=None)
def _run(text: str, programmes: bool, chunk: int = 50):  # noqa: ANN202 - (program, runner, records, planned)
    program, runner, records, planned = run(text, machine_config(**({} if programmes else NO_PROGRAMME)), chunk=chunk)
    records.flags.writeable = False
    return program, runner, records, planned


def _corner_speed(records, corner: tuple[float, float]) -> float:
    """The head's lowest speed within 0.5 mm of a corner."""
    near = np.hypot(*(records["position"][:, :2] - np.asarray(corner)).T) < 0.5
    return float(speed(records)[near].min())


@pytest.mark.parametrize("feed", [12000.0, 30000.0])
def test_gentle_corners_between_long_lines_are_passed_sooner_within_every_limit_and_p(feed):
    """The zigzag's corners (30 to 150 degrees inside) are programmed: the program runs sooner by
    well over a hundred periods, every axis within its limits, every record within P, the planned
    cycle time the one run, ending at the program's end."""
    text = zigzag((30, 60, 90, 120, 150), feed)
    program, _, records, planned = _run(text, True)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned, "the planned cycle time counts the programmed corners"
    assert records["position"][-1, :2] == pytest.approx(program.segments["end"][-1][:2], abs=1e-9)
    _, _, plain, plain_planned = _run(text, False)
    assert len(plain) == plain_planned
    assert len(plain) - len(records) >= 100, "sooner by a tenth of a second and more"


def test_a_programmed_corner_is_passed_at_speed_where_the_overlap_all_but_stops():
    """At a 30 degree turn between two 50 mm lines at 200 mm/s the overlap is held to a couple of
    periods by the axes' jerks and the head nearly stops; the programmed connection passes it at
    about half the feed, within P, the next line joined where it speeds up."""
    program, _, records, _ = _run(GENTLE, True)
    corner = tuple(program.segments["end"][-2][:2])
    _, _, plain, _ = _run(GENTLE, False)
    assert _corner_speed(plain, corner) < 20.0
    assert _corner_speed(records, corner) > 80.0
    assert len(plain) - len(records) >= 40


def test_corners_solved_ahead_by_the_worker_give_the_records_the_refill_would_make():
    """The planner's worker solves the corners ahead (`solve_ahead`, away from the refills) on
    sections of its own: the refill then solves none itself, and the records are the ones a runner
    solving every corner where it meets it makes, to rounding."""
    program, _, alone, _ = _run(ZIGZAG, True, chunk=7)
    config = machine_config()
    runner = ProgramRunner(interpret(ZIGZAG, dialect_for(config)), config)
    runner.solves_ahead = True
    made, solved = [], 0
    while not runner.finished:
        runner.build_ahead()
        solved += runner.solve_ahead()
        made.append(runner.take(7)[0])
    records = np.concatenate(made)
    assert solved == 6 and runner.book.solved_here == 0  # the rapid into the first line, and the five turns
    assert len(records) == len(alone)
    assert np.abs(records["position"] - alone["position"]).max() <= 1e-9


def test_a_corner_the_worker_has_not_reached_in_time_is_passed_by_the_planners_own_plan():
    """With a worker promised but never running (a host too busy for it), the refill leaves each
    corner undecided while it can, then passes it by the planner's own plan: it never solves one
    itself (tens of milliseconds against the FIFO's 20 of slack). The records are those of a run
    without programmes, every limit and P kept."""
    program, _, plain, _ = _run(ZIGZAG, False, chunk=7)
    config = machine_config()
    runner = ProgramRunner(interpret(ZIGZAG, dialect_for(config)), config)
    runner.solves_ahead = True
    made = []
    while not runner.finished:
        made.append(runner.take(7)[0])
    records = np.concatenate(made)
    assert runner.book.solved_here == 0 and runner.book.late == 6
    assert len(records) == len(plain) and np.abs(records["position"] - plain["position"]).max() <= 1e-9
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()


def test_a_corner_met_again_elsewhere_is_not_solved_again(monkeypatch):
    """The same corner at another place of the program (a nest's parts) takes the first one's
    solution, checked again on its own samples: one solve in each walk of the program (the
    timing's, the run's), both corners passed at speed, the planned time the run's."""
    calls = []  # the turns between two lines solved (the rapids' corners differ from place to place)
    solved = programme._solved
    monkeypatch.setattr(programme, "_solved", lambda corners, corner, p, j: calls.append(
        all(e.kind == LINE for e in corner.near)) or solved(corners, corner, p, j))
    # each copy between two dwells, as a part between its pierce and the jet closing: the rapids into
    # and out of it (which would move its ends outward, `sections._move_stop_corners`) do not shape it
    once, again = (zigzag((150,), 12000.0, origin=(600.0, y)).replace("F12000", "G4 P0.1\nF12000")
                   .replace("M2\n", "G4 P0.1\n") for y in (400.0, 600.0))
    program, _, records, planned = run(once + again.split("\n", 1)[1] + "M2\n", machine_config(), chunk=50)
    assert sum(calls) == 2, "solved once by the timing and once by the run, each taking the second from the first"
    assert len(records) == planned
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    corners = [(650.0, 400.0), (650.0, 600.0)]  # the turn of each copy
    assert all(_corner_speed(records, c) > 80.0 for c in corners)


@pytest.mark.parametrize("into", [2, 30])
@pytest.mark.parametrize("control", list(CONTROLS))
def test_a_control_in_a_programmed_connection_acts_when_it_ends_and_every_limit_holds(control, into):
    """A programmed connection's samples are committed, as any connection's: they come out as in a
    run without the control, then the next line's motion obeys it: a hold, a stop or 0 % bring the
    head to rest on that line within the braking distance of its speed from the connection's end
    on; 10 % and 200 % go on to the program's end. The ETA counts the connection's samples left."""
    program, _, undisturbed, _ = _run(GENTLE, True, chunk=1)
    config = machine_config()
    runner = ProgramRunner(interpret(GENTLE, dialect_for(config)), config)
    made = []
    while not (runner.connecting and runner.index == 2):  # steps: the rapid, the first line, the second
        made.append(runner.take(1)[0])
    made.append(runner.take(into)[0])
    given, left = sum(len(m) for m in made), runner.overlap_left
    assert left > 0 and runner.connecting
    assert into + left > 60, "a programmed connection: longer than the planner's own (60 ms)"
    # the ETA to the record (the newest sample made waits for the next one, as everywhere)
    assert runner.remaining_s() == pytest.approx((len(undisturbed) - given - 1) * 0.001, abs=1e-9)
    records, shared = control_after_committed(runner, control, made, program, undisturbed, given + left)
    v = speed(records)
    end_of_program = program.segments["end"][-1][:2]
    if control in ("hold", "stop", "override 0"):
        assert v[-1] == 0.0
        assert runner.state == {"hold": RunState.HELD, "stop": RunState.ABORTED, "override 0": RunState.RUNNING}[control]
        start, end = np.asarray(program.segments["end"][-2][:2]), np.asarray(end_of_program)
        at = records["position"][-1, :2]
        d, r = end - start, at - start
        across = abs(d[0] * r[1] - d[1] * r[0]) / np.linalg.norm(d)
        assert across <= 0.05 + 1e-9, "at rest on the last line"
        travelled = float(np.hypot(*np.diff(records["position"][shared:], axis=0).T).sum())
        peak, a, j = float(v[shared:].max()), LIMITS["acceleration"], LIMITS["jerk"]
        # the line is speeding up: a hold lets the acceleration run out first, then brakes
        assert travelled <= peak * (a / j + 5 * 0.001) + peak * peak / (2.0 * a) + peak * a / (2.0 * j)
    else:
        assert runner.state == RunState.DONE
        assert records["position"][-1, :2] == pytest.approx(end_of_program, abs=1e-9)


def test_a_hold_before_a_corner_falls_back_to_the_planners_own_plan_there():
    """Held and resumed on the line before a corner, the motion is replanned from where it stood:
    the corner's programme was solved for other samples, so the refill passes it by the planner's
    own plan rather than solving it again, within every limit and P, to the program's end."""
    config = machine_config()
    program = interpret(GENTLE, dialect_for(config))
    runner = ProgramRunner(program, config)
    runner.solves_ahead = True
    made = []
    while runner.s_program < 20.0:
        runner.build_ahead()
        runner.solve_ahead()
        made.append(runner.take(5)[0])
    runner.hold()
    while runner.state != RunState.HELD:
        made.append(runner.take(5)[0])
    runner.resume()
    while not runner.finished:
        runner.solve_ahead()
        made.append(runner.take(5)[0])
    records = np.concatenate(made)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert runner.book.solved_here == 0
    assert records["position"][-1, :2] == pytest.approx(program.segments["end"][-1][:2], abs=1e-9)


@pytest.mark.parametrize("control", ["override 0", "hold", "stop"])
def test_nothing_is_solved_ahead_while_the_motion_stands_or_ends(control):
    """At 0 % override, held or stopping, the worker solves nothing (a section planned at 0 %
    would never end) and makes no mark: the corners are solved once the motion goes on."""
    config = machine_config()
    runner = ProgramRunner(interpret(GENTLE, dialect_for(config)), config)
    runner.take(10)
    runner.build_ahead()
    CONTROLS[control](runner)
    assert runner.solve_ahead(5) == 0
    assert not runner.book.solved(runner.index, runner.override)
    if control == "override 0":
        runner.set_override(1.0)
        assert runner.solve_ahead(5) == 2  # the rapid into the first line, and the turn


def test_corner_programme_ms_is_checked_and_zero_turns_programmes_off():
    with pytest.raises(ConfigError, match=r"corner_programme_ms"):
        machine_config(**{"planner.corner_programme_ms": -1.0})
    with pytest.raises(ConfigError, match=r"corner_programme_ms"):
        machine_config(**{"planner.corner_programme_ms": 500.0})
    assert machine_config().planner.corner_programme_ms == 120.0
    _, runner, _, _ = _run(GENTLE, False)
    assert runner.book.solved_here == 0


# A lead-out and the rapid after it (of a random CAM part) on a machine whose Y has a jerk of 1000 mm/s³, at
# a 0.25 ms servo period: its programmes' coefficients go down to 1e-10, and HiGHS's simplex cycled for ever on
# one of them (the planner hung in the program's timing, at load)
BADLY_SCALED = {"timing.base_rate_hz": 4000.0, "planner.corner_connection_ms": 120.0, "planner.corner_programme_ms": 200.0,
                "axis.x.max_velocity_mm_s": 50.0, "axis.x.max_accel_mm_s2": 1e6, "axis.y.max_accel_mm_s2": 1e6,
                "axis.y.max_jerk_mm_s3": 1000.0}
CYCLING = "G21 G90 G64 P0.2\nG0 X-0.4494 Y2.8786\nG1 X-2.2492 Y1.4110 F300\nG0 X-29.1008 Y-6.0562\nM2\n"


def _runs_clean_counting_statuses(monkeypatch, text: str, config) -> list[int]:  # noqa: ANN001 - a MachineConfig
    """`text` run on `config` keeps every axis limit and P, and its timing is the run's; the status
    of every programme solved (0 feasible, 1 at the iteration limit, 2 infeasible)."""
    from cnc.planner.measure import peaks
    from cnc.planner.steps import ProgramTiming

    statuses: list[int] = []
    milp, constraint = programme.load_solver()

    def counted(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202 - milp's own arguments and result
        result = milp(*args, **kwargs)
        statuses.append(int(result.status))
        return result

    monkeypatch.setattr(programme, "load_solver", lambda: (counted, constraint))
    program, runner, records, planned = run(text, config)
    assert len(records) == planned == ProgramTiming.of(program, config).total_ticks
    assert runner.book.solved_here > 0
    assert (within_tolerance(program, records) <= 1e-9).all()
    pk = peaks(records["position"], config.timing.period_s)
    for name, key in (("velocity", "velocity_mm_s"), ("acceleration", "accel_mm_s2"), ("jerk", "jerk_mm_s3")):
        limit = [getattr(config.axis[a], f"max_{key}") for a in "xy"]
        assert (pk[name] <= np.asarray(limit) * (1 + 1e-6)).all(), f"{name} {pk[name]} over {limit}"
    return statuses


def test_a_programme_the_simplex_would_cycle_on_ends_and_the_run_is_its_timing(monkeypatch):
    """Each programme gets `programme.ITERATIONS` simplex iterations per row and column: with HiGHS
    1.12 one of this corner's programmes reaches them (it cycled for ever before) and counts as
    infeasible."""
    statuses = _runs_clean_counting_statuses(monkeypatch, CYCLING, machine_config(**BADLY_SCALED))
    assert statuses and set(statuses) <= {0, 1, 2}


def test_a_programme_stopped_at_its_iteration_limit_counts_as_infeasible_alike_in_timing_and_run(monkeypatch):
    """The limit is a count, not a time: programmes cut short by it (here all but the easiest, the
    limit made tiny) leave the corner to a longer programme or the planner's own plan, the same in
    the program's timing and in the run."""
    monkeypatch.setattr(programme, "ITERATIONS", 0.3)
    statuses = _runs_clean_counting_statuses(monkeypatch, ZIGZAG, machine_config())
    assert 1 in statuses, "programmes stopped at the limit"


def _random_polyline(seed: int) -> tuple[str, float]:
    """Long straight legs at random turns, feeds and tolerances: where corners are programmed."""
    rng = np.random.default_rng(seed)
    feed, p = float(rng.choice([6000.0, 12000.0, 18000.0, 30000.0])), float(rng.choice([0.01, 0.02, 0.05, 0.1]))
    x, y, heading = 600.0, 500.0, float(rng.uniform(0.0, 2.0 * math.pi))
    lines = [f"G21 G90 G17 G64 P{p:g}", f"G0 X{x:.4f} Y{y:.4f}", f"F{feed:g}"]
    for _ in range(6):
        length = float(rng.uniform(30.0, 120.0))
        x, y = x + length * math.cos(heading), y + length * math.sin(heading)
        lines.append(f"G1 X{x:.4f} Y{y:.4f}")
        heading += float(rng.choice([-1.0, 1.0]) * math.radians(rng.uniform(10.0, 170.0)))
    return "\n".join(lines + ["M2", ""]), p


@pytest.mark.parametrize("seed", range(8))
def test_random_polylines_keep_every_limit_and_p_and_time_exactly_with_programmed_corners(seed):
    """Random long-legged polylines (turns of 10 to 170 degrees, 100 to 500 mm/s, P 0.01 to 0.1):
    wherever corners are programmed, every axis keeps its limits, every record P, the run ends at
    the program's end and takes the planned periods, and never longer than without programmes."""
    text, _ = _random_polyline(seed)
    program, _, records, planned = _run(text, True)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned
    assert records["position"][-1, :2] == pytest.approx(program.segments["end"][-1][:2], abs=1e-9)
    _, _, plain, _ = _run(text, False)
    assert len(records) <= len(plain)


def test_some_random_polylines_are_programmed():
    """The random polylines above do meet programmed corners (the property is not vacuous)."""
    faster = sum(len(_run(_random_polyline(seed)[0], False)[2]) > len(_run(_random_polyline(seed)[0], True)[2])
                 for seed in range(8))
    assert faster >= 4


@pytest.mark.parametrize("seed", range(10))
def test_a_worker_lagging_at_random_and_controls_at_random_times_keep_every_limit_and_p(seed):
    """The random polylines with the worker solving ahead only now and then (a busy host) and holds,
    stops and overrides of 0 to 200 % pressed at random records (the operator resuming whatever
    waits): each run ends, every axis within its limits and every record within P, whether a
    corner was solved ahead, reached replanned or late."""
    rng = np.random.default_rng(1000 + seed)
    text, _ = _random_polyline(seed)
    config = machine_config()
    program = interpret(text, dialect_for(config))
    runner = ProgramRunner(program, config)
    runner.solves_ahead = True
    lag = float(rng.uniform(0.0, 1.0))  # the share of turns the worker misses
    presses = sorted(int(k) for k in rng.integers(1, 2500, size=int(rng.integers(0, 5))))
    made, n, turns = [], 0, 0
    while not runner.finished:
        turns += 1
        assert turns < 100_000, "the run ends"
        runner.build_ahead()
        if rng.uniform() >= lag:
            runner.solve_ahead()
        while presses and presses[0] <= n:
            presses.pop(0)
            press = rng.choice(["hold", "stop", "0", "10", "100", "200"])
            if press == "hold":
                runner.hold()
            elif press == "stop":
                runner.stop()
            else:
                runner.set_override(int(press) / 100.0)
        records, _ = runner.take(int(rng.choice([1, 3, 7, 20, 50])))
        made.append(records)
        n += len(records)
        if not len(records) and runner.idle and not runner.finished:  # held, or at 0 %: the operator resumes
            runner.set_override(1.0)
            runner.resume()
    records = np.concatenate(made)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert runner.book.solved_here == 0, "the refill never solves a corner"
