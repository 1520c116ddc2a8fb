"""Typed messages on the bus, declared once and shared by the controller and the HMI.

Payloads are JSON (Zenoh encoding application/json). Every top-level message carries
`version`: a reader refuses, clearly, a message whose major version it does not know.
"""

from __future__ import annotations

import msgspec

SCHEMA_VERSION = 1


class SchemaVersionError(ValueError):
    """The peer speaks a message schema this side does not understand."""


class AxisStatus(msgspec.Struct, frozen=True):
    name: str
    position_mm: float
    commanded_mm: float
    following_error_mm: float
    max_following_error_mm: float
    velocity_mm_s: float
    speed_command_v: float
    limit_min: bool
    limit_max: bool
    home_switch: bool
    drive_ready: bool
    drive_enabled: bool
    homed: bool = False


class Status(msgspec.Struct, frozen=True):
    """Cyclic controller status (`<root>/status`)."""

    machine: str
    seq: int
    stamp_ns: int  # wall-clock time of publication, ns since the epoch
    tick: int
    clock: str  # virtual | realtime | realtime-fallback
    servo_state: str  # ServoState name
    fault: str  # ServoFault name, NONE when healthy
    fault_axis: str  # axis name or "" when the fault is not an axis's
    watchdog_tripped: bool
    safe_state: bool
    estop_ok: bool
    doors_closed: bool
    jet_on: bool
    axes: list[AxisStatus]
    overruns: int
    underruns: int
    late_ticks: int
    servo_missed_ticks: int
    fifo_fill: int
    version: int = SCHEMA_VERSION


_encoder = msgspec.json.Encoder()


def encode(msg: msgspec.Struct) -> bytes:
    return _encoder.encode(msg)


def decode(payload: bytes, kind: type[msgspec.Struct]) -> msgspec.Struct:
    """Decode and check the schema version; raises SchemaVersionError or msgspec.ValidationError."""
    try:
        version = msgspec.json.decode(payload, type=_Versioned).version
    except msgspec.ValidationError:
        version = None
    if version != SCHEMA_VERSION:
        raise SchemaVersionError(
            f"{kind.__name__}: message schema version {version} is not the supported version {SCHEMA_VERSION}"
        )
    return msgspec.json.decode(payload, type=kind)


class _Versioned(msgspec.Struct):
    version: int | None = None
