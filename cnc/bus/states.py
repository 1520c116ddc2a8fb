"""The states, faults and alarm levels the controller reports, one definition for the controller and the HMI.

The processes keep them as numbers in shared memory (`cnc.data.layout`, `cnc.logic`); the status
message carries their names; a station compares against these, never against a spelled-out
string. Numbers are stable: never reuse one.
"""

from __future__ import annotations

import enum


class Mode(enum.IntEnum):
    MANUAL = 0  # jog, home, go-to, pump and jet by hand
    AUTO = 1  # the automatic cycle


class MachineState(enum.IntEnum):
    """What the machine is doing, as the operator sees it."""

    IDLE = 0  # drives off or axes not homed: nothing may run automatically
    HOMING = 1
    READY = 2  # drives on, homed, no blocking alarm: cycle start allowed (AUTO)
    RUNNING = 3  # the automatic cycle: transport or cutting phase (see CyclePhase)
    HOLD = 4  # the cycle is held: motion stopped on the path, the sequence paused
    STOPPED = 5  # the operator stopped the cycle; start begins a new one
    ESTOP = 6  # emergency stop or safety circuit open
    FAULT = 7  # a fatal or error alarm waits for reset
    JOGGING = 8  # manual motion: jog or go-to
    MDI = 9  # G-code typed by hand runs (manual data input, MANUAL mode)


class CyclePhase(enum.IntEnum):
    """Where the automatic cycle is (the paper's transport and cutting phases)."""

    NONE = 0
    PROCEDURE = 1  # the transport procedure walks the operator through the preconditions
    TRANSPORT = 2  # the PLC feeds material, the gripper closes on it
    PRESSURE = 3  # the pump ramps to its pierce or cutting pressure
    CUTTING = 4  # the NC program runs
    UNLOAD = 5  # the gripper opens, the pieces go to the output section


class ClockKind(enum.IntEnum):
    VIRTUAL = 0
    REALTIME = 1  # SCHED_FIFO and mlockall in force
    REALTIME_FALLBACK = 2  # absolute deadlines, but the scheduler class could not be raised


class ServoState(enum.IntEnum):
    DISABLED = 0  # drives off, loop open, commanded position follows actual
    HOLDING = 1  # drives on, holding the last commanded position
    TRACKING = 2  # drives on, following setpoints from the FIFO
    FAULT = 3  # tripped: speed 0, drives off, jet off until reset
    STOPPING = 4  # tripped, jet off, the drives still on: the servo brings the axes to rest itself, then FAULT


class PlannerState(enum.IntEnum):
    """What the planner is doing. Numbers are stable."""

    IDLE = 0
    RUNNING = 1  # a program
    HOLDING = 2  # decelerating to a feed hold
    HELD = 3
    PAUSED = 4  # at a program stop (M0, M1, M60), waiting for cycle start
    STOPPING = 5  # decelerating, then the program ends
    HOMING = 6
    JOGGING = 7
    MOVING = 8  # go-to-position
    MDI = 9  # G-code typed by hand (manual data input)


class ProgramCheck(enum.StrEnum):
    """How far the program library got with a stored program (`ProgramEntry.summary`)."""

    PENDING = "pending"  # not checked yet: new, or changed since
    READY = "ready"  # valid: the figures are its own
    REFUSED = "refused"  # it would be refused: the entry's `error` says where and why


class RunResult(enum.IntEnum):
    """How the last program run ended."""

    NONE = 0
    DONE = 1
    ABORTED = 2  # stopped by the operator
    FAULT = 3  # the servo tripped, or the planner failed


class ServoFault(enum.IntEnum):
    """Why the servo tripped. Numbers are stable: never reuse one."""

    NONE = 0
    FOLLOWING_ERROR = 1
    SOFT_LIMIT = 2
    HARD_LIMIT = 3
    DRIVE_FAULT = 4
    WATCHDOG = 5
    ESTOP = 6
    RESTARTED = 7  # the servo process was restarted: position continuity must be confirmed by reset
    SAFE_STATE = 8  # the supervisor forced the safe state
    UNDERRUN = 9  # the setpoint FIFO ran dry in the middle of a motion
    MAINS = 10  # the machine mains went off: the drives have no power
    DOORS = 11  # a safety door opened
    SAFETY_CIRCUIT = 12  # the PLC reports the safety circuit open
    BARRIER = 13  # a light barrier was interrupted while the automatic cycle ran
    PUMP = 14  # the pump reports a fault, or its pressure fell below the commander's floor with the jet open
    PLC_LINK = 15  # the PLC's inputs stopped being fresh (link lost, or its process hung or dead)
    COMMANDER = 16  # the commander (the control logic) stopped beating, or died while writing its block
    CONTROL_PROGRAM = 17  # the control program raised, returned no finite command, or overran its budget


class LinkState(enum.IntEnum):
    """The PLC link as the PLC-link process sees it. Numbers are stable."""

    DOWN = 0  # not started, or no serial port
    CONNECTING = 1  # port opening, or waiting before a reconnection attempt
    OK = 2  # exchanging
    LOST = 3  # lost_after_cycles consecutive exchanges failed; reconnecting


ALARM_CODE_MAX = 999_999  # alarm codes are 1 to this (a machine file's [[alarm]] code, a station's code filter)


class AlarmLevel(enum.IntEnum):
    """How severe an alarm is. A larger value is more severe, so `max()` of levels is the worst one
    and `level >= AlarmLevel.ERROR` reads as "at least an error". The numbers are stable."""

    INFO = 1
    WARNING = 2
    ERROR = 3
    FATAL = 4

    @property
    def stops_cut(self) -> bool:
        """Fatal and error alarms stop the cut and keep the machine from starting until reset."""
        return self >= AlarmLevel.ERROR

    @property
    def latched(self) -> bool:
        """Whether the alarm stays listed after its condition clears, until reset. Info-level
        entries are prompts and notices, not faults: they disappear when cleared."""
        return self > AlarmLevel.INFO

    @property
    def text(self) -> str:
        """The level as the machine file and the bus messages spell it: fatal | error | warning | info."""
        return self.name.lower()

    @classmethod
    def parse(cls, text: str) -> AlarmLevel:
        """The level named by `text` (as in the machine file); ValueError naming it when unknown."""
        try:
            return cls[text.upper()]
        except KeyError:
            known = ", ".join(level.text for level in cls)
            raise ValueError(f"alarm level {text!r} is not one of {known}") from None
