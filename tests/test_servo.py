"""The servo loop on the simulated board, real processes, virtual clock."""

from __future__ import annotations

import numpy as np
import pytest

from cnc.data.dataserver import SharedArea, unique_name
from cnc.data.fifo import SetpointFifo, SetpointFlag, setpoint_dtype
from cnc.hw.board import AxisIn, DigitalIn, DigitalOut
from cnc.data.layout import ServoFault, ServoState, controller_layouts
from cnc.ptp import move_setpoints
from cnc.brake import StopProfile, stop_distance_bound_mm
from cnc.servo import Servo

from .conftest import enable_and_hold, feed, machine_config

RAMP_FE_BOUND_MM = 0.060  # 12 % of the 0.5 mm trip limit, at 500 mm/s and 5000 mm/s^2


def _settled(sup, target, tol=0.005):
    return all(abs(a - t) <= tol for a, t in zip(sup.servo()["actual_mm"], target))


def test_servo_follows_a_ramp_in_virtual_time_with_following_error_below_bound(direct_controller):
    sup = direct_controller
    start = enable_and_hold(sup)
    target = [start[0] + 600.0, start[1] - 300.0]
    setpoints = move_setpoints(sup.config, start, target)
    assert np.max(np.abs(setpoints["velocity"][:, 0])) == pytest.approx(500.0, rel=1e-3), "the ramp reaches full speed"
    feed(sup, setpoints)
    sup.wait_motion_done()
    s = sup.servo()
    assert s["fault"] == ServoFault.NONE and s["underruns"] == 0
    assert max(s["max_following_error_mm"]) < RAMP_FE_BOUND_MM, s["max_following_error_mm"]
    assert max(s["max_following_error_mm"]) > 0.001, "a moving axis has some following error"
    sup.wait_until(lambda: _settled(sup, target), 5.0, "the table to settle on the target")


def test_following_error_beyond_limit_trips_servo_drives_off_and_jet_closed(direct_controller):
    sup = direct_controller
    start = enable_and_hold(sup)
    sup.set_sim(friction_scale=[300.0, 1.0])  # a seized X axis
    feed(sup, move_setpoints(sup.config, start, [start[0] + 200.0, start[1]], flags=SetpointFlag.JET_ON))
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT, 10.0, "the following-error trip")
    s, hw = sup.servo(), sup.hw()
    assert s["fault"] == ServoFault.FOLLOWING_ERROR and s["fault_axis"] == 0
    assert abs(s["fault_value"]) > sup.config.axis["x"].following_error_limit_mm
    assert s["speed_cmd_v"] == [0.0, 0.0] and s["drive_enable_mask"] == 0
    sup.wait_until(lambda: not sup.hw()["digital_out"] & DigitalOut.JET_VALVE, 2.0, "the jet to close")
    # the board reads its drives back on its next tick after the servo's output: wait for it, not a race
    sup.wait_until(lambda: all(not a & AxisIn.DRIVE_ENABLED for a in sup.hw()["axis_inputs"]), 2.0, "the drives to read back off")
    assert sup.fifo.fill() == 0, "a trip flushes the setpoints"
    assert hw["tick"] > 0


def test_setpoint_outside_travel_trips_soft_limit_and_nothing_moves(direct_controller):
    sup = direct_controller
    start = enable_and_hold(sup)
    counts = sup.hw()["encoder_counts"][0]
    seq = sup.set_position_reference(0, counts, counts * 0.001)  # home X where it stands
    sup.wait_until(lambda: sup.servo()["position_ref_seq"] == seq, 5.0, "X homed")
    sup.fifo.push_one((1600.5, start[1]), (0.0, 0.0), SetpointFlag.IN_MOTION)
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT, 5.0, "the soft-limit trip")
    s = sup.servo()
    assert s["fault"] == ServoFault.SOFT_LIMIT and s["fault_axis"] == 0 and s["fault_value"] == 1600.5
    assert all(abs(a - b) < 0.002 for a, b in zip(s["actual_mm"], start))


