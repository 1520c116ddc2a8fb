"""Behaviour of the simulated XY table: drive lag and current limit, friction, switches, encoder."""

from __future__ import annotations

import math
from pathlib import Path
import random

import pytest

from cnc.config import ConfigError, MachineConfig, load_machine, loads_machine
from cnc.hw.board import AxisIn, BoardInputs, DigitalIn, DigitalOut
from cnc.hw.sim_board import SimBoard

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

DT_S = 0.001
X, Y = 0, 1

# Plant defaults of SimAxisConfig, used by the analytic expectations below.
TAU_S = 0.003
VISCOUS_1_S = 2.0
COULOMB_MM_S2 = 50.0
MAX_ACCEL_MM_S2 = 20000.0
VOLTS_PER_MM_S = 10.0 / 1000.0


def machine(sim_x: str = "", substeps: int = 4) -> MachineConfig:
    """Two-axis machine with default plants; `sim_x` adds keys to [sim.axes.x]."""
    return loads_machine(
        f"""
[axis.x]
travel_min_mm = 0.0
travel_max_mm = 1600.0
[axis.y]
travel_min_mm = 0.0
travel_max_mm = 1200.0
[sim]
substeps = {substeps}
[sim.axes.x]
{sim_x}
"""
    )


def board_at(x_mm: float, **kw) -> SimBoard:
    return SimBoard(machine(f"start_position_mm = {x_mm!r}", **kw))


def run(board: SimBoard, n_ticks: int, x_volts: float = 0.0, enable: int = 0b11, out: int = 0) -> BoardInputs:
    """Hold one command for n_ticks base ticks and return the last tick's inputs."""
    inputs = BoardInputs(board.n_axes)
    for _ in range(n_ticks):
        board.write_outputs([x_volts, 0.0], enable, out)
        board.advance(DT_S)
        board.read_inputs(inputs)
    return inputs


def ticks(board: SimBoard, n_ticks: int, x_volts: float, enable: int = 0b11):
    """Yield every tick's inputs while holding one command."""
    for _ in range(n_ticks):
        board.write_outputs([x_volts, 0.0], enable, 0)
        board.advance(DT_S)
        inputs = BoardInputs(board.n_axes)
        board.read_inputs(inputs)
        yield inputs


def steady_state_mm_s(v_cmd_mm_s: float, scale: float = 1.0) -> float:
    """(v_cmd - v)/tau = f (b v + c sign v)  =>  v = (v_cmd - f c tau) / (1 + f b tau)."""
    return (v_cmd_mm_s - scale * COULOMB_MM_S2 * TAU_S) / (1.0 + scale * VISCOUS_1_S * TAU_S)


def coast_mm_s(v0: float, t: float) -> float:
    """dv/dt = -b v - c (v > 0): v(t) = (v0 + c/b) exp(-b t) - c/b."""
    return (v0 + COULOMB_MM_S2 / VISCOUS_1_S) * math.exp(-VISCOUS_1_S * t) - COULOMB_MM_S2 / VISCOUS_1_S


# -- drive -----------------------------------------------------------------------------------


def test_board_starts_at_rest_where_the_machine_file_parks_it_or_mid_travel():
    board = SimBoard(load_machine("machines/waterjet.toml"))
    inputs = BoardInputs(board.n_axes)
    board.read_inputs(inputs)
    assert (board.position_mm(X), board.position_mm(Y)) == (30.0, 30.0)
    assert inputs.encoder_counts == [30000, 30000]
    assert (board.velocity_mm_s(X), board.velocity_mm_s(Y)) == (0.0, 0.0)
    text = Path("machines/waterjet.toml").read_text().replace("start_position_mm = 30.0", "")
    board = SimBoard(loads_machine(text, "unparked.toml"))
    assert (board.position_mm(X), board.position_mm(Y)) == (800.0, 600.0), "without a start position: mid-travel"
    assert (board.velocity_mm_s(X), board.velocity_mm_s(Y)) == (0.0, 0.0)


