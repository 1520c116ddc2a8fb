"""Gateway: the HMI's door. Publishes the cyclic status on Zenoh from the data server.

It reads the shared-memory blocks as any reader does (never blocking their writers) and
puts one typed `Status` message per period on `<root>/status`.
"""

from __future__ import annotations

import os
import time

import zenoh

from .bus.keys import Keys
from .bus.messages import AxisStatus, Status, encode
from .config import MachineConfig
from .dataserver import SharedArea
from .fifo import SetpointFifo
from .hw.board import AxisIn, DigitalIn, DigitalOut
from .layout import ClockKind, Proc, ServoFault, ServoState

_CLOCK_NAMES = {ClockKind.VIRTUAL: "virtual", ClockKind.REALTIME: "realtime", ClockKind.REALTIME_FALLBACK: "realtime-fallback"}


class Gateway:
    """Cyclic status publisher; later issues add events, commands and queries here."""

    def __init__(self, config: MachineConfig, area: SharedArea, fifo: SetpointFifo, session: zenoh.Session, clock: str):
        self.config, self.area, self.fifo = config, area, fifo
        self.keys = Keys(config.zenoh.key_prefix, config.machine.name)
        self.hw, self.servo = area.reader("hw"), area.reader("servo")
        self.shutdown = area.blocks["command"].array["shutdown"]
        hb = area.blocks["heartbeat"].array[0]
        self.beat = hb["beat"]
        hb["pid"][Proc.GATEWAY] = os.getpid()
        self.token = session.liveliness().declare_token(self.keys.alive("gateway"))
        self.publisher = session.declare_publisher(
            self.keys.status, encoding=zenoh.Encoding.APPLICATION_JSON, congestion_control=zenoh.CongestionControl.DROP
        )
        self.period_s = 1.0 / config.gateway.status_rate_hz
        self.seq = 0

    def status(self) -> Status:
        """Assemble one status message from consistent snapshots of the blocks."""
        hw, sv = self.hw.read_dict(), self.servo.read_dict()
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
        )

    def run(self) -> None:
        next_t = time.monotonic()
        while not self.shutdown[0] & (1 << Proc.GATEWAY):
            self.publisher.put(encode(self.status()))
            self.beat[Proc.GATEWAY] += 1
            next_t += self.period_s
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                next_t = time.monotonic()

    def close(self) -> None:
        self.publisher.undeclare()
        self.token.undeclare()
