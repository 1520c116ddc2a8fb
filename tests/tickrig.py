"""The controller's real-time side in one process, stepped tick by tick, for the fault matrix.

The real hardware server on the real simulated board and the real servo with its interlocks run
on shared memory made for the rig; around them, stand-ins do what the other processes would,
on the same blocks and at the same divisors: a planner feeding the FIFO from a real
`ProgramRunner` (a cut, a jog) or the real `Homing` sequence, a commander beating its heartbeat
every scan, a PLC link publishing an input image every cycle. Each can be stopped (a process
hung or killed), or killed in the middle of a write (its block left odd, its pid gone). The wall
clock the interlocks judge signs of life by is the rig's tick count, so a hundred milliseconds
of machine time take a few milliseconds and every run is the same: the real-time clock's case,
where both clocks are one.

What the rig reads off is what the board did: the tick its jet valve closed, and the true table
positions (not the encoders) from which the stop distance is summed.
"""

from __future__ import annotations

import dataclasses
import math
import secrets
from pathlib import Path

import numpy as np

from cnc.config import MachineConfig
from cnc.data.dataserver import SharedArea, unique_name
from cnc.data.fifo import SetpointFifo
from cnc.hw.board import DigitalOut
from cnc.hw.clock import VirtualClock
from cnc.hw.server import HardwareServer
from cnc.hw.sim_board import SimBoard
from cnc.homing import Homing, HomingError, Push, Reference, Unhome
from cnc.data.layout import ClockKind, LinkState, Proc, ServoState, controller_layouts
from cnc.machine_dialect import dialect_for
from cnc.planner.runner import ProgramRunner
from cnc.planner.sections import move_steps
from cnc.servo import Servo
from gcode.interp import Interpreter

PLANNER_DIVISOR, LOGIC_DIVISOR = 5, 4
MEMBERS = 1 << Proc.LOGIC | 1 << Proc.PLC_LINK | 1 << Proc.PLANNER | 1 << Proc.SUPERVISOR


def dead_pid() -> int:
    """The pid of a writer that was killed: one no process has (what /proc does not know), found
    from the top of the pid range down, where the kernel hands out pids last."""
    pid = int(Path("/proc/sys/kernel/pid_max").read_text()) - 1
    while Path(f"/proc/{pid}").exists():
        pid -= 1
    return pid


class Feeder:
    """The planner's stand-in for one motion: tops the FIFO up between its watermarks every
    planner period with records stamped with the servo's motion epoch taken when it began, and
    stops when the servo voids the motion (a trip, a reset, the drives), as the planner does."""

    def __init__(self, rig: "Rig", runner: ProgramRunner) -> None:
        self.rig, self.runner = rig, runner
        self.epoch = rig.servo_block()["motion_epoch"]
        self.over = False

    def feed(self) -> None:
        rig, runner = self.rig, self.runner
        servo = rig.servo_block()
        if servo["state"] in (ServoState.FAULT, ServoState.DISABLED) or servo["motion_epoch"] != self.epoch:
            self.over = True
        if self.over:
            return
        fill = rig.fifo.fill()
        if fill < rig.low and not runner.idle:
            records, _ = runner.take(rig.high - fill)
            self._push(records)
            runner.prepare(0.5)
        elif runner.idle:
            records, _ = runner.take(0)
            self._push(records)

    def _push(self, records: np.ndarray) -> None:
        if len(records):
            records["epoch"] = self.epoch
            assert self.rig.fifo.push(records) == len(records)


class HomingFeeder:
    """The planner's homing (`Planner._step_homing`): the real sequence, its pushes and references."""

    def __init__(self, rig: "Rig", axes: list[str]) -> None:
        self.rig = rig
        self.homing = Homing(rig.config, rig.hw_block, rig.servo_block)
        self.steps = self.homing.steps(axes)
        self.waiting: tuple | None = None
        self.epoch = rig.servo_block()["motion_epoch"]
        self.over = False
        self.error = ""

    def feed(self) -> None:
        rig = self.rig
        servo = rig.servo_block()
        if servo["state"] in (ServoState.FAULT, ServoState.DISABLED) or servo["motion_epoch"] != self.epoch:
            self.over = True
        if self.over:
            return
        if self.waiting is not None:
            kind = self.waiting[0]
            if kind == "drain" and rig.fifo.fill() > rig.low:
                return
            if kind == "reference" and (servo["position_ref_seq"] != self.waiting[1] or rig.fifo.fill()):
                return
            if kind == "settle" and (rig.fifo.fill() or servo["state"] == ServoState.TRACKING):
                return
            self.waiting = None
        try:
            step = next(self.steps)
        except StopIteration:
            self.over = True
            return
        except HomingError as exc:
            self.over, self.error = True, str(exc)
            return
        if isinstance(step, Push):
            records = step.records.copy()
            records["epoch"] = self.epoch
            rig.fifo.push(records)
            self.waiting = ("drain",)
        elif isinstance(step, (Reference, Unhome)):
            self.waiting = ("reference", rig.reference(step))
        else:
            self.waiting = ("settle",)