@pytest.mark.parametrize("volts", [10.0, 5.0, -2.5])
def test_constant_command_settles_to_scaled_velocity_less_friction_error(volts):
    board = board_at(800.0)
    run(board, 300, volts)
    v_cmd = volts / VOLTS_PER_MM_S
    expected = math.copysign(steady_state_mm_s(abs(v_cmd)), v_cmd)
    assert board.velocity_mm_s(X) == pytest.approx(expected, rel=1e-12)
    # the P loop's steady-state error: the friction deceleration times tau
    error = TAU_S * (VISCOUS_1_S * abs(v_cmd) + COULOMB_MM_S2) / (1.0 + VISCOUS_1_S * TAU_S)
    assert abs(v_cmd) - abs(board.velocity_mm_s(X)) == pytest.approx(error, rel=1e-9)


def test_full_scale_command_runs_at_993_mm_s_not_1000():
    board = board_at(100.0)
    run(board, 300, 10.0)
    assert board.velocity_mm_s(X) == pytest.approx(993.887, abs=1e-3)


def test_encoder_rate_matches_settled_velocity():
    board = board_at(100.0)
    first = run(board, 300, 5.0).encoder_counts[X]
    last = run(board, 100, 5.0).encoder_counts[X]
    assert last - first == pytest.approx(steady_state_mm_s(500.0) * 0.1 / 0.001, abs=1)


def test_small_step_follows_first_order_lag_with_configured_time_constant():
    # 0.4 V -> 40 mm/s: initial acceleration 13 333 mm/s^2 stays below the current limit.
    board = board_at(800.0)
    run(board, 3, 0.4)  # t = tau
    v_ss = steady_state_mm_s(40.0)
    assert board.velocity_mm_s(X) / v_ss == pytest.approx(1.0 - math.exp(-1.0), rel=0.02)
    # exactly: dv/dt = v_cmd/tau - (1/tau + b) v - c
    k = 1.0 / TAU_S + VISCOUS_1_S
    assert board.velocity_mm_s(X) == pytest.approx(v_ss * (1.0 - math.exp(-k * 3 * DT_S)), rel=1e-12)


def test_large_step_accelerates_at_current_limit_then_follows_the_lag():
    board = board_at(100.0)
    run(board, 1, 10.0)
    assert board.velocity_mm_s(X) == pytest.approx((MAX_ACCEL_MM_S2 - COULOMB_MM_S2) * DT_S, rel=1e-3)
    # current-limited until v_cmd - v = a_max tau, then the exponential lag (both exact)
    b, c = VISCOUS_1_S, COULOMB_MM_S2
    v_edge = 1000.0 - MAX_ACCEL_MM_S2 * TAU_S
    v_inf = (MAX_ACCEL_MM_S2 - c) / b
    t_edge = math.log(v_inf / (v_inf - v_edge)) / b
    run(board, 59, 10.0)
    v_ss = steady_state_mm_s(1000.0)
    expected = v_ss + (v_edge - v_ss) * math.exp(-(1.0 / TAU_S + b) * (0.060 - t_edge))
    assert board.velocity_mm_s(X) == pytest.approx(expected, rel=1e-9)


def test_speed_command_saturates_at_full_scale_volts():
    full, over = board_at(800.0), board_at(800.0)
    run(full, 100, 10.0)
    run(over, 100, 14.0)
    assert over.position_mm(X) == full.position_mm(X)
    assert over.velocity_mm_s(X) == full.velocity_mm_s(X)
    run(full, 300, -10.0)
    run(over, 300, -50.0)
    assert over.velocity_mm_s(X) == full.velocity_mm_s(X) == pytest.approx(-steady_state_mm_s(1000.0))


def test_drive_reverses_through_zero_velocity():
    board = board_at(800.0)
    run(board, 200, 2.0)
    velocities = [board.velocity_mm_s(X) for _ in ticks(board, 200, -2.0)]
    assert velocities[-1] == pytest.approx(-steady_state_mm_s(200.0), rel=1e-12)
    assert all(b <= a for a, b in zip(velocities, velocities[1:]))


def random_commands(seed: int, n: int) -> list[tuple[float, bool, int]]:
    """(volts, enabled, ticks) segments: big and tiny commands, reversals, coasting."""
    rng = random.Random(seed)
    return [
        (rng.choice([rng.uniform(-12.0, 12.0), rng.uniform(-0.05, 0.05)]), rng.random() < 0.8, rng.randrange(1, 40))
        for _ in range(n)
    ]


