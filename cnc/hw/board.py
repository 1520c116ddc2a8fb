"""IOBoard: the narrow interface between the hardware server and an I/O board.

The hardware server is the only caller. Each base tick it writes outputs (speed commands,
drive enables, digital outputs), lets the board advance to the next sample (a real board
latches its inputs on the hardware sync signal; the simulated board integrates its plant),
then reads the inputs. Buffers are filled in place so the tick path allocates nothing.

What the software cannot replace, a real board must add: an output watchdog that drops the
outputs when the host stops refreshing them (`arm_output_watchdog`), and a hardwired e-stop
circuit that cuts the drives' power and the jet valve whatever the host does (the board only
reports it, as `DigitalIn.ESTOP_OK`).
"""

from __future__ import annotations

import abc
import enum
from dataclasses import dataclass, field


class DigitalIn(enum.IntFlag):
    """Machine-wide digital inputs (bit positions are part of the shared-memory layout)."""

    ESTOP_OK = 1 << 0  # e-stop circuit closed: no e-stop pressed
    DOORS_CLOSED = 1 << 1  # safety doors closed
    MAINS_ON = 1 << 2  # machine mains contactor on


class AxisIn(enum.IntFlag):
    """Per-axis digital inputs, one word per axis."""

    LIMIT_MIN = 1 << 0  # hard limit switch at the lower travel end is active
    LIMIT_MAX = 1 << 1  # hard limit switch at the upper travel end is active
    HOME = 1 << 2  # home switch active
    INDEX = 1 << 3  # encoder index pulse seen during the last tick
    DRIVE_READY = 1 << 4  # drive powered and without fault
    DRIVE_ENABLED = 1 << 5  # read-back: the drive's power stage is enabled


class DigitalOut(enum.IntFlag):
    """Digital outputs."""

    JET_VALVE = 1 << 0  # cutting-head valve open: water jet on
    ABRASIVE = 1 << 1  # abrasive feed
    AUX1 = 1 << 2
    AUX2 = 1 << 3
    AUX3 = 1 << 4
    AUX4 = 1 << 5


@dataclass
class BoardInputs:
    """One tick's inputs; the hardware server owns one instance and the board fills it."""

    n_axes: int
    encoder_counts: list[int] = field(default_factory=list)
    axis_inputs: list[int] = field(default_factory=list)
    index_latch_counts: list[int] = field(default_factory=list)  # encoder count at the last index pulse
    index_latch_seq: list[int] = field(default_factory=list)  # +1 at every index pulse
    digital_in: int = 0
    digital_out: int = 0  # read-back of what the board actually drives (after safe-state forcing)

    def __post_init__(self) -> None:
        for name in ("encoder_counts", "axis_inputs", "index_latch_counts", "index_latch_seq"):
            if not getattr(self, name):
                setattr(self, name, [0] * self.n_axes)


class IOBoard(abc.ABC):
    """What the hardware server needs from a board. Implementations: `SimBoard`."""

    n_axes: int

    @abc.abstractmethod
    def write_outputs(self, speed_cmd_v: list[float], drive_enable_mask: int, digital_out: int) -> None:
        """Set the DAC speed commands (volts), drive enables (bit i = axis i) and digital outputs."""

    @abc.abstractmethod
    def advance(self, dt_s: float) -> None:
        """Move to the next sample instant, dt_s after the previous one."""

    @abc.abstractmethod
    def read_inputs(self, into: BoardInputs) -> None:
        """Fill `into` with the inputs latched at the current sample instant."""

    @abc.abstractmethod
    def safe_state(self) -> None:
        """Watchdog action: speed commands 0, drives disabled, jet valve and outputs closed, at once."""

    @abc.abstractmethod
    def arm_output_watchdog(self, timeout_s: float) -> None:
        """The board's own output watchdog: when `write_outputs` (or `safe_state`) has not been called
        for `timeout_s` of the board's time, the board drops its outputs by itself (speed commands 0,
        drives disabled, every digital output off) until the next write. A real board implements it
        in hardware (a charge pump or a watchdog timer on the interface card), so that a host that
        stops (a crash, a hung kernel, a pulled cable) cannot leave the jet open or the drives
        driving; the hardware server arms it at start."""

    def close(self) -> None:
        """Release the board (default: nothing to release)."""
