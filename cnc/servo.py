"""Servo: the XY position loop and the machine's interlocks, a timer client of the hardware server at every base tick.

PI-P control as in the waterjet paper: the PI position loop runs here and outputs a speed
command; the P velocity loop is in the drive. Per axis

    u = velocity_ff * v_ref + accel_ff_s * a_ref + kp * e + ki * integral(e)    [mm/s]
    speed command = clamp(u * volts_per_mm_s, +-drive_full_scale_v)             [V]

with e = commanded - actual. The acceleration feed-forward makes up for the drive's lag
and the one-tick output delay (the command computed at tick k reaches the drive at k+1),
which is what keeps the following error small on curves rather than only on straights.

Each tick: read the hardware image, the commander's block and the PLC's inputs without ever
waiting (`read_nowait`); evaluate the stop-cut causes (`cnc.interlock`) and hold the jet closed
while any is in effect; take the next setpoint of the current motion epoch (records of another
epoch are dropped: they were made before a trip, a stop or a reset); check the soft and hard
limits, the drives and the following error; compute and publish (and, while tracing is on,
append the tick to the trace ring).

Trips. An e-stop or a mains loss (category 0: the drives have no power to stop with) opens the
loop at once. Every other trip is a controlled stop (category 1): the jet closes in that tick,
the servo brings the axes to rest itself, jerk-limited, along the setpoints still queued (the
planner's path) or straight on where none are (`cnc.brake`), holds, then disables the drives;
its state is STOPPING meanwhile and FAULT after. A trip is latched until a reset from the same
commander that arrives once the stop has run out, with no stop-cut cause present, and that was
asked for after the commander saw the trip (`reset_trip_seq`: a trip that comes just after the
operator pressed reset stays latched). Every trip counts `trip_seq`, so the commander reports each one. The servo
counts its own ticks against the hardware tick counter (QMotor 2.0's sequence counter) to
detect overruns.
"""

from __future__ import annotations

import logging
import math
import os
import time
from typing import Callable

from .brake import PathBrake, PathPoint
from .config import MachineConfig
from .control.loader import build as build_program
from .control.pip import PIP
from .control.program import ControlInputs, ControlProgram, outputs_problem
from .data.dataserver import SharedArea
from .data.fifo import OUTPUT_MASK, SetpointFifo, SetpointFlag
from .hw.board import AxisIn, DigitalOut
from .interlock import CATEGORY_0, Interlock, fault_of
from .data.layout import HIST_BINS, Proc, ServoFault, ServoState
from .params import registry
from .data.trace import TraceRing

log = logging.getLogger(__name__)

_IN_MOTION = int(SetpointFlag.IN_MOTION)
_JET_BITS = int(DigitalOut.JET_VALVE | DigitalOut.ABRASIVE)
_JET_VALVE = int(DigitalOut.JET_VALVE)
_LIMITS = int(AxisIn.LIMIT_MIN | AxisIn.LIMIT_MAX)
_LIMIT_MIN, _LIMIT_MAX = int(AxisIn.LIMIT_MIN), int(AxisIn.LIMIT_MAX)
_READY = int(AxisIn.DRIVE_READY)
_CATEGORY_0 = int(CATEGORY_0)
_LAW_FAILED = -2  # `_control`: the control program failed this period (the fallback law computed it)
SETTLE_TICKS = 20  # after its stop the servo holds this long, closed loop, before the drives go off
STOP_FE_FACTOR = 4.0  # during its own stop an axis may lag this many following-error limits before its drive goes off
_EPOCH_MASK = 0xFFFF_FFFF  # a record's epoch field is 32 bits