def test_integration_is_exact_so_substep_count_does_not_matter():
    boards = [board_at(800.0, substeps=n) for n in (1, 4, 64)]
    for volts, enabled, n_ticks in random_commands(7, 40):
        for _ in range(n_ticks):
            for board in boards:
                board.write_outputs([volts, 0.0], int(enabled), 0)
                board.advance(DT_S)
            for board in boards[1:]:
                assert board.position_mm(X) == pytest.approx(boards[0].position_mm(X), abs=1e-9)
                assert board.velocity_mm_s(X) == pytest.approx(boards[0].velocity_mm_s(X), abs=1e-8)


def reference_plant(segments: list[tuple[float, bool, int]], p: float, h: float = 5e-6) -> list[tuple[float, float]]:
    """The plant equations integrated naively with a tiny step, sampled every tick."""
    b, c, a_max = VISCOUS_1_S, COULOMB_MM_S2, MAX_ACCEL_MM_S2
    v = 0.0
    samples = []
    for volts, enabled, n_ticks in segments:
        v_cmd = max(-10.0, min(10.0, volts)) / VOLTS_PER_MM_S
        for _ in range(n_ticks):
            for _ in range(round(DT_S / h)):
                a_drive = max(-a_max, min(a_max, (v_cmd - v) / TAU_S)) if enabled else 0.0
                if v == 0.0 and abs(a_drive) <= c:
                    continue
                direction = math.copysign(1.0, v if v != 0.0 else a_drive)
                v_next = v + (a_drive - b * v - c * direction) * h
                if v_next * direction < 0.0 and abs(a_drive) <= c:
                    v_next = 0.0  # friction alone stops, never reverses
                p += 0.5 * (v + v_next) * h
                v = v_next
            samples.append((p, v))
    return samples


def test_plant_agrees_with_fine_step_reference_integration():
    segments = random_commands(5, 12)
    expected = reference_plant(segments, 800.0)
    board = board_at(800.0)
    got = []
    for volts, enabled, n_ticks in segments:
        for _ in range(n_ticks):
            board.write_outputs([volts, 0.0], int(enabled), 0)
            board.advance(DT_S)
            got.append((board.position_mm(X), board.velocity_mm_s(X)))
    for (p_ref, v_ref), (p, v) in zip(expected, got, strict=True):
        assert p == pytest.approx(p_ref, abs=1e-3)  # reference error: O(h * a_max)
        assert v == pytest.approx(v_ref, abs=0.1)


# -- friction --------------------------------------------------------------------------------


def test_coulomb_friction_holds_axis_at_rest_under_small_command():
    # 0.001 V -> 0.1 mm/s -> drive acceleration 33 mm/s^2 < Coulomb 50 mm/s^2
    board = board_at(800.0)
    inputs = run(board, 1000, 0.001)
    assert board.position_mm(X) == 800.0
    assert board.velocity_mm_s(X) == 0.0
    assert inputs.encoder_counts[X] == 800000
    # 0.002 V -> 67 mm/s^2 breaks loose and creeps at the friction-limited velocity
    run(board, 200, 0.002)
    assert board.velocity_mm_s(X) == pytest.approx(steady_state_mm_s(0.2), rel=1e-9)


def test_coasting_axis_stops_exactly_without_reversing():
    board = board_at(800.0)
    run(board, 200, 2.0)
    v0, p0 = board.velocity_mm_s(X), board.position_mm(X)
    velocities = [board.velocity_mm_s(X) for _ in ticks(board, 1500, 2.0, enable=0)]
    assert velocities[0] == pytest.approx(coast_mm_s(v0, DT_S), rel=1e-12)
    assert all(0.0 <= b <= a for a, b in zip(velocities, velocities[1:]))
    assert velocities[-1] == 0.0
    b, c = VISCOUS_1_S, COULOMB_MM_S2
    t_stop = math.log(1.0 + b * v0 / c) / b
    assert velocities.index(0.0) == math.ceil(t_stop / DT_S) - 1
    assert board.position_mm(X) - p0 == pytest.approx((v0 - c * t_stop) / b, rel=1e-12)