def test_estop_trips_the_servo_and_reset_recovers_only_once_released(direct_controller):
    sup = direct_controller
    enable_and_hold(sup)
    sup.fifo.push_one(sup.servo()["commanded_mm"], (0.0, 0.0), SetpointFlag.JET_ON)
    sup.wait_until(lambda: sup.hw()["digital_out"] & DigitalOut.JET_VALVE, 2.0, "the jet to open")
    sup.set_sim(estop_pressed=1)
    sup.wait_until(lambda: sup.servo()["fault"] == ServoFault.ESTOP, 2.0, "the e-stop trip")
    sup.wait_until(lambda: not sup.hw()["digital_out"] & DigitalOut.JET_VALVE, 2.0, "the jet to close")
    assert not sup.hw()["digital_in"] & DigitalIn.ESTOP_OK
    sup.reset()
    sup.wait_until(lambda: sup.servo()["reset_seq"] == sup.command.get("reset_seq"), 2.0, "the reset")
    sup.wait_until(lambda: sup.servo()["fault"] == ServoFault.ESTOP, 2.0, "the e-stop still latched")
    sup.set_sim(estop_pressed=0)
    sup.wait_until(lambda: sup.hw()["digital_in"] & DigitalIn.ESTOP_OK, 2.0, "the e-stop circuit to close")
    sup.reset()
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 5.0, "the servo to hold again")
    assert sup.servo()["fault"] == ServoFault.NONE


def test_the_fifo_running_dry_mid_motion_is_a_controlled_stop_straight_on_then_a_latched_trip(direct_controller):
    """A starved planner must not stop the head dead (a following-error trip, drives off, the table
    coasting): the servo closes the jet and brakes along the current velocity, jerk-limited, then trips."""
    sup = direct_controller
    start = enable_and_hold(sup)
    slow = move_setpoints(sup.config, start, [start[0] + 20.0, start[1]], velocity_scale=0.05, flags=SetpointFlag.JET_ON)
    half = slow[: len(slow) // 2]
    assert half["flags"][-1] & SetpointFlag.IN_MOTION
    feed(sup, half)
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT, 10.0, "the underrun trip")
    s = sup.servo()
    assert s["fault"] == ServoFault.UNDERRUN and s["underruns"] == 1
    v = float(half["velocity"][-1][0])
    assert s["trip_speed_mm_s"] == pytest.approx(v, rel=1e-6)
    bound = stop_distance_bound_mm(v, 0.0, 5000.0, 200000.0) - 1.0  # the braking part of the bound
    last = float(half["position"][-1][0])
    assert last < s["actual_mm"][0] <= last + bound + 0.01, "stopped straight on, within its braking distance"
    assert s["brake_distance_mm"] == pytest.approx(StopProfile(v, 0.0, 5000.0, 200000.0).distance, rel=1e-6)
    assert not sup.hw()["digital_out"] & DigitalOut.JET_VALVE and s["drive_enable_mask"] == 0


def test_setpoint_output_flags_drive_the_jet_valve(direct_controller):
    sup = direct_controller
    start = enable_and_hold(sup)
    feed(sup, move_setpoints(sup.config, start, [start[0] + 5.0, start[1]], flags=SetpointFlag.JET_ON | SetpointFlag.AUX1))
    sup.wait_until(lambda: sup.hw()["digital_out"] == DigitalOut.JET_VALVE | DigitalOut.AUX1, 5.0, "jet and aux on")
    sup.wait_motion_done()
    feed(sup, move_setpoints(sup.config, [start[0] + 5.0, start[1]], start))
    sup.wait_motion_done()
    sup.wait_until(lambda: sup.hw()["digital_out"] == 0, 5.0, "jet and aux off with the next move")


def test_an_unhomed_axis_has_no_soft_limits_but_its_hard_limit_switch_trips():
    from cnc.runtime.supervisor import DIRECT_FEED, Supervisor

    with Supervisor(machine_config(**{"sim.axes.x.start_position_mm": 3.0}), clock="virtual", processes=DIRECT_FEED) as sup:
        start = enable_and_hold(sup)
        # walk X down at 10 mm/s towards -9 mm, past the travel end (0) and the limit switch (-5)
        walk = np.zeros(4000, dtype=setpoint_dtype(2))
        walk["position"][:, 0] = start[0] - np.minimum(np.arange(1, 4001) * 0.01, 12.0)
        walk["position"][:, 1] = start[1]
        walk["velocity"][:, 0] = -10.0
        walk["flags"] = SetpointFlag.IN_MOTION
        feed(sup, walk)
        sup.wait_until(lambda: sup.servo()["state"] == ServoState.FAULT, 10.0, "the hard limit")
        s = sup.servo()
        assert s["fault"] == ServoFault.HARD_LIMIT and s["fault_axis"] == 0
        assert s["actual_mm"][0] < 0.0, "it went below the travel end: no soft limit before homing"


