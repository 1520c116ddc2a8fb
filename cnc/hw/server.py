"""Hardware server: owns the I/O board and produces the base tick.

Each tick: write the servo's last outputs to the board (or hold the board in the safe
state), advance the board to the next sample, read its inputs, bump the tick sequence
counter, publish the hardware image, wake the timer clients due on this tick. The drive
watchdog lives here, next to the board: when the servo has missed `watchdog_missed_ticks`
consecutive ticks, the board disables the drives and closes the jet valve and the trip is
latched in the hardware image, where the supervisor sees it, until a reset while the servo
is running again.

The image also records, as the board saw them, the tick the jet valve last closed and the last
tick an axis moved: how fast the machine reached a safe state after a fault is read there, in
ticks, whichever process reacted (fault injection, `cnc.faultinject`).
"""

from __future__ import annotations

import logging
import os
import time

from ..config import MachineConfig
from ..dataserver import SharedArea
from ..layout import HIST_BINS, ClockKind, Proc
from .board import BoardInputs, DigitalOut, IOBoard
from .clock import RealtimeClock, VirtualClock
from .timers import TimerClient

log = logging.getLogger(__name__)

STILL_MM_S = 1.0  # an axis slower than this (by its encoder, over one tick) stands still


class HardwareServer:
    """The base-tick loop around one board. `run()` returns when shutdown is commanded."""

    def __init__(
        self,
        config: MachineConfig,
        area: SharedArea,
        board: IOBoard,
        clock: RealtimeClock | VirtualClock,
        clients: list[TimerClient],
        clock_kind: ClockKind,
    ) -> None:
        self.config, self.board, self.clock, self.clients = config, board, clock, clients
        self.n = len(config.axis_names)
        self.period_s = config.timing.period_s
        self.watchdog_limit = config.timing.watchdog_missed_ticks
        self.client_timeout_s = config.timing.virtual_client_timeout_s
        self.hw = area.writer("hw")
        self.hw.load_current()
        self.servo = area.reader("servo")
        self.command = area.reader("command")
        self.supervisor = area.reader("supervisor")
        self.sim = area.reader("sim")
        self.sim_block = area.blocks["sim"]
        timing = area.blocks["hw_timing"].array[0]
        self.hist, self.timing = timing["hist"], area.blocks["hw_timing"].array
        beat = area.blocks["heartbeat"].array[0]
        self.beat = beat["beat"]
        beat["pid"][Proc.HARDWARE] = os.getpid()
        self.inputs = BoardInputs(self.n)
        self.hw.set("clock_kind", int(clock_kind))

    def run(self) -> None:
        self.clock.start()
        idx = self.hw.layout.index
        s_idx = self.servo.layout.index
        i_speed, i_enable, i_dout = s_idx["speed_cmd_v"], s_idx["drive_enable_mask"], s_idx["digital_out"]
        i_stick, i_sticks = s_idx["tick"], s_idx["ticks_processed"]
        i_reset = self.command.layout.index["reset_seq"]
        s_idx = self.supervisor.layout.index
        i_shutdown, i_safe, i_until = s_idx["shutdown"], s_idx["safe_state"], s_idx["virtual_run_until"]
        v = self.hw.values
        i_tick, i_ttime, i_wtime = idx["tick"], idx["tick_time_ns"], idx["wake_time_ns"]
        i_enc, i_ilc, i_ils, i_ain = idx["encoder_counts"], idx["index_latch_counts"], idx["index_latch_seq"], idx["axis_inputs"]
        i_din, i_dout_rb = idx["digital_in"], idx["digital_out"]
        i_trip, i_missed, i_trip_tick = idx["watchdog_tripped"], idx["watchdog_missed"], idx["watchdog_trip_tick"]
        i_missed_total, i_late, i_safe_rb = idx["servo_missed_total"], idx["late_ticks"], idx["safe_state"]
        i_reset_ack = idx["reset_seq"]
        i_jet_off, i_moved = idx["jet_off_tick"], idx["last_motion_tick"]
        still_counts = [STILL_MM_S * self.period_s / a.encoder_resolution_mm for a in self.config.axes]
        axes = range(self.n)
        jet_was_on, last_counts = False, [0] * self.n
        tick = v[i_tick]
        last_reset = v[i_reset_ack] = self.command.read()[0][i_reset]
        sim_seq = -1
        inputs, board = self.inputs, self.board
        clients = [(c, c.divisor) for c in self.clients]
        hist, last_bin = self.hist, HIST_BINS - 1
        while True:
            if self.clock.synchronous:
                self._gate(tick, i_until, i_shutdown)
            deadline, woke = self.clock.wait()
            cmd, _ = self.command.read()
            sup, _ = self.supervisor.read()
            if sup[i_shutdown] & 1 << Proc.HARDWARE:
                board.safe_state()
                break
            servo, _ = self.servo.read()
            if self.sim_block.seq() != sim_seq:
                sim_seq = self.sim_block.seq()
                self._apply_sim(self.sim.read_dict())
            # watchdog: the servo should have finished the previous tick by now
            if servo[i_sticks] and servo[i_stick] != tick:
                v[i_missed] += 1
                v[i_missed_total] += 1
                if v[i_missed] >= self.watchdog_limit and not v[i_trip]:
                    v[i_trip], v[i_trip_tick] = 1, tick + 1
                    log.error("drive watchdog: servo missed %d ticks, drives disabled", v[i_missed])
            else:
                v[i_missed] = 0
            if cmd[i_reset] != last_reset:
                last_reset = v[i_reset_ack] = cmd[i_reset]
                if v[i_trip] and v[i_missed] == 0:
                    v[i_trip] = 0
            safe = bool(v[i_trip] or sup[i_safe])
            if safe:
                board.safe_state()
            else:
                board.write_outputs(list(servo[i_speed]), servo[i_enable], servo[i_dout])
            board.advance(self.period_s)
            board.read_inputs(inputs)
            tick += 1
            counts = inputs.encoder_counts
            for i in axes:
                if abs(counts[i] - last_counts[i]) > still_counts[i]:
                    v[i_moved] = tick
                    break
            last_counts = list(counts)
            jet_on = bool(inputs.digital_out & DigitalOut.JET_VALVE)
            if jet_was_on and not jet_on:
                v[i_jet_off] = tick
            jet_was_on = jet_on
            v[i_tick], v[i_ttime], v[i_wtime] = tick, deadline, woke
            v[i_enc], v[i_ilc], v[i_ils], v[i_ain] = (
                inputs.encoder_counts, inputs.index_latch_counts, inputs.index_latch_seq, inputs.axis_inputs,
            )
            v[i_din], v[i_dout_rb], v[i_safe_rb] = inputs.digital_in, inputs.digital_out, int(safe)
            v[i_late] = self.clock.late_ticks
            self.hw.publish()
            woken = [c for c, div in clients if tick % div == 0]
            for c in woken:
                if self.clock.synchronous:
                    while c.done.acquire(False):
                        pass  # a late `done` from a tick that timed out must not stand for this one
                c.wake.release()
            if self.clock.synchronous:
                for c in woken:
                    c.done.acquire(True, self.client_timeout_s)
            else:
                lat = (woke - deadline) // 1000
                hist[lat if lat < last_bin else last_bin] += 1
                self.timing["count"][0] += 1
                if woke - deadline > self.timing["max_ns"][0]:
                    self.timing["max_ns"][0] = woke - deadline
            self.beat[Proc.HARDWARE] = tick

    def _gate(self, tick: int, i_until: int, i_shutdown: int) -> None:
        """Virtual clock: hold time still while the commander has set a tick not to pass."""
        i_paused = self.hw.layout.index["paused"]
        while True:
            sup, _ = self.supervisor.read()
            until = sup[i_until]
            if not until or tick < until or sup[i_shutdown] & 1 << Proc.HARDWARE:
                if self.hw.values[i_paused]:
                    self.hw.values[i_paused] = 0
                    self.hw.publish()
                return
            if not self.hw.values[i_paused]:
                self.hw.values[i_paused] = 1
                self.hw.publish()
            time.sleep(0.0005)

    def _apply_sim(self, env: dict) -> None:
        """Pass the commander's simulated environment (e-stop, doors, faults, friction) to a sim board."""
        board = self.board
        if not hasattr(board, "set_estop"):
            return
        board.set_estop(bool(env["estop_pressed"]))
        board.set_doors(bool(env["doors_open"]))
        board.set_mains(not env["mains_off"])
        for i in range(self.n):
            board.set_drive_fault(i, bool(env["drive_fault_mask"] >> i & 1))
            board.set_friction_scale(i, env["friction_scale"][i])


def make_board(config: MachineConfig) -> IOBoard:
    """The board named by the machine file's `[board] kind`."""
    if config.board.kind == "sim":
        from .sim_board import SimBoard

        return SimBoard(config)
    raise ValueError(f"{config.source}: [board] kind: no board implementation {config.board.kind!r}")