def test_friction_scale_multiplies_viscous_and_coulomb_friction():
    board = board_at(100.0)
    board.set_friction_scale(X, 3.0)
    run(board, 300, 5.0)
    assert board.velocity_mm_s(X) == pytest.approx(steady_state_mm_s(500.0, scale=3.0), rel=1e-12)
    board.set_friction_scale(X, 0.0)
    run(board, 300, 5.0)
    assert board.velocity_mm_s(X) == pytest.approx(500.0, rel=1e-12)


def test_friction_spike_stops_a_coasting_axis_sooner():
    normal, spiked = board_at(800.0), board_at(800.0)
    for board in (normal, spiked):
        run(board, 200, 2.0)
    spiked.set_friction_scale(X, 10.0)
    run(normal, 150, 0.0, enable=0)
    run(spiked, 150, 0.0, enable=0)
    assert spiked.velocity_mm_s(X) == 0.0 < normal.velocity_mm_s(X)


# -- switches and end stops ------------------------------------------------------------------


def test_lower_limit_switch_activates_at_overtravel_and_hard_stop_clamps():
    board = board_at(3.0)  # limit switch at -5 mm, end stop at -15 mm
    seen = []
    for inputs in ticks(board, 600, -0.5):
        p = board.position_mm(X)
        seen.append(p)
        assert bool(inputs.axis_inputs[X] & AxisIn.LIMIT_MIN) == (p <= -5.0)
        assert not inputs.axis_inputs[X] & AxisIn.LIMIT_MAX
    assert min(seen[:-1]) < -5.0 < max(seen)
    assert board.position_mm(X) == -15.0
    assert board.velocity_mm_s(X) == 0.0
    assert inputs.encoder_counts[X] == -15000


def test_upper_limit_switch_activates_at_overtravel_and_hard_stop_clamps():
    board = board_at(1597.0)
    for inputs in ticks(board, 600, 0.5):
        p = board.position_mm(X)
        assert bool(inputs.axis_inputs[X] & AxisIn.LIMIT_MAX) == (p >= 1605.0)
    assert board.position_mm(X) == 1615.0
    assert board.velocity_mm_s(X) == 0.0
    assert inputs.axis_inputs[X] & AxisIn.LIMIT_MAX
    # driving away from the stop leaves it again
    run(board, 300, -0.5)
    assert board.position_mm(X) < 1605.0
    assert not run(board, 1, -0.5).axis_inputs[X] & AxisIn.LIMIT_MAX


def test_home_switch_active_at_and_below_home_position():
    board = board_at(3.0)  # home switch at -2 mm
    positions = []
    for inputs in ticks(board, 150, -0.5):
        p = board.position_mm(X)
        positions.append(p)
        assert bool(inputs.axis_inputs[X] & AxisIn.HOME) == (p <= -2.0)
    assert positions[0] > -2.0 > positions[-1]


# -- encoder ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("start_mm", "zero_mm", "counts"),
    [
        (100.0004, 0.0, 100000),
        (100.0006, 0.0, 100001),
        (-3.2004, 0.0, -3200),
        (-3.2006, 0.0, -3201),
        (100.0004, 200.0, -100000),  # -99999.6 counts
        (100.0006, 0.5, 99501),  # 99500.6 counts
    ],
)
def test_encoder_counts_one_per_micrometre_rounded_to_nearest(start_mm, zero_mm, counts):
    board = SimBoard(machine(f"start_position_mm = {start_mm!r}\nencoder_zero_mm = {zero_mm!r}"))
    inputs = BoardInputs(board.n_axes)
    board.read_inputs(inputs)
    assert inputs.encoder_counts[X] == round((start_mm - zero_mm) / 0.001) == counts
    assert type(inputs.encoder_counts[X]) is int


def test_encoder_tracks_true_position_within_half_a_count():
    board = board_at(100.0)
    for inputs in ticks(board, 300, 3.7):
        error_mm = inputs.encoder_counts[X] * 0.001 - board.position_mm(X)
        assert abs(error_mm) <= 0.0005 + 1e-12