def test_disabling_opens_the_loop_and_the_drives(direct_controller):
    sup = direct_controller
    enable_and_hold(sup)
    sup.enable(False)
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.DISABLED, 2.0, "the servo to disable")
    sup.wait_until(lambda: all(not a & AxisIn.DRIVE_ENABLED for a in sup.hw()["axis_inputs"]), 2.0, "drives off")


class BareServo:
    """A servo in its own shared memory, driven tick by tick by the test (no processes): healthy
    inputs, drives ready, the loop enabled."""

    def __init__(self, fifo_capacity: int = 16, encoder_counts: tuple[int, int] = (0, 0)) -> None:
        self.area = SharedArea.create(unique_name("test", "servo"), controller_layouts(2))
        self.fifo = SetpointFifo.create(unique_name("test", "sfifo"), fifo_capacity, 2)
        self.hw = self.area.writer("hw")
        self.hw.set("digital_in", int(DigitalIn.ESTOP_OK | DigitalIn.DOORS_CLOSED | DigitalIn.MAINS_ON))
        self.hw.set("axis_inputs", [int(AxisIn.DRIVE_READY)] * 2)
        self.hw.set("encoder_counts", list(encoder_counts))
        self.command = self.area.writer("command")
        self.command.set("servo_enable", 1)
        self.command.publish()
        self.motion = self.area.writer("motion")
        self.servo: Servo | None = None

    def __enter__(self) -> "BareServo":
        return self

    def __exit__(self, *exc: object) -> None:
        if self.servo is not None:
            self.servo.close()
        self.servo = None  # drop its views of the shared memory before closing it
        self.fifo.close()
        self.area.close()

    def run(self, tick: int) -> dict:
        """Publish hardware tick `tick`, run the servo on it, return its block."""
        if self.servo is None:
            self.servo = Servo(machine_config(), self.area, self.fifo, record_latency=False)
        self.hw.set("tick", tick)
        self.hw.publish()
        self.servo.tick()
        return self.area.reader("servo").read_dict()

    def order(self, **fields) -> None:
        """Write fields of the block that holds them (command, or motion for position references)."""
        for name, value in fields.items():
            block = self.motion if name.startswith("position_ref") else self.command
            block.set(name, value)
            block.publish()


def test_servo_counts_overruns_and_consumes_the_skipped_ticks_setpoints():
    """QMotor 2.0's check: the hardware tick counter jumped past the servo's own count. The
    setpoints of the skipped ticks are consumed too, so the commanded path stays on time."""
    with BareServo(fifo_capacity=64) as bare:
        for k in range(20):
            bare.fifo.push_one((0.001 * k, 0.0), (1.0, 0.0), SetpointFlag.IN_MOTION, segment=k)
        seen = [bare.run(tick)["setpoint_segment"] for tick in (1, 2, 3, 7, 8, 10)]
        s = bare.area.reader("servo").read_dict()
        assert s["overruns"] == 3 + 1 and s["ticks_processed"] == 6 and s["tick"] == 10
        assert seen == [0, 1, 2, 6, 7, 9], "one setpoint per elapsed tick"


def test_setpoint_records_carry_position_velocity_flags_segment_line_and_epoch():
    dt = setpoint_dtype(2)
    assert dt.names == ("position", "velocity", "flags", "segment", "line", "epoch")
    assert dt.itemsize == 48


