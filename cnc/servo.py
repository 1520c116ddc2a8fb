"""Servo: the XY position loop, a timer client of the hardware server at every base tick.

PI-P control as in the waterjet paper: the PI position loop runs here and outputs a speed
command; the P velocity loop is in the drive. Per axis

    u = velocity_ff * v_ref + accel_ff_s * a_ref + kp * e + ki * integral(e)    [mm/s]
    speed command = clamp(u * volts_per_mm_s, +-drive_full_scale_v)             [V]

with e = commanded - actual. The acceleration feed-forward makes up for the drive's lag
and the one-tick output delay (the command computed at tick k reaches the drive at k+1),
which is what keeps the following error small on curves rather than only on straights.

Each tick: read the hardware image, take the next setpoint (hold position when none is
commanded; count an underrun when the FIFO runs dry in the middle of a motion), check
interlocks, soft limits (on homed axes) and the following error, compute and publish (and,
while tracing is on, append the tick to the trace ring). Any trip sets the
speed commands to 0, disables the drives, closes the jet and records why; it is latched
until a reset. The servo counts its own ticks against the hardware tick counter
(QMotor 2.0's sequence counter) to detect overruns.
"""

from __future__ import annotations

import logging
import os
import time

from .config import MachineConfig
from .dataserver import SharedArea
from .fifo import OUTPUT_MASK, SetpointFifo, SetpointFlag
from .hw.board import AxisIn, DigitalIn
from .layout import HIST_BINS, Proc, ServoFault, ServoState
from .params import registry
from .trace import TraceRing

log = logging.getLogger(__name__)

_IN_MOTION = int(SetpointFlag.IN_MOTION)
# the FIFO ran dry mid-motion: the head stops where it is, and a jet left open would pierce there
_DRY_CLOSES = int(SetpointFlag.JET_ON) | int(SetpointFlag.ABRASIVE)
# the servo's list that holds each servo-owned control parameter, per axis
_PARAM_LISTS = {"kp_1_s": "kp", "ki_1_s2": "ki", "velocity_ff": "kv", "accel_ff_s": "ka",
                "integral_limit_mm_s": "i_lim", "following_error_limit_mm": "fe_lim"}