def test_index_pulse_latches_exact_crossing_count_in_both_directions():
    # encoder zero at 0.5 mm: the index marks at 10 and 20 mm read 9500 and 19500 counts
    board = SimBoard(machine("start_position_mm = 5.0\nencoder_zero_mm = 0.5"))
    pulses = []
    for inputs in ticks(board, 400, 0.5):  # up 5 -> ~25 mm at 50 mm/s
        if inputs.axis_inputs[X] & AxisIn.INDEX:
            pulses.append((inputs.index_latch_seq[X], inputs.index_latch_counts[X], inputs.encoder_counts[X]))
    assert [p[:2] for p in pulses] == [(1, 9500), (2, 19500)]
    assert all(counts > latched for _, latched, counts in pulses)  # sampled after the crossing
    for inputs in ticks(board, 800, -0.5):  # back down to the end stop at -15 mm
        if inputs.axis_inputs[X] & AxisIn.INDEX:
            pulses.append((inputs.index_latch_seq[X], inputs.index_latch_counts[X], inputs.encoder_counts[X]))
    assert [p[:2] for p in pulses[2:]] == [(3, 19500), (4, 9500), (5, -500), (6, -10500)]
    assert all(counts < latched for _, latched, counts in pulses[2:])


def test_index_flag_is_set_only_in_the_tick_of_the_crossing():
    board = board_at(9.0)
    flags = [bool(inputs.axis_inputs[X] & AxisIn.INDEX) for inputs in ticks(board, 100, 0.5)]
    assert flags.count(True) == 1
    assert board.position_mm(X) > 10.0
    latched = BoardInputs(board.n_axes)
    board.read_inputs(latched)
    assert latched.index_latch_seq[X] == 1 and latched.index_latch_counts[X] == 10000


def test_index_counts_every_pulse_when_several_are_crossed_in_one_tick():
    board = SimBoard(machine("start_position_mm = 100.005\nindex_pitch_mm = 0.01"))
    run(board, 200, 3.0)  # ~300 mm/s: ~30 pitches per tick
    inputs = run(board, 1, 3.0)
    assert inputs.index_latch_seq[X] == math.floor(board.position_mm(X) / 0.01) - 10000
    assert inputs.index_latch_counts[X] == round(math.floor(board.position_mm(X) / 0.01) * 10)


# -- power stage, e-stop, safe state ---------------------------------------------------------


@pytest.mark.parametrize("cause", ["disabled", "estop", "drive_fault"])
def test_drive_without_power_produces_no_acceleration(cause):
    board = board_at(800.0)
    run(board, 200, 2.0)
    v0 = board.velocity_mm_s(X)
    enable = 0b10 if cause == "disabled" else 0b11
    if cause == "estop":
        board.set_estop(True)
    if cause == "drive_fault":
        board.set_drive_fault(X, True)
    inputs = run(board, 1, 10.0, enable=enable)
    assert board.velocity_mm_s(X) == pytest.approx(coast_mm_s(v0, DT_S), rel=1e-12)
    assert not inputs.axis_inputs[X] & AxisIn.DRIVE_ENABLED
    assert bool(inputs.axis_inputs[X] & AxisIn.DRIVE_READY) == (cause != "drive_fault")
    assert bool(inputs.digital_in & DigitalIn.ESTOP_OK) == (cause != "estop")
    # a standing axis stays put under a full command
    run(board, 1500, 10.0, enable=enable)
    assert board.velocity_mm_s(X) == 0.0
    assert bool(inputs.axis_inputs[Y] & AxisIn.DRIVE_ENABLED) == (cause != "estop")


def test_drive_resumes_once_fault_and_estop_clear():
    board = board_at(800.0)
    board.set_estop(True)
    board.set_drive_fault(X, True)
    run(board, 10, 1.0)
    board.set_estop(False)
    board.set_drive_fault(X, False)
    inputs = run(board, 300, 1.0)
    assert inputs.axis_inputs[X] & AxisIn.DRIVE_ENABLED and inputs.axis_inputs[X] & AxisIn.DRIVE_READY
    assert board.velocity_mm_s(X) == pytest.approx(steady_state_mm_s(100.0), rel=1e-12)