def test_a_second_wake_up_for_a_tick_already_done_changes_nothing():
    """Regression: a late servo that already read tick k's image must not run tick k again."""
    with BareServo() as bare:
        for k in range(6):
            bare.fifo.push_one((0.5 * k, 0.0), (500.0, 0.0), SetpointFlag.IN_MOTION, segment=k)
        for tick in (1, 2, 2, 3):  # tick 2's wake-up arrives after tick 2 was already done
            s = bare.run(tick)
        assert s["ticks_processed"] == 3 and s["setpoint_segment"] == 2, "one setpoint per tick, none extra"
        assert s["overruns"] == 0


def test_a_position_reference_shifts_the_frame_without_moving_the_table():
    """Homing: `counts` is `position`; the commanded position follows so no speed command jumps."""
    with BareServo(encoder_counts=(100_000, 50_000)) as bare:
        s = bare.run(1)
        assert s["actual_mm"] == [100.0, 50.0] and s["homed_mask"] == 0
        assert s["state"] == ServoState.HOLDING, "enabled from the first tick: the loop closes where the table is"
        bare.order(position_ref_counts=[90_000, 0], position_ref_mm=[810.0, 0.0], position_ref_mask=0b01, position_ref_seq=1)
        s = bare.run(2)
        assert s["actual_mm"][0] == pytest.approx(820.0) and s["actual_mm"][1] == 50.0
        assert s["commanded_mm"][0] == pytest.approx(820.0), "the command moved with the frame"
        assert s["position_offset_mm"][0] == pytest.approx(720.0) and s["homed_mask"] == 0b01
        assert s["position_ref_seq"] == 1 and abs(s["speed_cmd_v"][0]) < 1e-9
        # while following a motion a new reference waits
        bare.fifo.push_one((820.1, 50.0), (10.0, 0.0), SetpointFlag.IN_MOTION)
        s = bare.run(3)
        assert s["state"] == ServoState.TRACKING
        bare.order(position_ref_mask=0b10, position_ref_seq=2)
        s = bare.run(4)
        assert s["position_ref_seq"] == 1 and s["homed_mask"] == 0b01, "not while tracking"


def test_homing_against_the_index_pulse_puts_the_machine_frame_on_the_table():
    """The simulated encoder counts from power-up (encoder_zero_mm); a reference on the latched
    index pulse (every 10 mm of machine position) gives positions in machine coordinates."""
    from cnc.runtime.supervisor import DIRECT_FEED, Supervisor

    config = machine_config(**{"sim.axes.x.encoder_zero_mm": 123.0})
    with Supervisor(config, clock="virtual", processes=DIRECT_FEED) as sup:
        start = enable_and_hold(sup)
        assert start[0] == pytest.approx(800.0 - 123.0), "unhomed: the counter's frame"
        latch_seq = sup.hw()["index_latch_seq"][0]
        feed(sup, move_setpoints(config, start, [start[0] + 15.0, start[1]], velocity_scale=0.1))
        sup.wait_motion_done()
        hw = sup.hw()
        assert hw["index_latch_seq"][0] > latch_seq, "an index pulse was crossed"
        latched = hw["index_latch_counts"][0]  # the count at the last index mark: machine 810 mm
        assert latched == round((810.0 - 123.0) / 0.001)
        seq = sup.set_position_reference(0, latched, 810.0)
        sup.wait_until(lambda: sup.servo()["position_ref_seq"] == seq, 5.0, "the reference to apply")
        sup.pause_virtual_clock()  # read the servo and the encoder at the same tick
        s, hw = sup.servo(), sup.hw()
        sup.resume_virtual_clock()
        assert s["homed_mask"] & 1 and s["state"] == ServoState.HOLDING and s["fault"] == ServoFault.NONE
        assert s["actual_mm"][0] == pytest.approx(hw["encoder_counts"][0] * 0.001 + 123.0, abs=1e-9), "machine frame"
        assert abs(s["actual_mm"][0] - 815.0) < 0.05, "where the move ended, in machine coordinates"


def test_setpoints_left_in_the_fifo_are_dropped_while_the_drives_are_off(direct_controller):
    sup = direct_controller
    start = enable_and_hold(sup)
    sup.enable(False)
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.DISABLED, 5.0, "the drives to go off")
    sup.fifo.push(move_setpoints(sup.config, start, [start[0] + 50.0, start[1]]))
    sup.wait_until(lambda: sup.fifo.fill() == 0, 5.0, "the servo to drop them")
    held = enable_and_hold(sup)
    assert held == pytest.approx(start, abs=0.01), "nothing stale ran when the drives came back"


