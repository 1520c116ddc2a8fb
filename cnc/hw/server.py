"""Hardware server: owns the I/O board and produces the base tick.

Each tick (`step`): write the servo's last outputs to the board (or bring the board to rest
itself, below), advance the board to the next sample, read its inputs, bump the tick sequence
counter, publish the hardware image; then the timer clients due on this tick are woken. Nothing
on this path waits: the blocks it reads are read with `read_nowait`.

The drive watchdog lives here, next to the board: when the servo has missed
`watchdog_missed_ticks` consecutive ticks (or left its block mid-write), the watchdog trips.
The jet closes at once, and the hardware server stops the axes itself rather than letting them
coast: it ramps the servo's last speed commands down to zero, jerk-limited within the axes'
deceleration (`cnc.brake.StopProfile` on the speed vector, so the table stops along its current
direction), through the drives' own velocity loops; then the board goes to its safe state
(speed 0, drives off, outputs off). The supervisor's safe state (a servo process lost) is
handled the same way; a shutdown goes to the safe state at once. A trip is latched in the
hardware image, where the supervisor and the servo see it, until a reset from the commander that
was asked for at or after the trip, once the ramp has run out and the servo runs again.

Defence in depth: while the board's own inputs show the e-stop circuit open, the mains off or a
door open, the hardware server drops the jet and abrasive outputs whatever the servo wrote.

The image also records, as the board saw them, the tick the jet valve last closed and the last
tick an axis moved: how fast the machine reached a safe state after a fault is read there, in
ticks, whichever process reacted (fault injection, `cnc.sim.faultinject`).
"""

from __future__ import annotations

import logging
import math
import os
import time

from ..brake import StopProfile
from ..config import MachineConfig
from ..data.dataserver import SharedArea
from ..data.layout import HIST_BINS, ClockKind, Proc
from .board import BoardInputs, DigitalIn, DigitalOut, IOBoard
from .clock import RealtimeClock, VirtualClock
from .timers import TimerClient

log = logging.getLogger(__name__)

STILL_MM_S = 1.0  # an axis slower than this (by its encoder, over one tick) stands still
_JET_BITS = int(DigitalOut.JET_VALVE | DigitalOut.ABRASIVE)
_SAFE_INPUTS = int(DigitalIn.ESTOP_OK | DigitalIn.DOORS_CLOSED | DigitalIn.MAINS_ON)
#: virtual clock: how long after it pauses the server looks for the next tick closely (a step of
#: `Supervisor.run_ticks` follows within this), before it looks every half millisecond
GATE_POLL_NS = 2_000_000


