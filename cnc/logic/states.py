"""Modes, machine states and automatic-cycle phases of the control logic: defined with the message
schemas (`cnc.bus.states`), where the HMI takes them from too."""

from __future__ import annotations

from ..bus.states import CyclePhase, MachineState, Mode  # noqa: F401 - defined with the schemas