def test_the_commanders_inhibit_closes_the_jet_at_once_and_a_jet_test_opens_it_only_when_asked_at_rest():
    """A fault closes the jet before the stop (inhibit wins over the setpoints, within the tick);
    the jet test opens it only while the axes hold still, and only when asked for while they do: a
    jet test asked for during a motion, or left on through one, never opens the jet by itself."""
    from cnc.hw.board import DigitalOut

    jet = int(DigitalOut.JET_VALVE)
    with BareServo(fifo_capacity=64) as bare:
        for k in range(4):
            flags = SetpointFlag.IN_MOTION | (SetpointFlag.JET_ON if k < 2 else 0)
            bare.fifo.push_one((0.001 * k, 0.0), (1.0, 0.0), flags if k < 3 else 0, segment=k)
        assert bare.run(1)["digital_out"] & jet
        bare.order(output_inhibit=jet)
        s = bare.run(2)
        assert not s["digital_out"] & jet and s["state"] == ServoState.TRACKING, "jet off while still moving"
        bare.order(output_inhibit=0, output_force=jet)
        s = bare.run(3)
        assert not s["digital_out"] & jet and s["state"] == ServoState.TRACKING, "no jet test while moving"
        for tick in range(4, 10):
            s = bare.run(tick)
        assert s["state"] == ServoState.HOLDING and not s["digital_out"] & jet, "asked for while moving: void"
        bare.order(output_force=0)
        bare.run(10)
        bare.order(output_force=jet)
        assert bare.run(11)["digital_out"] & jet, "asked for at rest: the jet test opens the jet"
        bare.fifo.push_one((0.01, 0.0), (1.0, 0.0), SetpointFlag.IN_MOTION)
        bare.fifo.push_one((0.011, 0.0), (0.0, 0.0), 0)
        assert not bare.run(12)["digital_out"] & jet, "a motion ends the jet test"
        for tick in range(13, 16):
            s = bare.run(tick)
        assert s["state"] == ServoState.HOLDING and not s["digital_out"] & jet, "and it does not reopen at rest"


def test_control_parameters_written_between_two_ticks_apply_from_the_next_tick_whole():
    """QMotor's online tuning: the gateway writes the params block; the servo takes every new value
    at the tick boundary, so the next tick is computed entirely with the new gains."""
    from cnc.params import registry, values_of

    config = machine_config()
    specs = registry(config)
    kp_x = next(s for s in specs if s.name == "axis.x.kp_1_s")
    fe_y = next(s for s in specs if s.name == "axis.y.following_error_limit_mm")
    with BareServo(fifo_capacity=64, encoder_counts=(0, 0)) as bare:
        bare.fifo.push_one((0.010, 0.0), (0.0, 0.0), SetpointFlag.IN_MOTION)  # 10 um of error on X, no velocity
        bare.fifo.push_one((0.010, 0.0), (0.0, 0.0), SetpointFlag.IN_MOTION)
        bare.fifo.push_one((0.010, 0.0), (0.0, 0.0), SetpointFlag.IN_MOTION)
        s = bare.run(1)
        volts = s["speed_cmd_v"][0]
        assert s["params_change"] == 0 and volts > 0.0
        block = bare.area.writer("params")
        values = values_of(config, specs)
        values[kp_x.index] = 2 * values[kp_x.index]
        values[fe_y.index] = 0.25
        block.set("values", values + [0.0] * (len(block.get("values")) - len(values)))
        block.set("change", 1)
        block.publish()
        s = bare.run(2)
        assert s["params_change"] == 1 and s["params_tick"] == 2
        integral_step = config.axis["x"].ki_1_s2 * 0.010 * config.timing.period_s * config.axis["x"].volts_per_mm_s
        p_part = lambda kp: kp * 0.010 * config.axis["x"].volts_per_mm_s  # noqa: E731
        assert s["speed_cmd_v"][0] == pytest.approx(volts + p_part(values[kp_x.index] / 2) + integral_step, rel=1e-9)
        assert bare.servo.fe_lim[1] == 0.25 and bare.servo.program.kp_1_s[0] == values[kp_x.index]
        s = bare.run(3)
        assert s["params_change"] == 1 and s["params_tick"] == 2, "applied once"


