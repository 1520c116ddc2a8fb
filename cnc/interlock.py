"""The stop-cut interlocks, decided every base tick by the servo from the shared-memory images.

What stops a cut is decided here, in code, in the tick, from what the tick reads anyway: the
hardware image (e-stop, doors, mains), the PLC's input block (safety circuit, light barriers,
pump fault and pressure, and whether the link still delivers) and the commander's block (its
heartbeat, what it arms, the pump pressure floor). No process, disk or network sits between a
cause and the jet: the servo holds the jet closed in the tick that sees a cause, and trips.
The control logic only arms (a barrier matters while the automatic cycle runs), sets the
pressure floor, and tells people.

Liveness of other processes (the PLC link's input sequence, the commander's heartbeat) is
judged on two clocks: a sign of life is overdue once both the controller time (ticks) and the
wall-clock time since the last one exceed the limit. On the real-time clock they are the same
time. On the virtual clock the ticks run faster than the wall, while the PLC link and the
commander live partly in wall time: waiting for both keeps a healthy process from being taken
for a dead one however fast the ticks run, and still catches a dead one (its wall time runs on).

A block found mid-write for more than one base period of wall time whose writer process is gone
(dead or a zombie) is a dead writer: the tick treats it as that process's loss at once rather
than trusting the last copy until a timeout (`dead_writer`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from .config import MachineConfig
from .hw.board import DigitalIn
from .data.layout import LinkState, Proc, ServoFault


class StopCause(enum.IntFlag):
    """Stop-cut causes the tick decides. Bits are part of the shared-memory layout: never reuse one."""

    ESTOP = 1 << 0  # the board's e-stop circuit is open (category 0: the drives lose power)
    MAINS = 1 << 1  # the machine mains are off (category 0: no power to stop with)
    DOORS = 1 << 2  # a safety door is open
    SAFETY_CIRCUIT = 1 << 3  # the PLC reports its safety circuit open
    BARRIER = 1 << 4  # a light barrier is interrupted while the commander arms the barriers
    PUMP = 1 << 5  # the pump reports a fault, or its pressure is below the floor while the jet is open
    PLC_LINK = 1 << 6  # the PLC's inputs are not fresh: link lost, PLC-link process hung or dead
    COMMANDER = 1 << 7  # the commander's heartbeat stopped (hung or dead logic)


CATEGORY_0 = StopCause.ESTOP | StopCause.MAINS  # nothing left to brake with: drives off at once
# Plain ints for the tick path: IntFlag arithmetic goes through the enum machinery.
_ESTOP, _MAINS, _DOORS = int(StopCause.ESTOP), int(StopCause.MAINS), int(StopCause.DOORS)
_SAFETY, _BARRIER, _PUMP = int(StopCause.SAFETY_CIRCUIT), int(StopCause.BARRIER), int(StopCause.PUMP)
_PLC_LINK, _COMMANDER = int(StopCause.PLC_LINK), int(StopCause.COMMANDER)
_ESTOP_OK, _MAINS_ON, _DOORS_CLOSED = int(DigitalIn.ESTOP_OK), int(DigitalIn.MAINS_ON), int(DigitalIn.DOORS_CLOSED)
_LINK_OK = int(LinkState.OK)
ALWAYS_ARMED = StopCause.ESTOP | StopCause.MAINS | StopCause.DOORS
# the board's own causes, which no reset clears: drives switched on while one is present trip in the
# next tick, so a reset leaves them off (cnc.logic.process); plain int, as the servo publishes its causes
DRIVES_HELD_OFF = int(ALWAYS_ARMED)
PLC_CAUSES = StopCause.SAFETY_CIRCUIT | StopCause.PUMP | StopCause.PLC_LINK

# the servo fault a cause trips with; the first present in this order names the trip
CAUSE_FAULTS: tuple[tuple[StopCause, ServoFault], ...] = (
    (StopCause.ESTOP, ServoFault.ESTOP), (StopCause.MAINS, ServoFault.MAINS), (StopCause.DOORS, ServoFault.DOORS),
    (StopCause.SAFETY_CIRCUIT, ServoFault.SAFETY_CIRCUIT), (StopCause.BARRIER, ServoFault.BARRIER),
    (StopCause.PUMP, ServoFault.PUMP), (StopCause.PLC_LINK, ServoFault.PLC_LINK),
    (StopCause.COMMANDER, ServoFault.COMMANDER),
)


def fault_of(causes: int) -> ServoFault:
    """The servo fault that names a trip on these causes."""
    for cause, fault in CAUSE_FAULTS:
        if causes & cause:
            return fault
    return ServoFault.NONE


def process_gone(pid: int) -> bool:
    """Whether process `pid` has ended (no such process, or a zombie its parent has not reaped)."""
    if pid <= 0:
        return False
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
    except OSError:
        return True
    state = stat[stat.rfind(b")") + 2: stat.rfind(b")") + 3]
    return state in (b"Z", b"X")


@dataclass
class _Life:
    """When a process last showed a sign of life, on both clocks."""

    value: int = -1
    tick: int = 0
    ns: int = 0

    def saw(self, value: int, tick: int, ns: int) -> None:
        if value != self.value:
            self.value, self.tick, self.ns = value, tick, ns

    def overdue(self, tick: int, ns: int, limit_ticks: int, limit_ns: int) -> bool:
        return tick - self.tick > limit_ticks and ns - self.ns > limit_ns


class Interlock:
    """Evaluates the stop-cut causes of one tick. Pure: the servo hands it what it read."""

    def __init__(self, config: MachineConfig, members: int) -> None:
        period_s = config.timing.period_s
        self.period_ns = int(period_s * 1e9)
        inputs = config.plc.inputs()
        index = {v.id: k for k, v in enumerate(inputs)}
        self.i_safety = index.get("safety_circuit_ok", -1)
        self.i_barriers = [index[b] for b in ("barrier_front_ok", "barrier_rear_ok") if b in index]
        self.i_pump_fault = index.get("pump_fault", -1)
        self.i_pressure = index.get("pump_pressure", -1)
        self.plc_watched = bool(inputs) and bool(members >> Proc.PLC_LINK & 1)
        self.commander_watched = bool(members >> Proc.LOGIC & 1)
        plc = config.plc
        # lost_after_cycles + 1 exchange cycles without a new input image; a cycle that fails lasts
        # up to the request's timeout, so the link's own loss detection always fits inside
        fresh_s = (plc.lost_after_cycles + 1) * max(plc.cycle_ms, plc.timeout_ms) / 1000.0
        self.plc_limit = (round(fresh_s / period_s), int(fresh_s * 1e9))
        beat_s = config.timing.commander_timeout_ms / 1000.0
        self.commander_limit = (round(beat_s / period_s), int(beat_s * 1e9))
        self.plc_life = _Life()
        self.commander_life = _Life()
        self.token = -1
        self.started = False
        self.pressure_bar = 0.0  # the pump pressure last read: a PUMP trip's figure

    def watched(self) -> int:
        """The causes this controller can raise at all (what it is made of decides)."""
        causes = ALWAYS_ARMED | StopCause.BARRIER
        if self.plc_watched:
            causes |= PLC_CAUSES
        if self.commander_watched:
            causes |= StopCause.COMMANDER
        return int(causes)

    def evaluate(self, tick: int, now_ns: int, digital_in: int, plc: tuple | None, plc_index: dict,
                 command: tuple, command_index: dict, jet_open: bool, commander_dead: bool = False,
                 plc_dead: bool = False) -> int:
        """The causes in effect this tick (StopCause bits). `plc` is the PLC block's values (None when
        not watched), `command` the commander's; `jet_open`: the jet would be open this tick;
        `*_dead`: that block's writer died mid-write (`dead_writer`)."""
        if not self.started:  # a sign of life is due one limit after the servo starts, not before
            self.started = True
            self.plc_life = _Life(-1, tick, now_ns)
            self.commander_life = _Life(-1, tick, now_ns)
        causes = 0
        if not digital_in & _ESTOP_OK:
            causes |= _ESTOP
        if not digital_in & _MAINS_ON:
            causes |= _MAINS
        if not digital_in & _DOORS_CLOSED:
            causes |= _DOORS
        arm = command[command_index["arm"]]
        if self.commander_watched:
            token = command[command_index["token"]]
            if token != self.token:  # a new commander: its heartbeat starts afresh
                self.token = token
                self.commander_life = _Life(-1, tick, now_ns)
            self.commander_life.saw(command[command_index["heartbeat"]], tick, now_ns)
            if commander_dead or self.commander_life.overdue(tick, now_ns, *self.commander_limit):
                causes |= _COMMANDER
        if plc is not None and self.plc_watched:
            causes |= self._plc(tick, now_ns, plc, plc_index, arm, command[command_index["pressure_floor_bar"]],
                                jet_open, plc_dead)
        return causes

    def _plc(self, tick: int, now_ns: int, plc: tuple, ix: dict, arm: int, floor_bar: float, jet_open: bool,
             dead: bool) -> int:
        self.plc_life.saw(plc[ix["input_seq"]], tick, now_ns)
        if dead or plc[ix["state"]] != _LINK_OK or self.plc_life.overdue(tick, now_ns, *self.plc_limit):
            return _PLC_LINK  # the PLC's other signals are unknown: not trusted, not stale
        inputs = plc[ix["inputs"]]
        causes = 0
        if self.i_safety >= 0 and not inputs[self.i_safety]:
            causes |= _SAFETY
        if arm & _BARRIER:
            for k in self.i_barriers:
                if not inputs[k]:
                    causes |= _BARRIER
        if self.i_pump_fault >= 0 and inputs[self.i_pump_fault]:
            causes |= _PUMP
        if self.i_pressure >= 0:
            self.pressure_bar = inputs[self.i_pressure]
            if jet_open and floor_bar > 0.0 and self.pressure_bar < floor_bar:
                causes |= _PUMP
        return causes

    def dead_writer(self, odd_since_ns: int, now_ns: int, pid: int) -> bool:
        """A block stuck mid-write for more than one base period whose writer has ended."""
        return bool(odd_since_ns) and now_ns - odd_since_ns > self.period_ns and process_gone(pid)