class Servo:
    """One instance per controller; `tick()` is the whole control step."""

    def __init__(
        self, config: MachineConfig, area: SharedArea, fifo: SetpointFifo, record_latency: bool, trace: TraceRing | None = None
    ) -> None:
        self.config, self.fifo, self.trace = config, fifo, trace
        self.axes = config.axes
        self.n = n = len(self.axes)
        self.dt = config.timing.period_s
        self.record_latency = record_latency
        self.out = area.writer("servo")
        self.out.load_current()
        self.hw = area.reader("hw")
        self.command = area.reader("command")
        self.motion = area.reader("motion")
        t = area.blocks["servo_timing"].array
        self.timing, self.hist = t, t[0]["hist"]
        hb = area.blocks["heartbeat"].array[0]
        self.beat = hb["beat"]
        hb["pid"][Proc.SERVO] = os.getpid()
        # per-axis constants, as plain floats for the tick path
        self.res = [a.encoder_resolution_mm for a in self.axes]
        self.kp = [a.kp_1_s for a in self.axes]
        self.ki = [a.ki_1_s2 for a in self.axes]
        self.kv = [a.velocity_ff for a in self.axes]
        self.ka = [a.accel_ff_s for a in self.axes]
        self.i_lim = [a.integral_limit_mm_s for a in self.axes]
        self.vpm = [a.volts_per_mm_s for a in self.axes]
        self.vmax = [a.drive_full_scale_v for a in self.axes]
        self.fe_lim = [a.following_error_limit_mm for a in self.axes]
        self.lo = [a.travel_min_mm for a in self.axes]
        self.hi = [a.travel_max_mm for a in self.axes]
        # loop state
        self.integral = [0.0] * n
        self.v_prev = [0.0] * n
        self.last_flags = 0
        self.dry = False  # the FIFO ran dry during a motion and nothing came since
        self.last_tick = 0
        self.first = True
        ix = self.out.layout.index
        self._i = {k: ix[k] for k in ix}
        hx = self.hw.layout.index
        self._h_tick, self._h_ttime = hx["tick"], hx["tick_time_ns"]
        self._h_enc, self._h_ain, self._h_din = hx["encoder_counts"], hx["axis_inputs"], hx["digital_in"]
        self._h_trip, self._h_safe, self._h_reset = hx["watchdog_tripped"], hx["safe_state"], hx["reset_seq"]
        cx = self.command.layout.index
        self._c_enable, self._c_reset = cx["servo_enable"], cx["reset_seq"]
        self._c_inhibit, self._c_force = cx["output_inhibit"], cx["output_force"]
        # the supervisor's safe state reaches the servo through the hardware image (the hardware
        # server acts on it earlier in the same tick); tracing is one 4-byte read of its block
        sup = area.blocks["supervisor"]
        at = sup.offset + sup.layout.dtype.fields["trace_enable"][1]
        self._trace_cell = sup.buf[at:at + 4].cast("I")
        # control parameters: one 8-byte read per tick tells whether the gateway wrote new ones
        self.params = area.reader("params")
        block = area.blocks["params"]
        at = block.offset + block.layout.dtype.fields["change"][1]
        self._params_change_cell = block.buf[at:at + 8].cast("Q")
        self._param_slots = [(_PARAM_LISTS[s.key], self.config.axis_names.index(s.path[1]), s.index)
                             for s in registry(config) if s.owner == "servo"]
        mx = self.motion.layout.index
        self._m_ref = (mx["position_ref_seq"], mx["position_ref_mask"], mx["position_ref_counts"], mx["position_ref_mm"])
        # one 8-byte read per tick tells whether a reference waits; the block is read only then
        block = area.blocks["motion"]
        at = block.offset + block.layout.dtype.fields["position_ref_seq"][1]
        self._ref_seq_cell = block.buf[at:at + 8].cast("Q")
        v = self.out.values
        if self._params_change_cell[0]:
            self._apply_params(v[self._i["tick"]])  # a restarted servo takes the values in force, not the file's
        if v[self._i["ticks_processed"]]:
            # a restarted servo: the position it held is not known to be the one the planner expects
            self._trip(ServoFault.RESTARTED, -1, 0.0, v[self._i["tick"]])
        else:
            v[self._i["reset_seq"]] = self.command.read()[0][self._c_reset]

    # -- the control step ----------------------------------------------------------------
    def tick(self) -> None:
        t0 = time.monotonic_ns()
        hw, _ = self.hw.read()
        cmd, _ = self.command.read()
        v, I, n = self.out.values, self._i, self.n
        tick = hw[self._h_tick]
        if not self.first and tick <= self.last_tick:
            # A late servo can read the image of the next tick before that tick's wake-up
            # arrives; the wake-up then finds a tick already done. Running it again would
            # take one setpoint too many (a following error of one period's travel).
            return
        steps = 1
        if not self.first and tick > self.last_tick + 1:
            steps = tick - self.last_tick
            v[I["overruns"]] += steps - 1
        self.first = False
        self.last_tick = tick
        if self._params_change_cell[0] != v[I["params_change"]]:
            self._apply_params(tick)  # at the tick boundary: this whole tick runs with the new values
        enc = hw[self._h_enc]
        offset = v[I["position_offset_mm"]]
        actual = [enc[i] * self.res[i] + offset[i] for i in range(n)]
        state = v[I["state"]]
        if self._ref_seq_cell[0] != v[I["position_ref_seq"]] and state != ServoState.TRACKING:
            actual = self._apply_reference(self.motion.read()[0], enc, actual)

        # A reset is acted on once the hardware server, upstream in the tick, has acted on it:
        # the image then shows the watchdog and safe state as they are after the reset.
        if cmd[self._c_reset] != v[I["reset_seq"]] and hw[self._h_reset] == cmd[self._c_reset]:
            v[I["reset_seq"]] = cmd[self._c_reset]
            if state == ServoState.FAULT:
                state = self._clear_fault(actual)

        if state != ServoState.FAULT:
            fault = self._interlock(hw, cmd)
            if fault is not None:
                self._trip(fault[0], fault[1], 0.0, tick)
                state = ServoState.FAULT

        if state == ServoState.FAULT:
            self._open_loop(actual)
            self.fifo.flush()
        elif not cmd[self._c_enable]:
            state = ServoState.DISABLED
            self._open_loop(actual)
            self.fifo.flush()  # setpoints made for a closed loop must not run when the drives come back
        else:
            if state == ServoState.DISABLED:
                self._open_loop(actual)  # close the loop where the table is, whatever was commanded before
            state = self._close_loop(actual, tick, steps)

        if cmd[self._c_inhibit] or cmd[self._c_force]:
            # the commander's word on the outputs: inhibit wins at once (jet off before the stop), force only at rest
            dout = v[I["digital_out"]] | (cmd[self._c_force] if state == ServoState.HOLDING else 0)
            v[I["digital_out"]] = dout & ~cmd[self._c_inhibit] & OUTPUT_MASK
        v[I["state"]] = state
        v[I["tick"]] = tick
        v[I["actual_mm"]] = actual
        v[I["ticks_processed"]] += 1
        v[I["loop_ns"]] = time.monotonic_ns() - t0
        self.out.publish()
        latency = time.monotonic_ns() - hw[self._h_ttime] if self.record_latency else 0
        if self._trace_cell[0] and self.trace is not None:
            self.trace.write(
                tick, v[I["commanded_mm"]], actual, v[I["commanded_velocity_mm_s"]], v[I["speed_cmd_v"]],
                v[I["setpoint_flags"]], v[I["setpoint_segment"]], v[I["setpoint_line"]], self.fifo.fill(), latency,
            )
        if self.record_latency:
            self._record_latency(latency)
        self.beat[Proc.SERVO] = tick

    def _close_loop(self, actual: list[float], tick: int, steps: int) -> int:
        """One closed-loop step; after an overrun of `steps - 1` ticks the setpoints of the
        skipped ticks are consumed too, so the commanded path stays locked to time."""
        v, I, n, dt = self.out.values, self._i, self.n, self.dt * steps
        rec = self.fifo.pop()
        for _ in range(steps - 1):
            newer = self.fifo.pop()
            if newer is None:
                break
            rec = newer
        commanded = v[I["commanded_mm"]]
        if rec is not None:
            pos, vel, flags = rec[:n], rec[n : 2 * n], rec[2 * n]
            homed = v[I["homed_mask"]]
            for i in range(n):
                # soft limits hold once an axis is homed: before, its position means nothing
                # (and homing itself travels onto the switch beyond the travel end)
                if homed >> i & 1 and not self.lo[i] <= pos[i] <= self.hi[i]:
                    self._trip(ServoFault.SOFT_LIMIT, i, pos[i], tick)
                    self._open_loop(actual)
                    self.fifo.flush()
                    return ServoState.FAULT
            commanded, velocity = list(pos), list(vel)
            self.dry = False
            v[I["setpoint_flags"]], v[I["setpoint_segment"]], v[I["setpoint_line"]] = flags, rec[2 * n + 1], rec[2 * n + 2]
            self.last_flags = flags
        else:
            if self.last_flags & _IN_MOTION:
                v[I["underruns"]] += 1
                if not self.dry:
                    v[I["underrun_tick"]] = tick
                self.dry = True
                self.last_flags &= ~_DRY_CLOSES
            velocity = [0.0] * n
            flags = self.last_flags & ~_IN_MOTION
        errors, speed = [0.0] * n, [0.0] * n
        fe_max = v[I["max_following_error_mm"]]
        for i in range(n):
            e = commanded[i] - actual[i]
            errors[i] = e
            if abs(e) > fe_max[i]:
                fe_max[i] = abs(e)
            if abs(e) > self.fe_lim[i]:
                v[I["following_error_mm"]] = errors
                self._trip(ServoFault.FOLLOWING_ERROR, i, e, tick)
                self._open_loop(actual)
                self.fifo.flush()
                return ServoState.FAULT
            integ = self.integral[i] + e * dt
            lim = self.i_lim[i] / self.ki[i] if self.ki[i] > 0.0 else 0.0
            integ = lim if integ > lim else -lim if integ < -lim else integ
            self.integral[i] = integ
            accel = (velocity[i] - self.v_prev[i]) / dt
            self.v_prev[i] = velocity[i]
            u = self.kv[i] * velocity[i] + self.ka[i] * accel + self.kp[i] * e + self.ki[i] * integ
            volts = u * self.vpm[i]
            vmax = self.vmax[i]
            speed[i] = vmax if volts > vmax else -vmax if volts < -vmax else volts
        v[I["commanded_mm"]] = commanded
        v[I["commanded_velocity_mm_s"]] = velocity
        v[I["following_error_mm"]] = errors
        v[I["max_following_error_mm"]] = fe_max
        v[I["speed_cmd_v"]] = speed
        v[I["drive_enable_mask"]] = (1 << n) - 1
        v[I["digital_out"]] = flags & OUTPUT_MASK
        return ServoState.TRACKING if flags & _IN_MOTION else ServoState.HOLDING

    def _apply_params(self, tick: int) -> None:
        """Take the control parameters in force from the params block (its writer, the gateway,
        has checked them); the tick they apply from is published with their change number."""
        values, _ = self.params.read()
        block = self.params.layout.index
        slots = values[block["values"]]
        for attr, axis, slot in self._param_slots:
            getattr(self, attr)[axis] = float(slots[slot])
        v, I = self.out.values, self._i
        v[I["params_change"]], v[I["params_tick"]] = values[block["change"]], tick

    def _apply_reference(self, ref: tuple, enc: tuple, actual: list[float]) -> list[float]:
        """Homing: `position_ref_counts` of the masked axes is `position_ref_mm`. Applied only while
        not following a motion; the commanded position becomes the new actual one, so nothing jumps."""
        v, I = self.out.values, self._i
        i_seq, i_mask, i_counts, i_mm = self._m_ref
        mask, counts, mm = ref[i_mask], ref[i_counts], ref[i_mm]
        offset = v[I["position_offset_mm"]]
        commanded = v[I["commanded_mm"]]
        for i in range(self.n):
            if mask >> i & 1:
                shift = (mm[i] - counts[i] * self.res[i]) - offset[i]
                offset[i] += shift
                actual[i] += shift
                commanded[i] = actual[i]
                self.integral[i] = 0.0
        v[I["position_offset_mm"]] = offset
        v[I["commanded_mm"]] = commanded
        v[I["homed_mask"]] |= mask
        v[I["position_ref_seq"]] = ref[i_seq]
        return actual

    def close(self) -> None:
        """Let go of the views into shared memory (before the segment is closed)."""
        self._ref_seq_cell.release()
        self._trace_cell.release()
        self._params_change_cell.release()

    def _interlock(self, hw: tuple, cmd: tuple) -> tuple[ServoFault, int] | None:
        """Conditions that trip the servo whatever it is doing."""
        if not hw[self._h_din] & DigitalIn.ESTOP_OK:
            return ServoFault.ESTOP, -1
        if hw[self._h_trip]:
            return ServoFault.WATCHDOG, -1
        if hw[self._h_safe]:
            return ServoFault.SAFE_STATE, -1
        ain = hw[self._h_ain]
        for i in range(self.n):
            if ain[i] & (AxisIn.LIMIT_MIN | AxisIn.LIMIT_MAX):
                return ServoFault.HARD_LIMIT, i
            if cmd[self._c_enable] and not ain[i] & AxisIn.DRIVE_READY:
                return ServoFault.DRIVE_FAULT, i
        return None

    def _trip(self, fault: ServoFault, axis: int, value: float, tick: int) -> None:
        v, I = self.out.values, self._i
        v[I["state"]] = ServoState.FAULT
        v[I["fault"]], v[I["fault_axis"]], v[I["fault_value"]], v[I["fault_tick"]] = int(fault), axis, value, tick
        self.last_flags = 0

    def _clear_fault(self, actual: list[float]) -> int:
        v, I = self.out.values, self._i
        v[I["fault"]], v[I["fault_axis"]], v[I["fault_value"]] = int(ServoFault.NONE), -1, 0.0
        v[I["max_following_error_mm"]] = [0.0] * self.n
        self._open_loop(actual)
        return ServoState.DISABLED

    def _open_loop(self, actual: list[float]) -> None:
        """Speed 0, drives off, outputs off; the commanded position follows the actual one."""
        v, I, n = self.out.values, self._i, self.n
        v[I["speed_cmd_v"]] = [0.0] * n
        v[I["drive_enable_mask"]] = 0
        v[I["digital_out"]] = 0
        v[I["commanded_mm"]] = list(actual)
        v[I["commanded_velocity_mm_s"]] = [0.0] * n
        v[I["following_error_mm"]] = [0.0] * n
        self.integral = [0.0] * n
        self.v_prev = [0.0] * n
        self.last_flags = 0

    def _record_latency(self, ns: int) -> None:
        b = ns // 1000
        self.hist[b if b < HIST_BINS - 1 else HIST_BINS - 1] += 1
        t = self.timing
        t["count"][0] += 1
        if ns > t["max_ns"][0]:
            t["max_ns"][0] = ns