def test_control_parameters_found_mid_write_are_taken_at_the_next_tick_never_as_zeros():
    """The params block caught mid-write at the tick the servo sees a change: before this was fixed
    the reader's fallback (the layout's zeros, when it had not read the block before) became the
    gains and limits, and a following-error limit of 0 tripped the cut at once (seen in a fresh-clone
    `make test` under load). The values in force stay; the change applies once the block is whole."""
    from cnc.params import registry, values_of

    config = machine_config()
    specs = registry(config)
    kp_x = next(s for s in specs if s.name == "axis.x.kp_1_s")
    with BareServo(fifo_capacity=64, encoder_counts=(0, 0)) as bare:
        for _ in range(4):
            bare.fifo.push_one((0.010, 0.0), (0.0, 0.0), SetpointFlag.IN_MOTION)  # 10 um of error on X
        s = bare.run(1)
        kp_before, fe_before = list(bare.servo.program.kp_1_s), list(bare.servo.fe_lim)
        block = bare.area.writer("params")
        values = values_of(config, specs)
        values[kp_x.index] = 2 * values[kp_x.index]
        block.set("values", values + [0.0] * (len(block.get("values")) - len(values)))
        block.set("change", 1)
        block.publish()
        cell = bare.area.blocks["params"].seq_cell
        cell[0] += 1  # the writer stopped half-way through its next write
        s = bare.run(2)
        assert s["state"] != ServoState.FAULT and s["params_change"] == 0, "nothing taken from a block mid-write"
        assert bare.servo.program.kp_1_s == kp_before and bare.servo.fe_lim == fe_before
        cell[0] += 1  # the write completes
        s = bare.run(3)
        assert s["params_change"] == 1 and s["params_tick"] == 3 and bare.servo.program.kp_1_s[0] == values[kp_x.index]
        assert s["state"] != ServoState.FAULT


def _home_both(bare: BareServo, tick: int) -> int:
    """Home both axes where the encoders stand (counts are machine micrometres)."""
    bare.order(position_ref_counts=[0, 0], position_ref_mm=[0.0, 0.0], position_ref_mask=0b11, position_ref_seq=1)
    bare.run(tick)
    assert bare.area.reader("servo").read_dict()["homed_mask"] == 0b11
    return tick + 1


def test_a_setpoint_on_the_travel_end_within_the_tolerance_runs_clamped_onto_it_beyond_it_trips():
    """A program parking at X0 rounds to -1.4e-14 mm: it must run, not trip the soft limit."""
    with BareServo(fifo_capacity=64, encoder_counts=(0, 0)) as bare:
        tick = _home_both(bare, 1)
        bare.fifo.push_one((-1.4e-14, 0.0), (0.0, 0.0), 0)
        s = bare.run(tick)
        assert s["state"] == ServoState.HOLDING and s["commanded_mm"][0] == 0.0, "clamped onto the end"
        bare.fifo.push_one((-0.004, 0.0), (0.0, 0.0), 0)
        s = bare.run(tick + 1)
        assert s["state"] == ServoState.HOLDING and s["commanded_mm"][0] == 0.0, "within 5 um: still clamped"
        bare.fifo.push_one((-0.02, 0.0), (0.0, 0.0), 0)
        s = bare.run(tick + 2)
        assert s["fault"] == ServoFault.SOFT_LIMIT and s["fault_value"] == -0.02