class Servo:
    """One instance per controller; `tick()` is the whole control step."""

    def __init__(
        self, config: MachineConfig, area: SharedArea, fifo: SetpointFifo, record_latency: bool, trace: TraceRing | None = None,
        clock_ns: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        """`clock_ns`: the wall clock the interlocks judge other processes' signs of life by (a
        simulation that steps ticks itself passes its own)."""
        self.config, self.fifo, self.trace = config, fifo, trace
        self.clock_ns = clock_ns
        self.axes = config.axes
        self.names = config.axis_names
        self.n = n = len(self.axes)
        self.dt = config.timing.period_s
        self.record_latency = record_latency
        self.out = area.writer("servo")
        known = self.out.load_current()
        self.hw = area.reader("hw")
        self.command = area.reader("command")
        self.motion = area.reader("motion")
        self.plc = area.reader("plc")
        t = area.blocks["servo_timing"].array
        self.timing, self.hist = t, t[0]["hist"]
        hb = area.blocks["heartbeat"].array[0]
        self.beat, self.pids = hb["beat"], hb["pid"]
        hb["pid"][Proc.SERVO] = os.getpid()
        # per-axis constants, as plain floats for the tick path
        self.res = [a.encoder_resolution_mm for a in self.axes]
        self.vpm = [a.volts_per_mm_s for a in self.axes]
        self.vmax = [a.drive_full_scale_v for a in self.axes]
        self.fe_lim = [a.following_error_limit_mm for a in self.axes]
        self.lo = [a.travel_min_mm for a in self.axes]
        self.hi = [a.travel_max_mm for a in self.axes]
        self.tol = [a.soft_limit_tolerance_mm for a in self.axes]
        self.stop_accel = min(a.max_accel_mm_s2 for a in self.axes)
        self.stop_jerk = min(a.max_jerk_mm_s3 for a in self.axes)
        # the control law: the machine's control program (`cnc.control`), supervised from here; after it
        # failed, the servo's own PI-P of the machine file's gains brings the axes to rest until a reset
        self.program: ControlProgram = build_program(config)
        self.program_name = f"{config.control.program} ({type(self.program).__name__})"
        self.fallback: ControlProgram = PIP(config)
        self.law = self.program
        self.law_running = False
        self.inputs = ControlInputs(n)
        self.budget_ns = config.control.budget_share * self.dt * 1e9
        self.budget_overruns = config.control.budget_overruns
        self.over_budget = 0  # consecutive periods over the budget
        self.control_ns = 0  # the control program's CPU time in the last period it ran (for the trace)
        self.logs = self.program.log_variables
        self.log_values = [0.0] * sum(spec.size for spec in self.logs)  # flattened, for the trace
        ct = area.blocks["control_timing"].array
        self.control_timing, self.control_hist = ct, ct[0]["hist"]
        # loop state
        self.v_prev = [0.0] * n
        self.actual_prev: list[float] | None = None  # the encoders' position the period before (velocity estimate)
        self.last_flags = 0
        self.dry = False  # the FIFO ran dry during a motion and nothing came since
        self.last_tick = 0
        self.first = True
        self.brake: PathBrake | None = None
        self.released: set[int] = set()  # axes that could not follow the servo's own stop (`_run_brake`)
        self.settle = 0  # ticks held at rest after the servo's own stop
        self.force_ok = False  # the commander's forced outputs (jet test) rose while the axes held still
        self.force_blocked = False  # ... or were asked for while they did not: void until the commander asks again
        self.velocity_before = [0.0] * n  # the setpoint velocity before the current one (the stop's start acceleration)
        self.limits_prev = [0] * n
        ix = self.out.layout.index
        self._i = {k: ix[k] for k in ix}
        hx = self.hw.layout.index
        self._h_tick, self._h_ttime = hx["tick"], hx["tick_time_ns"]
        self._h_enc, self._h_ain, self._h_din = hx["encoder_counts"], hx["axis_inputs"], hx["digital_in"]
        self._h_trip, self._h_safe, self._h_reset = hx["watchdog_tripped"], hx["safe_state"], hx["reset_seq"]
        cx = self.cmd_index = self.command.layout.index
        self._c_enable, self._c_reset, self._c_reset_trips = cx["servo_enable"], cx["reset_seq"], cx["reset_trip_seq"]
        self._c_inhibit, self._c_force, self._c_token = cx["output_inhibit"], cx["output_force"], cx["token"]
        self._c_stop = cx["stop_seq"]
        self.plc_index = self.plc.layout.index
        sup = area.blocks["supervisor"]
        members = int(sup.array["members"][0])
        self.interlock = Interlock(config, members)
        self.commander_slot = Proc.LOGIC if members >> Proc.LOGIC & 1 else Proc.SUPERVISOR
        # the supervisor's safe state reaches the servo through the hardware image (the hardware
        # server acts on it earlier in the same tick); tracing is one 4-byte read of its block
        at = sup.offset + sup.layout.dtype.fields["trace_enable"][1]
        self._trace_cell = sup.buf[at:at + 4].cast("I")
        # control parameters: one 8-byte read per tick tells whether the gateway wrote new ones
        self.params = area.reader("params")
        block = area.blocks["params"]
        at = block.offset + block.layout.dtype.fields["change"][1]
        self._params_change_cell = block.buf[at:at + 8].cast("Q")
        self._param_slots = [self._param_slot(s) for s in registry(config) if s.owner == "servo"]
        mx = self.motion.layout.index
        self._m_ref = (mx["position_ref_seq"], mx["position_ref_mask"], mx["position_ref_counts"], mx["position_ref_mm"],
                       mx["position_ref_unhome"])
        # one 8-byte read per tick tells whether a reference waits; the block is read only then
        block = area.blocks["motion"]
        at = block.offset + block.layout.dtype.fields["position_ref_seq"][1]
        self._ref_seq_cell = block.buf[at:at + 8].cast("Q")
        self._i_epoch = 2 * n + 3  # a popped record's epoch
        v = self.out.values
        cmd, _ = self.command.read()
        if self._params_change_cell[0]:
            self._apply_params(v[self._i["tick"]])  # a restarted servo takes the values in force, not the file's
        if not known or v[self._i["ticks_processed"]]:
            # a restarted servo (or its block left torn): the position it held is not known to be the
            # one the planner expects, and nothing it was doing may go on
            v[self._i["motion_epoch"]] += 1
            self._trip(ServoFault.RESTARTED, -1, 0.0, v[self._i["tick"]], 0)
            v[self._i["state"]] = ServoState.FAULT
        v[self._i["reset_seq"]] = cmd[self._c_reset]
        v[self._i["commander_token"]] = cmd[self._c_token]
        self.stop_seen = cmd[self._c_stop]
        self.commanded = False  # the stop under way is the commander's (it ends holding, not tripped)

    # -- the control step ----------------------------------------------------------------
    def tick(self) -> None:
        t0 = time.monotonic_ns()
        hw, _ = self.hw.read_nowait()
        cmd, _ = self.command.read_nowait()
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
            v[I["overrun_last_ticks"]] = steps - 1
        self.first = False
        self.last_tick = tick
        self.control_ns = 0  # until the control program runs in this tick
        if self._params_change_cell[0] != v[I["params_change"]]:
            self._apply_params(tick)  # at the tick boundary: this whole tick runs with the new values
        enc = hw[self._h_enc]
        offset = v[I["position_offset_mm"]]
        actual = [enc[i] * self.res[i] + offset[i] for i in range(n)]
        state = v[I["state"]]
        if self._ref_seq_cell[0] != v[I["position_ref_seq"]] and state not in (ServoState.TRACKING, ServoState.STOPPING):
            actual = self._apply_reference(self.motion.read()[0], enc, actual)

        causes = self._causes(tick, self.clock_ns(), hw, cmd, state)
        state = self._serve_reset(hw, cmd, causes, state, actual, tick)
        state = self._supervise(hw, cmd, causes, state, actual, tick)

        if state == ServoState.FAULT:
            self._open_loop(actual)
            self.fifo.flush()
        elif state == ServoState.STOPPING:
            state = self._run_brake(hw, actual, tick, steps)
        elif not cmd[self._c_enable]:
            if state != ServoState.DISABLED:
                v[I["motion_epoch"]] += 1  # whatever was queued was made for a closed loop that is now open
            state = ServoState.DISABLED
            self._open_loop(actual)
            self.fifo.flush()
        else:
            if state == ServoState.DISABLED:
                self._open_loop(actual)  # close the loop where the table is, whatever was commanded before
            state = self._close_loop(hw, actual, tick, steps)

        self._outputs(cmd, causes, state)
        if v[I["digital_out"]] & _JET_VALVE:  # where the jet cuts, exact to the tick (cnc.planner.recovery)
            v[I["jet_on_ticks"]] += 1
            v[I["jet_on_mm"]] = list(v[I["commanded_mm"]])  # a copy: a homing reference shifts commanded in place
            v[I["jet_on_segment"]], v[I["jet_on_line"]] = v[I["setpoint_segment"]], v[I["setpoint_line"]]
            v[I["jet_on_tick"]] = tick
        v[I["stop_causes"]] = causes
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
                self.control_ns, self.log_values,
            )
        if self.record_latency:
            self._record_latency(latency)
        self.beat[Proc.SERVO] = tick

    # -- interlocks, trips and reset -----------------------------------------------------
    def _causes(self, tick: int, now_ns: int, hw: tuple, cmd: tuple, state: int) -> int:
        """The stop-cut causes in effect (cnc.interlock), from the blocks as they are now."""
        il = self.interlock
        hw_din = hw[self._h_din]
        wall = time.monotonic_ns()  # the readers note when a block got stuck on this clock
        commander_dead = il.commander_watched and il.dead_writer(
            self.command.odd_since_ns, wall, int(self.pids[self.commander_slot]))
        plc = None
        plc_dead = False
        if il.plc_watched:
            plc, _ = self.plc.read_nowait()
            plc_dead = il.dead_writer(self.plc.odd_since_ns, wall, int(self.pids[Proc.PLC_LINK]))
        jet_open = bool(self._jet_wanted(cmd, state))
        return il.evaluate(tick, now_ns, hw_din, plc, self.plc_index, cmd, self.cmd_index, jet_open,
                           commander_dead, plc_dead)

    def _jet_wanted(self, cmd: tuple, state: int) -> int:
        """The jet bits the setpoints and the commander would open this tick (before the interlocks)."""
        if state not in (ServoState.HOLDING, ServoState.TRACKING):
            return 0
        bits = (self.last_flags & ~cmd[self._c_inhibit]) | (cmd[self._c_force] if self.force_ok else 0)
        return bits & _JET_BITS

    def _serve_reset(self, hw: tuple, cmd: tuple, causes: int, state: int, actual: list[float], tick: int) -> int:
        """A reset from the commander (its reset_seq advanced, and the hardware server has acted on
        it upstream in this tick) clears a latched trip if the trip is not newer than the request,
        its stop has run out and no stop-cut cause is in effect. A new commander (another token)
        starts a new baseline: its counters are not requests."""
        v, I = self.out.values, self._i
        token = cmd[self._c_token]
        if token != v[I["commander_token"]]:
            v[I["commander_token"]], v[I["reset_seq"]] = token, cmd[self._c_reset]
            if cmd[self._c_stop] < self.stop_seen:  # a new count (its block was unknown); a continued one that
                self.stop_seen = cmd[self._c_stop]  # moved on asks for a stop, acted on below
            return state
        if cmd[self._c_reset] == v[I["reset_seq"]] or hw[self._h_reset] != cmd[self._c_reset]:
            return state
        v[I["reset_seq"]] = cmd[self._c_reset]
        if (state == ServoState.FAULT and v[I["trip_seq"]] <= cmd[self._c_reset_trips] and not causes
                and not hw[self._h_trip] and not hw[self._h_safe]):
            v[I["fault"]], v[I["fault_axis"]], v[I["fault_value"]], v[I["fault_causes"]] = int(ServoFault.NONE), -1, 0.0, 0
            v[I["max_following_error_mm"]] = [0.0] * self.n
            v[I["motion_epoch"]] += 1
            self._open_loop(actual)
            self.law = self.program  # a control program that failed gets its next chance with the next run
            return ServoState.DISABLED
        return state

    def _supervise(self, hw: tuple, cmd: tuple, causes: int, state: int, actual: list[float], tick: int) -> int:
        """Trips that do not depend on the setpoint: the board's side, the stop-cut causes, the
        drives and the hard limits."""
        ain = hw[self._h_ain]
        rising = -1
        for i in range(self.n):
            limits = ain[i] & _LIMITS
            if limits & ~self.limits_prev[i] and rising < 0:
                rising = i
            self.limits_prev[i] = limits
        if state == ServoState.FAULT:
            return state
        if hw[self._h_trip] or hw[self._h_safe]:  # the hardware server brakes on its own: hands off the outputs
            fault = ServoFault.WATCHDOG if hw[self._h_trip] else ServoFault.SAFE_STATE
            return self._hard_trip(fault, -1, 0.0, tick, causes, actual)
        if causes & _CATEGORY_0:
            return self._hard_trip(fault_of(causes & _CATEGORY_0), -1, 0.0, tick, causes, actual)
        if state == ServoState.STOPPING and self.commanded and causes:
            self._trip(fault_of(causes), -1, 0.0, tick, causes)  # the commander's stop runs on, and now latches
            self.commanded = False
        if cmd[self._c_stop] != self.stop_seen and cmd[self._c_token] == self.out.values[self._i["commander_token"]]:
            self.stop_seen = cmd[self._c_stop]
            state = self._commanded_stop(state)
        if state not in (ServoState.HOLDING, ServoState.TRACKING):
            return state
        if causes:
            return self._brake_trip(fault_of(causes), -1, 0.0, tick, causes, follow_path=True)
        for i in range(self.n):
            if not ain[i] & _READY:
                return self._brake_trip(ServoFault.DRIVE_FAULT, i, 0.0, tick, causes, follow_path=False)
        if rising >= 0:
            return self._brake_trip(ServoFault.HARD_LIMIT, rising, actual[rising], tick, causes, follow_path=False)
        return state

    def _hard_trip(self, fault: ServoFault, axis: int, value: float, tick: int, causes: int, actual: list[float]) -> int:
        """Category 0, or the hardware server has taken the outputs: drives off now."""
        v, I = self.out.values, self._i
        self.brake = None
        self._trip(fault, axis, value, tick, causes)
        v[I["motion_epoch"]] += 1
        self._open_loop(actual)
        self.fifo.flush()
        return ServoState.FAULT

    def _brake_trip(self, fault: ServoFault, axis: int, value: float, tick: int, causes: int, follow_path: bool) -> int:
        """Category 1: latch the fault, close the jet, and start the servo's own stop from the setpoint
        under way, along the queued path (or straight on, when the path itself is the fault)."""
        self._trip(fault, axis, value, tick, causes)
        self.commanded = False
        self._start_brake(follow_path)
        return ServoState.STOPPING

    def _start_brake(self, follow_path: bool) -> None:
        v, I, n = self.out.values, self._i, self.n
        position, velocity = list(v[I["commanded_mm"]]), list(v[I["commanded_velocity_mm_s"]])
        speed = math.sqrt(sum(x * x for x in velocity))
        accel_along = 0.0
        if speed > 0.0:
            accel_along = sum((velocity[i] - self.velocity_before[i]) / self.dt * velocity[i] / speed for i in range(n))
        source = _QueuedPath(self) if follow_path else _NoPath()
        self.brake = PathBrake(position, velocity, accel_along, self.stop_accel, self.stop_jerk, self.dt, source)
        self.settle = 0
        self.released = set()  # axes that could not follow this stop: their drives off, the others brake on
        v[I["trip_speed_mm_s"]] = speed
        v[I["brake_distance_mm"]] = 0.0
        v[I["brake_tick"]] = self.last_tick

    def _commanded_stop(self, state: int) -> int:
        """The commander stops the machine for an alarm of its own (a process lost, a timeout): the
        same controlled stop along the queued path, started in the tick that reads the request, but
        no trip: it ends holding, and what was queued is void."""
        v, I = self.out.values, self._i
        if state == ServoState.HOLDING:
            v[I["motion_epoch"]] += 1
            self.fifo.flush()
            return state
        if state != ServoState.TRACKING:
            return state
        self._start_brake(follow_path=True)
        self.commanded = True
        self.last_flags = 0
        self.force_ok, self.force_blocked = False, True
        return ServoState.STOPPING

    def _run_brake(self, hw: tuple, actual: list[float], tick: int, steps: int) -> int:
        """One tick of the servo's own stop: the brake's setpoint, closed loop; then hold, then FAULT
        (the commander's stop: HOLDING)."""
        v, I = self.out.values, self._i
        brake = self.brake
        if brake is None:  # a restarted servo never starts in STOPPING; a stop without a brake ends at once
            return self._finish_brake(actual)
        position, velocity = brake.step(steps)
        v[I["brake_distance_mm"]] = brake.s
        if brake.done:
            self.settle += steps
            if self.settle >= SETTLE_TICKS:
                return self._finish_brake(actual)
        ain = hw[self._h_ain]
        released = self.released
        lagging = self._control(position, velocity, actual, steps,
                                [bool(ain[i] & _READY) and i not in released for i in range(self.n)], STOP_FE_FACTOR, released)
        if lagging == _LAW_FAILED and self.commanded:  # the commander's stop goes on with the fallback, latched now
            self._trip(ServoFault.CONTROL_PROGRAM, -1, 0.0, tick, 0)
            self.commanded = False
        if lagging >= 0:
            # an axis cannot follow its own stop (seized, runaway): its drive goes off, from the next
            # period on, and the others go on braking under control (all drives off would let them
            # coast: a seized X at a corner left Y running 30 mm); all of them lagging: drives off
            released.add(lagging)
            if len(released) == self.n:
                log.error("servo: no axis can follow the controlled stop: drives off")
                return self._finish_brake(actual)
            log.error("servo: axis %s cannot follow the controlled stop: its drive off, the others brake on",
                      self.names[lagging].upper())
        v[I["digital_out"]] = 0
        return ServoState.STOPPING

    def _finish_brake(self, actual: list[float]) -> int:
        v, I = self.out.values, self._i
        self.brake = None
        v[I["motion_epoch"]] += 1  # setpoints pushed during the stop are void from here
        self.fifo.flush()
        if self.commanded:  # the commander's stop: the axes hold where they came to rest
            self.commanded = False
            v[I["commanded_velocity_mm_s"]] = [0.0] * self.n
            self.v_prev = [0.0] * self.n
            self.last_flags = 0
            return ServoState.HOLDING
        self._open_loop(actual)
        return ServoState.FAULT

    def _trip(self, fault: ServoFault, axis: int, value: float, tick: int, causes: int) -> None:
        v, I = self.out.values, self._i
        if fault == ServoFault.PUMP and axis < 0:  # the figure that says why: the pressure the tick read
            value = self.interlock.pressure_bar
        v[I["fault"]], v[I["fault_axis"]], v[I["fault_value"]], v[I["fault_tick"]] = int(fault), axis, value, tick
        v[I["fault_causes"]] = causes
        v[I["trip_fault"]], v[I["trip_axis"]], v[I["trip_value"]], v[I["trip_causes"]] = int(fault), axis, value, causes
        v[I["trip_seq"]] += 1
        v[I["trip_actual_mm"]] = list(v[I["actual_mm"]])
        self.last_flags = 0
        self.force_ok = False
        self.force_blocked = True

    # -- following the setpoints ---------------------------------------------------------
    def _close_loop(self, hw: tuple, actual: list[float], tick: int, steps: int) -> int:
        """One closed-loop step; after an overrun of `steps - 1` ticks the setpoints of the
        skipped ticks are consumed too, so the commanded path stays locked to time."""
        v, I, n = self.out.values, self._i, self.n
        rec = self._pop()
        for _ in range(steps - 1):
            newer = self._pop()
            if newer is None:
                break
            rec = newer
        commanded = list(v[I["commanded_mm"]])
        ain = hw[self._h_ain]
        if rec is not None:
            pos, velocity, flags = list(rec[:n]), list(rec[n: 2 * n]), rec[2 * n]
            fault = self._limits(pos, commanded, ain)
            if fault is not None:
                return self._brake_trip(fault[0], fault[1], fault[2], tick, 0, follow_path=False)
            commanded = pos
            self.dry = False
            v[I["setpoint_flags"]], v[I["setpoint_segment"]], v[I["setpoint_line"]] = flags, rec[2 * n + 1], rec[2 * n + 2]
            self.last_flags = flags
        else:
            if self.last_flags & _IN_MOTION:
                # the FIFO ran dry mid-motion: the head would stop dead where it is (and a jet left
                # open would drill there); the servo stops it itself, jerk-limited, straight on
                v[I["underruns"]] += 1
                if not self.dry:
                    v[I["underrun_tick"]] = tick
                self.dry = True
                return self._brake_trip(ServoFault.UNDERRUN, -1, 0.0, tick, 0, follow_path=False)
            velocity = [0.0] * n
            flags = self.last_flags & ~_IN_MOTION
            self.last_flags = flags
        lagging = self._control(commanded, velocity, actual, steps, [True] * n, 1.0)
        if lagging == _LAW_FAILED:  # stopped along the path by the fallback law: the alarm names the program
            return self._brake_trip(ServoFault.CONTROL_PROGRAM, -1, 0.0, tick, 0, follow_path=True)
        if lagging >= 0:
            return self._brake_trip(ServoFault.FOLLOWING_ERROR, lagging, v[I["following_error_mm"]][lagging], tick, 0,
                                    follow_path=True)
        v[I["digital_out"]] = flags & OUTPUT_MASK
        return ServoState.TRACKING if flags & _IN_MOTION else ServoState.HOLDING

    def _limits(self, pos: list[float], commanded: list[float], ain: tuple) -> tuple[ServoFault, int, float] | None:
        """Soft limits (homed axes; setpoints within the tolerance beyond an end are clamped onto it,
        an axis beyond its travel may move back in) and hard limit switches (an active one may only
        be moved away from)."""
        homed = self.out.values[self._i["homed_mask"]]
        for i in range(self.n):
            if ain[i] & _LIMIT_MIN and pos[i] < commanded[i] or ain[i] & _LIMIT_MAX and pos[i] > commanded[i]:
                return ServoFault.HARD_LIMIT, i, pos[i]
            if not homed >> i & 1:
                continue  # before homing a position means nothing (and homing travels onto the switch)
            lo, hi = self.lo[i], self.hi[i]
            beyond = lo - pos[i] if pos[i] < lo else pos[i] - hi
            if beyond <= 0.0:
                continue
            if beyond <= self.tol[i]:
                pos[i] = lo if pos[i] < lo else hi
                continue
            was = lo - commanded[i] if commanded[i] < lo else commanded[i] - hi
            if beyond > was:
                return ServoFault.SOFT_LIMIT, i, pos[i]
        return None

    def _control(self, commanded: list[float], velocity: list[float], actual: list[float], steps: int,
                 watched: list[bool], fe_factor: float, released: set[int] = frozenset()) -> int:
        """The control law towards `commanded` (the supervision around it is this method's): the
        axis whose error passed fe_factor x its limit, `_LAW_FAILED` when the control program
        failed this period (the fallback law's commands are out), or -1. `released`: axes whose
        drives are off (speed 0) while the others are controlled (the servo's own stop)."""
        v, I, n, dt = self.out.values, self._i, self.n, self.dt * steps
        inp = self.inputs
        errors = inp.error_mm
        fe_max = v[I["max_following_error_mm"]]
        prev = self.actual_prev if self.actual_prev is not None else actual
        lagging = -1
        for i in range(n):
            e = commanded[i] - actual[i]
            errors[i] = e
            if abs(e) > fe_max[i]:
                fe_max[i] = abs(e)
            if watched[i] and abs(e) > self.fe_lim[i] * fe_factor and lagging < 0:
                lagging = i
            inp.setpoint_mm[i] = commanded[i]
            inp.setpoint_velocity_mm_s[i] = velocity[i]
            inp.setpoint_accel_mm_s2[i] = (velocity[i] - self.v_prev[i]) / dt
            self.v_prev[i] = velocity[i]
            inp.actual_mm[i] = actual[i]
            inp.velocity_mm_s[i] = (actual[i] - prev[i]) / dt
        self.actual_prev = actual
        inp.dt_s = dt
        inp.flags = self.last_flags
        inp.moving = bool(self.last_flags & _IN_MOTION)
        u, failed = self._run_law(inp, dt)
        speed = [0.0] * n
        for i in range(n):
            if i in released:
                continue
            volts = u[i] * self.vpm[i]
            vmax = self.vmax[i]
            speed[i] = vmax if volts > vmax else -vmax if volts < -vmax else volts
        v[I["following_error_mm"]] = list(errors)
        v[I["max_following_error_mm"]] = fe_max
        if lagging >= 0:
            return lagging
        self.velocity_before = v[I["commanded_velocity_mm_s"]]
        v[I["commanded_mm"]] = list(commanded)
        v[I["commanded_velocity_mm_s"]] = list(velocity)
        v[I["speed_cmd_v"]] = speed
        mask = (1 << n) - 1
        for i in released:  # (only in the servo's own stop: an axis that could not follow it)
            mask &= ~(1 << i)
        v[I["drive_enable_mask"]] = mask
        return _LAW_FAILED if failed else -1

    def _run_law(self, inp: ControlInputs, dt: float) -> tuple[list[float], bool]:
        """One period of the control law, timed in CPU time against its budget: (speed commands,
        whether the control program failed). A program that raises, returns anything but one
        finite number per axis, or overruns its budget is replaced by the fallback law at once
        (`_fail_law`), which computes this period."""
        law = self.law
        why = ""
        if not self.law_running:
            self.law_running = True
            try:
                law._started()
            except (Exception, SystemExit) as exc:  # noqa: BLE001 - whatever the user's code raises
                why = f"start_control raised {type(exc).__name__}: {exc}"
        if not why:
            t0 = time.thread_time_ns()
            try:
                u = law.control(inp)
                used = time.thread_time_ns() - t0
                law._counted(dt)
                why = outputs_problem(u, self.names)
            except (Exception, SystemExit) as exc:  # noqa: BLE001
                used = time.thread_time_ns() - t0
                why = f"raised {type(exc).__name__}: {exc}"
            if law is self.program:
                self._record_control(used)
                if used > self.budget_ns:
                    self.over_budget += 1
                    if self.over_budget >= self.budget_overruns and not why:
                        why = (f"used {used / 1000:.0f} us of CPU in a period, over its budget of "
                               f"{self.budget_ns / 1000:.0f} us ({self.over_budget} periods in a row)")
                else:
                    self.over_budget = 0
        if why and law is self.program:
            self._fail_law(why)
            u, _ = self._run_law(inp, dt)  # the fallback, this very period
            return u, True
        if why:  # the fallback itself failed: nothing sane to command
            log.error("servo: the fallback control law failed: %s", why)
            return [0.0] * self.n, True
        if self.logs and law is self.program and self._trace_cell[0]:
            self._take_logs()
        return u, False

    def _fail_law(self, why: str) -> None:
        """The control program failed: say so in the block, stop it, and let the fallback law take over."""
        v, I = self.out.values, self._i
        text = f"control program {self.program_name} {why}"
        self.out.set("control_failure", text)
        v[I["control_failures"]] += 1
        log.error("servo: %s: the servo's own PI-P takes over", text)
        try:
            self.program.stop_control()
        except (Exception, SystemExit):  # noqa: BLE001 - it has failed already
            pass
        self.law, self.law_running, self.over_budget = self.fallback, False, 0

    def _take_logs(self) -> None:
        """The control program's log variables, flattened for the trace record."""
        out, k, program = self.log_values, 0, self.program
        for spec in self.logs:
            value = getattr(program, spec.name, 0.0)
            if spec.size == 1 and not spec.per_axis:
                out[k] = float(value) if isinstance(value, (int, float)) else math.nan
                k += 1
                continue
            for j in range(spec.size):
                try:
                    out[k] = float(value[j])
                except (TypeError, IndexError, ValueError):
                    out[k] = math.nan
                k += 1

    def _record_control(self, ns: int) -> None:
        self.control_ns = ns
        _count(self.control_timing, self.control_hist, ns)

    def _pop(self) -> tuple | None:
        """The next setpoint of the current motion epoch; records of another are dropped and counted."""
        v, I = self.out.values, self._i
        epoch = v[I["motion_epoch"]] & _EPOCH_MASK
        while True:
            rec = self.fifo.pop()
            if rec is None or rec[self._i_epoch] == epoch:
                return rec
            v[I["stale_dropped"]] += 1

    def _outputs(self, cmd: tuple, causes: int, state: int) -> None:
        """The digital outputs: the setpoints' bits, the commander's inhibit (at once) and forced bits
        (only while the axes hold still, and only when asked for while they did: a jet test never
        reopens by itself after a motion or a drives change), and no jet while a stop-cut cause is
        in effect."""
        v, I = self.out.values, self._i
        force = cmd[self._c_force]
        if not force:
            self.force_ok = self.force_blocked = False
        elif state != ServoState.HOLDING:
            self.force_ok, self.force_blocked = False, True  # asked for while not at rest: void until asked again
        elif not self.force_blocked:
            self.force_ok = True
        if state not in (ServoState.HOLDING, ServoState.TRACKING):
            v[I["digital_out"]] = 0
            return
        dout = v[I["digital_out"]]
        if self.force_ok:
            dout |= force
        dout &= ~cmd[self._c_inhibit]
        if causes:
            dout &= ~_JET_BITS
        v[I["digital_out"]] = dout & OUTPUT_MASK

    # -- parameters and references ---------------------------------------------------------
    def _apply_params(self, tick: int) -> None:
        """Take the control parameters in force from the params block (its writer, the gateway,
        has checked them); the tick they apply from is published with their change number. A
        block found mid-write is left for the next tick (its change number is not taken)."""
        values, consistent = self.params.read_nowait()
        if not consistent:
            # the gateway is writing the block this very moment: what the reader falls back to is the
            # last copy it saw, or before any the layout's zeros (a gain of 0, a following-error limit
            # of 0: a trip at once). Keep the values in force; the change is taken at the next tick.
            return
        block = self.params.layout.index
        slots = values[block["values"]]
        for target, where, slot in self._param_slots:
            if isinstance(where, int):
                target[where] = float(slots[slot])
            else:
                setattr(target, where, float(slots[slot]))
        v, I = self.out.values, self._i
        v[I["params_change"]], v[I["params_tick"]] = values[block["change"]], tick

    def _param_slot(self, spec) -> tuple[object, int | str, int]:  # noqa: ANN001 - a ParamSpec
        """Where the servo keeps a servo-owned parameter: (a list and its axis, or an object and its
        member name, the block slot). The following-error limits are the supervision's own; the
        rest are the control program's registered members."""
        axis = self.names.index(spec.path[1]) if spec.path[0] == "axis" else (
            self.names.index(spec.path[2]) if len(spec.path) == 3 else -1)
        if spec.key == "following_error_limit_mm":
            return self.fe_lim, axis, spec.index
        if spec.path[0] == "axis":
            member = next(p.name for p in self.program.parameters if p.option == spec.key)
            return getattr(self.program, member), axis, spec.index
        if axis >= 0:
            return getattr(self.program, spec.key), axis, spec.index
        return self.program, spec.key, spec.index

    def _apply_reference(self, ref: tuple, enc: tuple, actual: list[float]) -> list[float]:
        """Homing: `position_ref_counts` of the masked axes is `position_ref_mm`; the axes of
        `position_ref_unhome` lose their reference (homing again starts from an unhomed axis).
        Applied only while not following a motion; the commanded position becomes the new actual
        one, so nothing jumps."""
        v, I = self.out.values, self._i
        i_seq, i_mask, i_counts, i_mm, i_unhome = self._m_ref
        mask, counts, mm = ref[i_mask], ref[i_counts], ref[i_mm]
        offset = v[I["position_offset_mm"]]
        commanded = v[I["commanded_mm"]]
        for i in range(self.n):
            if mask >> i & 1:
                shift = (mm[i] - counts[i] * self.res[i]) - offset[i]
                offset[i] += shift
                actual[i] += shift
                commanded[i] = actual[i]
                if self.law_running:
                    self.law.position_referenced(i)
                if self.actual_prev is not None:
                    self.actual_prev[i] += shift
        v[I["position_offset_mm"]] = offset
        v[I["commanded_mm"]] = commanded
        v[I["homed_mask"]] = (v[I["homed_mask"]] & ~ref[i_unhome]) | mask
        v[I["position_ref_seq"]] = ref[i_seq]
        return actual

    def close(self) -> None:
        """Let go of the views into shared memory (before the segment is closed)."""
        self._ref_seq_cell.release()
        self._trace_cell.release()
        self._params_change_cell.release()

    def _open_loop(self, actual: list[float]) -> None:
        """Speed 0, drives off, outputs off; the commanded position follows the actual one."""
        v, I, n = self.out.values, self._i, self.n
        v[I["speed_cmd_v"]] = [0.0] * n
        v[I["drive_enable_mask"]] = 0
        v[I["digital_out"]] = 0
        v[I["commanded_mm"]] = list(actual)
        v[I["commanded_velocity_mm_s"]] = [0.0] * n
        v[I["following_error_mm"]] = [0.0] * n
        self.v_prev = [0.0] * n
        self.actual_prev = None
        self.last_flags = 0
        if self.law_running:  # the loop opens: the law stops (it starts afresh when the loop closes again)
            self.law_running = False
            try:
                self.law.stop_control()
            except (Exception, SystemExit) as exc:  # noqa: BLE001
                if self.law is self.program:
                    self._fail_law(f"stop_control raised {type(exc).__name__}: {exc}")

    def _record_latency(self, ns: int) -> None:
        _count(self.timing, self.hist, ns)


def _count(timing, hist, ns: int) -> None:  # noqa: ANN001 - a timing block's array and its histogram
    """One duration into a timing block: its 1 us histogram bin (the last collects what is later), count, max."""
    b = ns // 1000
    hist[b if b < HIST_BINS - 1 else HIST_BINS - 1] += 1
    timing["count"][0] += 1
    if ns > timing["max_ns"][0]:
        timing["max_ns"][0] = ns


class _QueuedPath:
    """The brake's path: the servo's queued setpoints of the current epoch, taken as they are passed."""

    def __init__(self, servo: Servo) -> None:
        self.servo = servo

    def next_point(self) -> PathPoint | None:
        s = self.servo
        rec = s._pop()
        if rec is None:
            return None
        n = s.n
        v, I = s.out.values, s._i
        v[I["setpoint_segment"]], v[I["setpoint_line"]] = rec[2 * n + 1], rec[2 * n + 2]
        return PathPoint(tuple(rec[:n]), math.sqrt(sum(x * x for x in rec[n: 2 * n])))


class _NoPath:
    """A brake straight on along the current velocity (the queued path is the fault, or there is none)."""

    def next_point(self) -> PathPoint | None:
        return None