@dataclasses.dataclass
class Alive:
    """Which stand-ins still do their work."""

    commander: bool = True
    plc_link: bool = True
    planner: bool = True
    servo: bool = True


class Rig:
    """One controller's real-time side; use as a context manager."""

    def __init__(self, config: MachineConfig, homed: bool = True, members: int = MEMBERS) -> None:
        self.config = config
        self.n = n = len(config.axis_names)
        self.dt = config.timing.period_s
        self.period_ns = int(round(self.dt * 1e9))
        self.low = max(1, round(config.planner.fifo_low_ms / 1000.0 / self.dt))
        self.high = round(config.planner.fifo_high_ms / 1000.0 / self.dt)
        self.plc_ticks = max(1, round(config.plc.cycle_ms / 1000.0 / self.dt))
        self.area = SharedArea.create(unique_name("rig", "data"), controller_layouts(n))
        self.fifo = SetpointFifo.create(unique_name("rig", "fifo"), 8192, n)
        sup = self.area.writer("supervisor")
        sup.set("members", members)
        sup.publish()
        sim = self.area.writer("sim")  # the simulated environment as the supervisor starts it (faults: on the board)
        sim.set("friction_scale", [1.0] * n)
        sim.publish()
        self.command = self.area.writer("command")
        self.command.set("token", secrets.randbits(63))
        self.command.set("servo_enable", 1)
        self.command.publish()
        self.plc = self.area.writer("plc")
        self.plc_inputs = {v.id: 0.0 for v in config.plc.inputs()}
        self.plc_inputs.update(safety_circuit_ok=1.0, barrier_front_ok=1.0, barrier_rear_ok=1.0, plc_running=1.0,
                               mains_on=1.0, pump_running=1.0, pump_pressure=config.pump.cut_pressure_bar)
        self.plc.set("state", int(LinkState.OK))
        self._publish_plc(advance=True)
        self.motion = self.area.writer("motion")
        pids = self.area.blocks["heartbeat"].array[0]["pid"]
        import os

        for slot in (Proc.LOGIC, Proc.PLC_LINK, Proc.PLANNER, Proc.SUPERVISOR):
            pids[slot] = os.getpid()
        self.pids = pids
        self.board = SimBoard(config)
        self.tick = 0
        self.hw = HardwareServer(config, self.area, self.board, VirtualClock(self.dt), [], ClockKind.VIRTUAL)
        self.servo = Servo(config, self.area, self.fifo, record_latency=False, clock_ns=lambda: self.tick * self.period_ns)
        self.alive = Alive()
        self.feeder: Feeder | HomingFeeder | None = None
        self.positions: list[tuple[float, ...]] = []
        self.jet: list[bool] = []
        self._hw_r, self._servo_r = self.area.reader("hw"), self.area.reader("servo")
        self.step(2)
        if homed:
            self.home_here()

    def __enter__(self) -> "Rig":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.servo.close()
        del self.servo, self.hw, self.pids
        self.fifo.close()
        self.area.close()

    # -- stepping ------------------------------------------------------------------------
    def step(self, ticks: int = 1) -> None:
        for _ in range(ticks):
            deadline = (self.tick + 1) * self.period_ns
            self.hw.step(deadline, deadline)
            self.tick += 1
            if self.alive.commander and self.tick % LOGIC_DIVISOR == 0:
                self.command.set("heartbeat", self.command.get("heartbeat") + 1)
                self.command.publish()
            if self.alive.plc_link and self.tick % self.plc_ticks == 0:
                self._publish_plc(advance=True)
            if self.alive.planner and self.feeder is not None and self.tick % PLANNER_DIVISOR == 0:
                self.feeder.feed()
            if self.alive.servo:
                self.servo.tick()
            self.positions.append(tuple(self.board.position_mm(i) for i in range(self.n)))
            self.jet.append(bool(self.hw_block()["digital_out"] & DigitalOut.JET_VALVE))

    def run_until(self, predicate, max_ticks: int, what: str) -> int:
        for k in range(max_ticks):
            if predicate():
                return k
            self.step()
        raise AssertionError(f"{what}: not within {max_ticks} ticks (state {ServoState(self.servo_block()['state']).name})")

    # -- the blocks ----------------------------------------------------------------------
    def hw_block(self) -> dict:
        return self._hw_r.read_dict()

    def servo_block(self) -> dict:
        return self._servo_r.read_dict()

    def speed_mm_s(self) -> float:
        return math.hypot(*(self.board.velocity_mm_s(i) for i in range(self.n)))

    # -- the stand-ins' work -----------------------------------------------------------------
    def _publish_plc(self, advance: bool) -> None:
        values = [self.plc_inputs[v.id] for v in self.config.plc.inputs()]
        self.plc.set("inputs", values + [0.0] * (len(self.plc.get("inputs")) - len(values)))
        if advance:
            self.plc.set("input_seq", self.plc.get("input_seq") + 1)
        self.plc.publish()

    def set_plc_input(self, **values: float) -> None:
        """The PLC's next input image shows these (the link brings it at its next cycle)."""
        self.plc_inputs.update(values)

    def set_command(self, **fields) -> None:
        for name, value in fields.items():
            self.command.set(name, value)
        self.command.publish()

    def reference(self, step: Reference | Unhome) -> int:
        m = self.motion
        seq = m.get("position_ref_seq") + 1
        if isinstance(step, Unhome):
            m.set("position_ref_mask", 0)
            m.set("position_ref_unhome", 1 << step.axis)
        else:
            counts, mm = list(m.get("position_ref_counts")), list(m.get("position_ref_mm"))
            counts[step.axis], mm[step.axis] = int(step.counts), float(step.position_mm)
            m.set("position_ref_counts", counts)
            m.set("position_ref_mm", mm)
            m.set("position_ref_mask", 1 << step.axis)
            m.set("position_ref_unhome", 0)
        m.set("position_ref_seq", seq)
        m.publish()
        return seq

    def home_here(self) -> None:
        """Both axes homed where the table stands (machine position = the board's encoder frame)."""
        enc = self.hw_block()["encoder_counts"]
        for i in range(self.n):
            seq = self.reference(Reference(i, enc[i], enc[i] * self.config.axes[i].encoder_resolution_mm))
            self.run_until(lambda s=seq: self.servo_block()["position_ref_seq"] == s, 50, "the reference")

    def run_program(self, text: str) -> ProgramRunner:
        here = self.servo_block()["commanded_mm"]
        dialect = dataclasses.replace(dialect_for(self.config), start_position_mm=(*here, 0.0)[:3])
        program = Interpreter(dialect, "rig.ngc").run(text.encode())
        runner = ProgramRunner(program, self.config)  # streamed: its steps made as the run reaches them
        self.feeder = Feeder(self, runner)
        return runner

    def jog(self, axis: int, velocity_mm_s: float, to_mm: float) -> ProgramRunner:
        here = list(self.servo_block()["commanded_mm"])
        end = list(here)
        end[axis] = to_mm
        xyz = lambda p: (*p, 0.0)[:3]  # noqa: E731
        runner = ProgramRunner(None, self.config, steps=move_steps(xyz(here), xyz(end), abs(velocity_mm_s), self.config))
        self.feeder = Feeder(self, runner)
        return runner

    def home(self, axes: list[str]) -> HomingFeeder:
        self.feeder = HomingFeeder(self, axes)
        return self.feeder

    def reset(self) -> None:
        """The commander's reset: it has seen the servo's trips and the image of this tick."""
        self.set_command(reset_tick=self.hw_block()["tick"], reset_trip_seq=self.servo_block()["trip_seq"],
                         reset_seq=self.command.get("reset_seq") + 1)

    def kill_mid_write(self, block: str, slot: Proc) -> None:
        """The writer of `block` dies inside a publish: its sequence number stays odd, its pid is gone."""
        cell = self.area.blocks[block].seq_cell
        cell[0] = cell[0] | 1
        self.pids[slot] = dead_pid()
