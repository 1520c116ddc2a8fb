"""Modes, machine states and automatic-cycle phases of the control logic (numbers are stable)."""

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


class CyclePhase(enum.IntEnum):
    """Where the automatic cycle is (the paper's transport and cutting phases)."""

    NONE = 0
    PROCEDURE = 1  # the transport procedure walks the operator through the preconditions
    TRANSPORT = 2  # the PLC feeds material, the gripper closes on it
    PRESSURE = 3  # the pump ramps to its pierce or cutting pressure
    CUTTING = 4  # the NC program runs
    UNLOAD = 5  # the gripper opens, the pieces go to the output section