def test_safe_state_zeroes_everything_until_next_write():
    board = board_at(800.0)
    jet = int(DigitalOut.JET_VALVE | DigitalOut.ABRASIVE)
    inputs = run(board, 200, 2.0, out=jet)
    assert inputs.digital_out == jet and inputs.axis_inputs[X] & AxisIn.DRIVE_ENABLED
    v0 = board.velocity_mm_s(X)
    board.safe_state()
    board.read_inputs(inputs)
    assert inputs.digital_out == 0
    assert not any(word & AxisIn.DRIVE_ENABLED for word in inputs.axis_inputs)
    for _ in range(1500):  # no write: the board stays safe, the axis coasts to rest
        board.advance(DT_S)
    board.read_inputs(inputs)
    assert inputs.digital_out == 0 and not inputs.axis_inputs[X] & AxisIn.DRIVE_ENABLED
    assert board.velocity_mm_s(X) == 0.0 < v0
    inputs = run(board, 1, 2.0, out=jet)
    assert inputs.digital_out == jet and inputs.axis_inputs[X] & AxisIn.DRIVE_ENABLED


def test_safe_state_drops_the_last_speed_command():
    board = board_at(800.0)
    run(board, 200, 5.0)
    v0 = board.velocity_mm_s(X)
    board.safe_state()
    board.write_outputs([0.0, 0.0], 0b00, 0)
    board.advance(DT_S)
    assert board.velocity_mm_s(X) == pytest.approx(coast_mm_s(v0, DT_S), rel=1e-12)
    board.safe_state()
    board.advance(DT_S)  # enables restored without a write would drive at 5 V again; they are not
    assert board.velocity_mm_s(X) == pytest.approx(coast_mm_s(v0, 2 * DT_S), rel=1e-12)


def test_estop_cuts_digital_outputs_read_back():
    board = board_at(800.0)
    inputs = run(board, 1, 0.0, out=int(DigitalOut.JET_VALVE))
    assert inputs.digital_out == DigitalOut.JET_VALVE
    board.set_estop(True)
    board.read_inputs(inputs)
    assert inputs.digital_out == 0 and not inputs.digital_in & DigitalIn.ESTOP_OK
    board.set_estop(False)
    board.read_inputs(inputs)
    assert inputs.digital_out == DigitalOut.JET_VALVE and inputs.digital_in & DigitalIn.ESTOP_OK


def test_digital_out_read_back_holds_only_existing_outputs():
    inputs = run(board_at(800.0), 1, 0.0, out=0xFFFF)
    assert inputs.digital_out == sum(int(o) for o in DigitalOut)


def test_global_inputs_follow_injected_doors_and_mains():
    board = board_at(800.0)
    inputs = BoardInputs(board.n_axes)
    board.read_inputs(inputs)
    assert inputs.digital_in == DigitalIn.ESTOP_OK | DigitalIn.DOORS_CLOSED | DigitalIn.MAINS_ON
    board.set_doors(True)
    board.set_mains(False)
    board.read_inputs(inputs)
    assert inputs.digital_in == DigitalIn.ESTOP_OK
    board.set_doors(False)
    board.read_inputs(inputs)
    assert inputs.digital_in == DigitalIn.ESTOP_OK | DigitalIn.DOORS_CLOSED


# -- determinism, validation, cost -----------------------------------------------------------


