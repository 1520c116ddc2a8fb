"""The safety alarms in code: which alarm every servo fault and stop-cut cause raises, and how low a
machine file may set it.

What stops a cut is a decision of the code, as grblHAL's `alarm_is_critical()` is: a machine file
may reword an alarm (text, cause, remedy) or make it graver, never demote one of these below
`error` (a warning neither stops the cut nor blocks a start), and a catalogue without one of them
is refused at load, naming the id it lacks. Every servo fault, a drive's included, has its alarm.
"""

from __future__ import annotations

from .data.layout import ServoFault

ERROR, FATAL = "error", "fatal"
LEVEL_ORDER = ("info", "warning", "error", "fatal")

# The stop-cut alarms and servo faults: id -> the lowest level a machine file may give them.
SAFETY_ALARMS: dict[str, str] = {
    "estop": ERROR,
    "mains_off": ERROR,
    "doors_open": ERROR,
    "barrier_interrupted": ERROR,
    "pump_pressure_fault": ERROR,
    "plc_link_lost": ERROR,
    "following_error": ERROR,
    "soft_limit": ERROR,
    "hard_limit": ERROR,
    "watchdog": ERROR,
    "fifo_underrun": ERROR,
    "process_lost": ERROR,
    "control_program": ERROR,
}

# The alarms of the servo's faults; DRIVE_FAULT raises the faulted axis' `<axis>_drive`.
FAULT_ALARMS: dict[ServoFault, str] = {
    ServoFault.FOLLOWING_ERROR: "following_error",
    ServoFault.SOFT_LIMIT: "soft_limit",
    ServoFault.HARD_LIMIT: "hard_limit",
    ServoFault.WATCHDOG: "watchdog",
    ServoFault.ESTOP: "estop",
    ServoFault.RESTARTED: "process_lost",
    ServoFault.SAFE_STATE: "process_lost",
    ServoFault.UNDERRUN: "fifo_underrun",
    ServoFault.MAINS: "mains_off",
    ServoFault.DOORS: "doors_open",
    ServoFault.SAFETY_CIRCUIT: "estop",
    ServoFault.BARRIER: "barrier_interrupted",
    ServoFault.PUMP: "pump_pressure_fault",
    ServoFault.PLC_LINK: "plc_link_lost",
    ServoFault.COMMANDER: "process_lost",
    ServoFault.CONTROL_PROGRAM: "control_program",
}


def drive_alarm(axis: str) -> str:
    """The alarm of one axis' drive fault: `x_drive`, `y_drive`."""
    return f"{axis}_drive"


def fault_alarm(fault: ServoFault, axis_names: tuple[str, ...], axis: int) -> str:
    """The alarm id a servo fault raises (a drive fault: the faulted axis' own)."""
    if fault == ServoFault.DRIVE_FAULT:
        return drive_alarm(axis_names[axis] if 0 <= axis < len(axis_names) else axis_names[0])
    return FAULT_ALARMS[fault]


def minimum_levels(axis_names: tuple[str, ...]) -> dict[str, str]:
    """Every safety alarm of a machine with these axes, and its lowest allowed level."""
    return {**SAFETY_ALARMS, **{drive_alarm(a): ERROR for a in axis_names}}


def below(level: str, minimum: str) -> bool:
    """Whether `level` is less grave than `minimum`."""
    return LEVEL_ORDER.index(level) < LEVEL_ORDER.index(minimum)
