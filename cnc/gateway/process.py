"""Gateway: the HMI's door. Publishes the cyclic status and the position stream on Zenoh, and
serves operator commands and queries (`door.py`).

It reads the shared-memory blocks as any reader does (never blocking their writers) and
puts one typed `Status` message per period on `<root>/status` (the servo and the board, the
planner's progress, the control logic's mode, state, cycle and alarms summary, the PLC link
and the pump, the operator stations) and one `Position` per position period on
`<root>/position` for the live path. Events (alarms, procedures) are published by the control
logic, which owns them; the gateway answers the history queries from the same files.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import zenoh

from ..bus.keys import Keys
from .control_timing import ControlTiming
from ..bus.messages import AxisStatus, InterruptedCut, Position, ProgramProgress, Status, encode
from .door import Door
from ..config import MachineConfig
from ..data.dataserver import SharedArea
from ..data.injection import injected_bugs
from ..data.fifo import SetpointFifo
from ..hw.board import AxisIn, DigitalIn, DigitalOut
from ..alarms import AlarmLevel
from ..data.layout import ClockKind, LinkState, PlannerState, Proc, RunResult, ServoFault, ServoState
from ..logic.states import CyclePhase, MachineState, Mode
from .param_door import ParamDoor

_LEVELS = {int(level): level.name.lower() for level in AlarmLevel}
_CLOCK_NAMES = {ClockKind.VIRTUAL: "virtual", ClockKind.REALTIME: "realtime", ClockKind.REALTIME_FALLBACK: "realtime-fallback"}


class Gateway:
    """Cyclic status publisher; later issues add events, commands and queries here."""

    def __init__(
        self, config: MachineConfig, area: SharedArea, fifo: SetpointFifo, session: zenoh.Session, clock: str,
        history_path: str, program_dir: str = "",
    ):
        self.config, self.area, self.fifo = config, area, fifo
        self.keys = Keys(config.zenoh.key_prefix, config.machine.name)
        self.hw, self.servo, self.motion = area.reader("hw"), area.reader("servo"), area.reader("motion")
        self.logic, self.plc = area.reader("logic"), area.reader("plc")
        self.plc_ids = [v.id for v in config.plc.inputs()]
        self.pressure_index = next((k for k, v in enumerate(config.plc.inputs()) if v.id == "pump_pressure"), -1)
        self._last_actual: list[float] | None = None
        self._last_tick = 0
        self.shutdown = area.blocks["supervisor"].array["shutdown"]
        hb = area.blocks["heartbeat"].array[0]
        self.beat = hb["beat"]
        hb["pid"][Proc.GATEWAY] = os.getpid()
        self.publisher = session.declare_publisher(
            self.keys.status, encoding=zenoh.Encoding.APPLICATION_JSON, congestion_control=zenoh.CongestionControl.DROP
        )
        self.position_pub = session.declare_publisher(
            self.keys.position, encoding=zenoh.Encoding.APPLICATION_JSON, congestion_control=zenoh.CongestionControl.DROP
        )
        self.period_s = 1.0 / config.gateway.status_rate_hz
        self.position_period_s = 1.0 / config.gateway.position_rate_hz
        self.position_seq = 0
        self.door = Door(
            config, session, self.keys, history_path, program_dir or str(Path(history_path).parent / "programs"),
            machine_state=lambda: MachineState(self.logic.read_dict()["state"]).name, motion=self.motion.read_dict,
            inject=injected_bugs(area, config),
        )
        self.param_door = ParamDoor(config, session, self.keys, area, self.door.service)
        self.control_timing = ControlTiming(config, area)
        # last: declarations travel in order, so whoever sees this token can reach every door above
        self.token = session.liveliness().declare_token(self.keys.alive("gateway"))
        self.seq = 0

    def status(self) -> Status:
        """Assemble one status message from consistent snapshots of the blocks."""
        hw, sv, mo = self.hw.read_dict(), self.servo.read_dict(), self.motion.read_dict()
        lo, plc = self.logic.read_dict(), self.plc.read_dict()
        names = self.config.axis_names
        fault = ServoFault(sv["fault"])
        axes = []
        for i, name in enumerate(names):
            ain = hw["axis_inputs"][i]
            axes.append(
                AxisStatus(
                    name=name,
                    position_mm=sv["actual_mm"][i],
                    commanded_mm=sv["commanded_mm"][i],
                    following_error_mm=sv["following_error_mm"][i],
                    max_following_error_mm=sv["max_following_error_mm"][i],
                    velocity_mm_s=sv["commanded_velocity_mm_s"][i],
                    speed_command_v=sv["speed_cmd_v"][i],
                    limit_min=bool(ain & AxisIn.LIMIT_MIN),
                    limit_max=bool(ain & AxisIn.LIMIT_MAX),
                    home_switch=bool(ain & AxisIn.HOME),
                    drive_ready=bool(ain & AxisIn.DRIVE_READY),
                    drive_enabled=bool(ain & AxisIn.DRIVE_ENABLED),
                    homed=bool(sv["homed_mask"] >> i & 1),
                    travel_min_mm=self.config.axes[i].travel_min_mm,
                    travel_max_mm=self.config.axes[i].travel_max_mm,
                )
            )
        self.seq += 1
        fa = sv["fault_axis"]
        return Status(
            machine=self.config.machine.name,
            seq=self.seq,
            stamp_ns=time.time_ns(),
            tick=hw["tick"],
            clock=_CLOCK_NAMES[ClockKind(hw["clock_kind"])],
            servo_state=ServoState(sv["state"]).name,
            fault=fault.name,
            fault_axis=names[fa] if 0 <= fa < len(names) else "",
            watchdog_tripped=bool(hw["watchdog_tripped"]),
            safe_state=bool(hw["safe_state"]),
            estop_ok=bool(hw["digital_in"] & DigitalIn.ESTOP_OK),
            doors_closed=bool(hw["digital_in"] & DigitalIn.DOORS_CLOSED),
            jet_on=bool(hw["digital_out"] & DigitalOut.JET_VALVE),
            axes=axes,
            overruns=sv["overruns"],
            underruns=sv["underruns"],
            late_ticks=hw["late_ticks"],
            servo_missed_ticks=hw["servo_missed_total"],
            fifo_fill=self.fifo.fill(),
            planner_state=PlannerState(mo["state"]).name,
            feed_override=mo["override"],
            feed_commanded_mm_s=math.hypot(*sv["commanded_velocity_mm_s"]),
            feed_actual_mm_s=self._actual_speed(sv["actual_mm"], sv["tick"]),
            homing_axis=names[mo["homing_axis"]] if 0 <= mo["homing_axis"] < len(names) else "",
            program=self._program(mo, lo),
            event=mo["event"],
            error=mo["error"],
            machine_state=MachineState(lo["state"]).name,
            mode=Mode(lo["mode"]).name,
            cycle_phase=CyclePhase(lo["phase"]).name,
            cycles_done=lo["cycles_done"],
            cycles_target=lo["cycles_target"],
            plc_link=LinkState(plc["state"]).name,
            plc_exchanges=plc["exchanges"],
            plc_failed=plc["failed"],
            plc_dropped=plc["dropped"],
            pump_on=bool(lo["pump_on"]),
            pump_set_bar=lo["pump_set_bar"],
            pump_pressure_bar=plc["inputs"][self.pressure_index] if self.pressure_index >= 0 and plc["state"] == LinkState.OK else 0.0,
            alarms_active=lo["alarms_active"],
            alarm_level=_LEVELS.get(lo["alarm_level"], ""),
            alarm_seq=lo["alarm_seq"],
            procedure=lo["procedure"],
            logic_message=lo["message"],
            plc_inputs=dict(zip(self.plc_ids, plc["inputs"])) if plc["state"] == LinkState.OK else {},
            control=self.control_timing.law(sv),
            **self._stations(),
        )

    def _stations(self) -> dict:
        lock = self.door.lock.state()
        return {"operator": lock.holder, "stations": lock.stations, "network_alive": bool(lock.holder) and lock.holder in lock.stations}

    def _program(self, mo: dict, lo: dict) -> ProgramProgress | None:
        if not mo["program_name"]:
            return None
        interrupted = None
        if lo["cut_point_hash"] and lo["cut_point_hash"] == mo["program_hash"]:
            interrupted = InterruptedCut(int(lo["cut_point_line"]), *(float(v) for v in lo["cut_point_mm"]))
        total = mo["total_mm"]
        return ProgramProgress(
            name=mo["program_name"], hash=mo["program_hash"], lines=mo["program_lines"], segment=mo["segment"],
            line=mo["line"], done_mm=mo["done_mm"], remaining_mm=max(total - mo["done_mm"], 0.0),
            progress=mo["done_mm"] / total if total > 0 else 0.0, eta_s=mo["eta_s"], planned_s=mo["planned_s"],
            run=mo["run_seq"], result=RunResult(mo["run_result"]).name, cut=mo["cut"], interrupted=interrupted,
        )

    def _actual_speed(self, actual: list[float], tick: int) -> float:
        """Path speed from the measured positions at two status messages, over the machine time between."""
        speed = 0.0
        if self._last_actual is not None and tick > self._last_tick:
            speed = math.dist(actual, self._last_actual) / ((tick - self._last_tick) * self.config.timing.period_s)
        self._last_actual, self._last_tick = list(actual), tick
        return speed

    def position(self) -> Position:
        sv, mo = self.servo.read_dict(), self.motion.read_dict()
        self.position_seq += 1
        return Position(
            seq=self.position_seq, stamp_ns=time.time_ns(), tick=sv["tick"], position_mm=list(sv["actual_mm"]),
            commanded_mm=list(sv["commanded_mm"]), velocity_mm_s=list(sv["commanded_velocity_mm_s"]),
            segment=mo["segment"], line=mo["line"], jet_on=bool(sv["digital_out"] & DigitalOut.JET_VALVE),
        )

    def run(self) -> None:
        """Status every status period, position every position period, on absolute deadlines."""
        now = time.monotonic()
        next_status, next_position = now, now
        while not self.shutdown[0] & (1 << Proc.GATEWAY):
            now = time.monotonic()
            if now >= next_status:
                self.publisher.put(encode(self.status()))
                self.beat[Proc.GATEWAY] += 1
                next_status = _next(next_status, self.period_s, now)
            if now >= next_position:
                self.position_pub.put(encode(self.position()))
                next_position = _next(next_position, self.position_period_s, now)
            delay = min(next_status, next_position) - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def close(self) -> None:
        self.door.close()
        self.publisher.undeclare()
        self.position_pub.undeclare()
        self.token.undeclare()


def _next(deadline: float, period: float, now: float) -> float:
    """The next deadline; after a stall, start again from now rather than bursting to catch up."""
    deadline += period
    return deadline if deadline > now else now + period