class SpeedRamp:
    """The hardware server's own stop: the last speed commands scaled down along a jerk-limited
    stop profile, all axes by the same factor (the table stops along its current direction)."""

    def __init__(self, config: MachineConfig, speed_cmd_v: list[float], enable_mask: int) -> None:
        self.vpm = [a.volts_per_mm_s for a in config.axes]
        self.accel_ff = [a.accel_ff_s for a in config.axes]  # leads the drives' lag, as the servo's feed-forward does
        mm_s = [v / k for v, k in zip(speed_cmd_v, self.vpm)]
        speed = math.sqrt(sum(x * x for x in mm_s))
        self.direction = [x / speed for x in mm_s] if speed > 0.0 else [0.0] * len(mm_s)
        self.profile = StopProfile(speed, 0.0, min(a.max_accel_mm_s2 for a in config.axes),
                                   min(a.max_jerk_mm_s3 for a in config.axes))
        self.enable_mask = enable_mask
        self.dt = config.timing.period_s
        self.t = 0.0

    @property
    def done(self) -> bool:
        return self.t >= self.profile.duration

    def next_volts(self) -> list[float]:
        self.t += self.dt
        _, v, a = self.profile.at(self.t)
        return [d * (v + ka * a) * k for d, ka, k in zip(self.direction, self.accel_ff, self.vpm)]


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
        board.arm_output_watchdog(config.board.output_watchdog_ms / 1000.0)
        idx, s_idx = self.hw.layout.index, self.servo.layout.index
        c_idx, sup_idx = self.command.layout.index, self.supervisor.layout.index
        self._i = idx
        self._s = (s_idx["speed_cmd_v"], s_idx["drive_enable_mask"], s_idx["digital_out"], s_idx["tick"],
                   s_idx["ticks_processed"])
        self._c = (c_idx["reset_seq"], c_idx["reset_tick"], c_idx["token"])
        self._sup = (sup_idx["shutdown"], sup_idx["safe_state"], sup_idx["virtual_run_until"])
        self.still_counts = [STILL_MM_S * self.period_s / a.encoder_resolution_mm for a in config.axes]
        cmd, _ = self.command.read()
        v = self.hw.values
        v[idx["reset_seq"]], v[idx["commander_token"]] = cmd[self._c[0]], cmd[self._c[2]]
        self.jet_was_on, self.last_counts = False, [0] * self.n
        self.sim_seq = -1
        self.ramp: SpeedRamp | None = None
        # what the board was last given (speed commands, drive enables): a ramp starts from these, not from
        # the servo's block, which a servo restarted before this server's next tick has already zeroed
        self.applied: tuple[list[float], int] = ([0.0] * self.n, 0)
        self.din = _SAFE_INPUTS

    def run(self) -> None:
        self.clock.start()
        i_until, i_shutdown = self._sup[2], self._sup[0]
        # each client with its process's bit in the supervisor's shutdown word
        clients = [(c, c.divisor, 1 << Proc[c.name.upper()]) for c in self.clients]
        hist, last_bin = self.hist, HIST_BINS - 1
        tick_i = self._i["tick"]
        stopped = 0  # the shutdown word: processes told to stop
        while True:
            if self.clock.synchronous:
                stopped = self._gate(self.hw.values[tick_i], i_until, i_shutdown)
            deadline, woke = self.clock.wait()
            if not self.step(deadline, woke):
                break
            tick = self.hw.values[tick_i]
            woken = [(c, bit) for c, div, bit in clients if tick % div == 0]
            for c, _ in woken:
                if self.clock.synchronous:
                    while c.done.acquire(False):
                        pass  # a late `done` from a tick that timed out must not stand for this one
                c.wake.release()
            if self.clock.synchronous:
                last = woken[-1][0] if woken else None
                for c, bit in woken:
                    if not stopped & bit:  # a process told to stop answers no more ticks: time goes on without it
                        # polled only for the last: the others are waited for while the later ones still
                        # work, when a polling server would take a CPU one of them needs
                        c.wait_done(self.client_timeout_s, poll=c is last)
            else:
                lat = (woke - deadline) // 1000
                hist[lat if lat < last_bin else last_bin] += 1
                self.timing["count"][0] += 1
                if woke - deadline > self.timing["max_ns"][0]:
                    self.timing["max_ns"][0] = woke - deadline
            self.beat[Proc.HARDWARE] = tick

    def step(self, deadline: int, woke: int) -> bool:
        """One base tick of the board; False (and the board safe) when shutdown is commanded."""
        idx, v, board, inputs = self._i, self.hw.values, self.board, self.inputs
        i_speed, i_enable, i_dout, i_stick, i_sticks = self._s
        i_shutdown, i_safe, _ = self._sup
        sup, _ = self.supervisor.read_nowait()
        if sup[i_shutdown] & 1 << Proc.HARDWARE:
            board.safe_state()
            return False
        cmd, _ = self.command.read_nowait()
        servo, servo_whole = self.servo.read_nowait()
        if self.sim_block.seq() != self.sim_seq:
            env, whole = self.sim.read_nowait()
            if whole:
                self.sim_seq = self.sim_block.seq()
                self._apply_sim(env)
        tick = v[idx["tick"]]
        # watchdog: the servo should have finished the previous tick by now (and not be stuck mid-write)
        if servo[i_sticks] and (servo[i_stick] != tick or not servo_whole):
            v[idx["watchdog_missed"]] += 1
            v[idx["servo_missed_total"]] += 1
            if v[idx["watchdog_missed"]] >= self.watchdog_limit and not v[idx["watchdog_tripped"]]:
                v[idx["watchdog_tripped"]], v[idx["watchdog_trip_tick"]] = 1, tick + 1
                log.error("drive watchdog: servo missed %d ticks, the axes are brought to rest", v[idx["watchdog_missed"]])
        else:
            v[idx["watchdog_missed"]] = 0
        self._serve_reset(cmd, bool(sup[i_safe]))
        stop = bool(v[idx["watchdog_tripped"]] or sup[i_safe])
        if stop and self.ramp is None:
            self.ramp = SpeedRamp(self.config, *self.applied)
        elif not stop and self.ramp is not None and self.ramp.done:
            self.ramp = None  # a ramp once begun runs out, whatever is restarted meanwhile
        safe = False
        if self.ramp is not None and not self.ramp.done:
            board.write_outputs(self.ramp.next_volts(), self.ramp.enable_mask, 0)
        elif self.ramp is not None:
            board.safe_state()
            safe = True
        else:
            dout = servo[i_dout]
            if self.din & _SAFE_INPUTS != _SAFE_INPUTS:
                dout &= ~_JET_BITS
            self.applied = (list(servo[i_speed]), servo[i_enable])
            board.write_outputs(*self.applied, dout)
        board.advance(self.period_s)
        board.read_inputs(inputs)
        self.din = inputs.digital_in
        tick += 1
        counts = inputs.encoder_counts
        for i in range(self.n):
            if abs(counts[i] - self.last_counts[i]) > self.still_counts[i]:
                v[idx["last_motion_tick"]] = tick
                break
        self.last_counts = list(counts)
        jet_on = bool(inputs.digital_out & DigitalOut.JET_VALVE)
        if self.jet_was_on and not jet_on:
            v[idx["jet_off_tick"]] = tick
        self.jet_was_on = jet_on
        v[idx["tick"]], v[idx["tick_time_ns"]], v[idx["wake_time_ns"]] = tick, deadline, woke
        v[idx["encoder_counts"]], v[idx["index_latch_counts"]] = inputs.encoder_counts, inputs.index_latch_counts
        v[idx["index_latch_seq"]], v[idx["axis_inputs"]] = inputs.index_latch_seq, inputs.axis_inputs
        v[idx["digital_in"]], v[idx["digital_out"]], v[idx["safe_state"]] = inputs.digital_in, inputs.digital_out, int(safe)
        v[idx["braking"]] = int(self.ramp is not None and not self.ramp.done)
        v[idx["late_ticks"]] = self.clock.late_ticks
        self.hw.publish()
        return True

    def terminate(self) -> None:
        """Terminated from outside (SIGTERM, the supervisor's end): the board safe first, then one last
        image that says so, for whoever reads it after this process is gone."""
        self.board.safe_state()
        self.board.read_inputs(self.inputs)
        idx, v = self._i, self.hw.values
        v[idx["digital_out"]], v[idx["safe_state"]] = self.inputs.digital_out, 1
        self.hw.publish()

    def _serve_reset(self, cmd: tuple, supervisor_safe: bool) -> None:
        """A reset from the commander clears a watchdog trip that is not newer than the request, once
        the servo runs on time again and the ramp has brought the axes to rest. Until then the
        request waits (this server's `reset_seq` stays behind the commander's, so the servo, which
        acts on a reset only once this server has, waits with it): a servo a tick late just when the
        reset comes, on a busy host, must not swallow the operator's reset. So does a reset while
        the supervisor still holds the board safe (`supervisor_safe`: a servo being restarted; it
        gives the board back once the new one runs): the servo would take it and clear nothing, the
        board being safe, and the operator would have to reset again. A trip newer than the
        request is not cleared by it. A new commander (another token) is a new baseline, not a
        request."""
        idx, v = self._i, self.hw.values
        i_reset, i_reset_tick, i_token = self._c
        if cmd[i_token] != v[idx["commander_token"]]:
            v[idx["commander_token"]], v[idx["reset_seq"]] = cmd[i_token], cmd[i_reset]
            return
        if cmd[i_reset] == v[idx["reset_seq"]] or supervisor_safe:
            return
        if v[idx["watchdog_tripped"]] and v[idx["watchdog_trip_tick"]] <= cmd[i_reset_tick]:
            ramping = self.ramp is not None and not self.ramp.done
            if v[idx["watchdog_missed"]] != 0 or ramping:
                return  # pending: served at the first tick the servo is on time with the axes at rest
            v[idx["watchdog_tripped"]] = 0
        v[idx["reset_seq"]] = cmd[i_reset]

    def _gate(self, tick: int, i_until: int, i_shutdown: int) -> int:
        """Virtual clock: hold time still while the commander has set a tick not to pass; returns
        the supervisor's shutdown word (the processes told to stop)."""
        i_paused = self.hw.layout.index["paused"]
        paused_at = 0
        while True:
            sup, _ = self.supervisor.read()
            until = sup[i_until]
            if not until or tick < until or sup[i_shutdown] & 1 << Proc.HARDWARE:
                if self.hw.values[i_paused]:
                    self.hw.values[i_paused] = 0
                    self.hw.publish()
                return int(sup[i_shutdown])
            if not self.hw.values[i_paused]:
                self.hw.values[i_paused] = 1
                self.hw.publish()
                paused_at = time.monotonic_ns()
            # a commander stepping the clock a tick at a time sets the next tick at once: look closely
            # for a moment (giving way to everyone else), then at a pace that costs nothing
            if time.monotonic_ns() - paused_at < GATE_POLL_NS:
                os.sched_yield()
            else:
                time.sleep(0.0005)

    def _apply_sim(self, values: tuple) -> None:
        """Pass the commander's simulated environment (e-stop, doors, faults, friction) to a sim board."""
        board = self.board
        if not hasattr(board, "set_estop"):
            return
        ix = self.sim.layout.index
        board.set_estop(bool(values[ix["estop_pressed"]]))
        board.set_doors(bool(values[ix["doors_open"]]))
        board.set_mains(not values[ix["mains_off"]])
        limits = values[ix["limit_switch_mask"]]
        for i in range(self.n):
            board.set_drive_fault(i, bool(values[ix["drive_fault_mask"]] >> i & 1))
            board.set_friction_scale(i, values[ix["friction_scale"]][i])
            board.force_limit_switch(i, bool(limits >> (2 * i) & 1), bool(limits >> (2 * i + 1) & 1))


def make_board(config: MachineConfig) -> IOBoard:
    """The board named by the machine file's `[board] kind`."""
    if config.board.kind == "sim":
        from .sim_board import SimBoard

        return SimBoard(config)
    raise ValueError(f"{config.source}: [board] kind: no board implementation {config.board.kind!r}")