def test_same_command_sequence_gives_identical_inputs():
    rng = random.Random(20240521)
    commands = [
        ([rng.uniform(-12.0, 12.0), rng.uniform(-12.0, 12.0)], rng.randrange(4), rng.randrange(64))
        for _ in range(50)
    ]
    config = load_machine("machines/waterjet.toml")
    a, b = SimBoard(config), SimBoard(config)
    ia, ib = BoardInputs(2), BoardInputs(2)
    for tick in range(3000):
        volts, enable, out = commands[(tick // 60) % len(commands)]
        for board, inputs in ((a, ia), (b, ib)):
            board.write_outputs(volts, enable, out)
            board.advance(DT_S)
            board.read_inputs(inputs)
        assert ia == ib
        assert (a.position_mm(X), a.velocity_mm_s(Y)) == (b.position_mm(X), b.velocity_mm_s(Y))


@pytest.mark.parametrize(
    ("call", "argument"),
    [
        (lambda b: b.set_friction_scale(X, -0.1), "scale"),
        (lambda b: b.set_friction_scale(X, math.nan), "scale"),
        (lambda b: b.set_friction_scale(X, math.inf), "scale"),
        (lambda b: b.set_friction_scale(2, 1.0), "axis"),
        (lambda b: b.set_drive_fault(-1, True), "axis"),
        (lambda b: b.set_drive_fault(True, True), "axis"),
        (lambda b: b.position_mm(2), "axis"),
        (lambda b: b.velocity_mm_s(5), "axis"),
        (lambda b: b.write_outputs([1.0], 1, 0), "speed_cmd_v"),
        (lambda b: b.write_outputs([0.0, math.nan], 1, 0), "speed command is NaN"),
        (lambda b: b.advance(0.0), "dt_s"),
    ],
)
def test_bad_arguments_are_rejected_naming_the_argument(call, argument):
    board = board_at(800.0)
    board.write_outputs([0.5, 0.0], 0b01, 0)
    with pytest.raises(ValueError, match=argument):
        call(board)
    board.advance(DT_S)  # the rejected call changed nothing: the 0.5 V command still drives
    reference = board_at(800.0)
    run(reference, 1, 0.5, enable=0b01)
    assert board.velocity_mm_s(X) == reference.velocity_mm_s(X) > 0.0


def test_start_position_beyond_end_stops_is_a_config_error():
    with pytest.raises(ConfigError, match=r"sim\.axes\.x.*start_position_mm"):
        board_at(-20.0)


def test_the_output_watchdog_drops_every_output_when_nobody_refreshes_them():
    """The IOBoard contract: outputs not refreshed within the watchdog's timeout (the board's own
    time) are dropped by the board itself: drives off, jet closed; the next write re-arms it."""
    board = board_at(800.0)
    board.arm_output_watchdog(0.005)
    inputs = run(board, 50, 2.0, out=int(DigitalOut.JET_VALVE))
    assert inputs.digital_out == DigitalOut.JET_VALVE and all(a & AxisIn.DRIVE_ENABLED for a in inputs.axis_inputs)
    moving = board.velocity_mm_s(X)
    for _ in range(4):  # the host stops refreshing (run's last tick counted): within the timeout they stand
        board.advance(DT_S)
        board.read_inputs(inputs)
    assert inputs.digital_out == DigitalOut.JET_VALVE and not board.watchdog_expired
    board.advance(DT_S)
    board.read_inputs(inputs)
    assert board.watchdog_expired and inputs.digital_out == 0, "the jet closed by the board itself"
    assert not any(a & AxisIn.DRIVE_ENABLED for a in inputs.axis_inputs), "the drives off"
    for _ in range(200):
        board.advance(DT_S)
    assert abs(board.velocity_mm_s(X)) < moving, "the axis no longer driven"
    inputs = run(board, 1, 0.0, out=int(DigitalOut.JET_VALVE))
    assert inputs.digital_out == DigitalOut.JET_VALVE and not board.watchdog_expired, "a write re-arms it"


def test_a_mains_loss_takes_the_drives_power_and_the_outputs():
    board = board_at(800.0)
    inputs = run(board, 20, 2.0, out=int(DigitalOut.JET_VALVE))
    board.set_mains(False)
    inputs = run(board, 1, 2.0, out=int(DigitalOut.JET_VALVE))
    assert not inputs.digital_in & DigitalIn.MAINS_ON and inputs.digital_out == 0
    assert not any(a & AxisIn.DRIVE_ENABLED for a in inputs.axis_inputs)


def test_a_limit_switch_can_be_forced_active_wherever_the_table_stands():
    board = board_at(800.0)
    board.force_limit_switch(X, True, False)
    inputs = run(board, 1)
    assert inputs.axis_inputs[X] & AxisIn.LIMIT_MIN and not inputs.axis_inputs[X] & AxisIn.LIMIT_MAX
    board.force_limit_switch(X, False, False)
    assert not run(board, 1).axis_inputs[X] & (AxisIn.LIMIT_MIN | AxisIn.LIMIT_MAX)