def test_an_axis_beyond_its_travel_may_move_back_in_but_not_further_out():
    with BareServo(fifo_capacity=64, encoder_counts=(-30, 0)) as bare:  # 30 um below X0 (a park's overshoot)
        tick = _home_both(bare, 1)
        s = bare.run(tick)
        assert s["commanded_mm"][0] == pytest.approx(-0.030), "the loop closed where the table stands"
        bare.fifo.push_one((-0.020, 0.0), (1.0, 0.0), SetpointFlag.IN_MOTION)
        bare.fifo.push_one((-0.010, 0.0), (0.0, 0.0), 0)
        for k in (1, 2):
            s = bare.run(tick + k)
        assert s["state"] == ServoState.HOLDING and s["commanded_mm"][0] == pytest.approx(-0.010), "inward runs"
        bare.fifo.push_one((-0.015, 0.0), (0.0, 0.0), 0)
        s = bare.run(tick + 3)
        assert s["fault"] == ServoFault.SOFT_LIMIT, "outward trips"


def test_on_an_active_hard_limit_switch_after_the_reset_the_axis_moves_away_from_it_only():
    with BareServo(fifo_capacity=64) as bare:
        hw = bare.hw
        assert bare.run(1)["state"] == ServoState.HOLDING
        hw.set("axis_inputs", [int(AxisIn.DRIVE_READY | AxisIn.LIMIT_MIN), int(AxisIn.DRIVE_READY)])
        s = bare.run(2)
        assert s["fault"] == ServoFault.HARD_LIMIT, "the switch becoming active trips"
        for tick in range(3, 40):
            s = bare.run(tick)
        assert s["state"] == ServoState.FAULT
        bare.order(reset_trip_seq=s["trip_seq"], reset_seq=1)
        hw.set("reset_seq", 1)
        s = bare.run(41)
        s = bare.run(42)
        assert s["state"] == ServoState.HOLDING, "reset while still on the switch: the loop closes"
        epoch = s["motion_epoch"]
        bare.fifo.push_one((0.01, 0.0), (1.0, 0.0), SetpointFlag.IN_MOTION, epoch=epoch)
        bare.fifo.push_one((0.02, 0.0), (0.0, 0.0), 0, epoch=epoch)
        assert bare.run(43)["state"] == ServoState.TRACKING and bare.run(44)["state"] == ServoState.HOLDING, "away: runs"
        bare.fifo.push_one((0.01, 0.0), (0.0, 0.0), 0, epoch=epoch)
        assert bare.run(45)["fault"] == ServoFault.HARD_LIMIT, "further onto the switch: trips"


def test_setpoints_of_another_motion_epoch_are_dropped_and_counted():
    with BareServo(fifo_capacity=64) as bare:
        epoch = bare.run(1)["motion_epoch"]
        bare.fifo.push_one((0.5, 0.0), (0.0, 0.0), 0, epoch=epoch + 7)  # made before a trip, a stop or a reset
        bare.fifo.push_one((0.001, 0.0), (0.0, 0.0), 0, epoch=epoch)
        s = bare.run(2)
        assert s["stale_dropped"] == 1 and s["commanded_mm"][0] == pytest.approx(0.001)


def test_a_reset_clears_only_a_trip_the_commander_saw_from_the_same_commander_once_the_stop_ran_out():
    with BareServo(fifo_capacity=64) as bare:
        bare.run(1)
        bare.hw.set("digital_in", int(DigitalIn.ESTOP_OK | DigitalIn.MAINS_ON))  # a door opens ...
        s = bare.run(2)
        assert s["state"] == ServoState.FAULT or s["state"] == ServoState.STOPPING
        bare.hw.set("digital_in", int(DigitalIn.ESTOP_OK | DigitalIn.DOORS_CLOSED | DigitalIn.MAINS_ON))
        for tick in range(3, 40):
            s = bare.run(tick)
        assert s["state"] == ServoState.FAULT and s["trip_seq"] == 1
        # a reset asked for before the trip was seen (its trip_seq is older): the trip stays latched
        bare.order(reset_trip_seq=0, reset_seq=1)
        bare.hw.set("reset_seq", 1)
        assert bare.run(40)["state"] == ServoState.FAULT
        # another commander's counters are a baseline, not a request
        bare.order(token=99, reset_trip_seq=1, reset_seq=5)
        bare.hw.set("reset_seq", 5)
        assert bare.run(41)["state"] == ServoState.FAULT
        bare.order(reset_seq=6)
        bare.hw.set("reset_seq", 6)
        bare.run(42)
        assert bare.run(43)["state"] == ServoState.HOLDING, "the same commander, after it saw the trip"
