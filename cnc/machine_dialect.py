"""The G-code dialect of a machine: its axes, M-code map and nozzle table, from the machine file."""

from __future__ import annotations

from pathlib import Path

from gcode.dialect import Dialect, read_tool_table

from .config import MachineConfig

NUMBERED_OUTPUTS = 4  # M62-M65 P0..P3 drive the board's AUX1..AUX4 (cnc.planner.sections.output_flags)


def dialect_for(config: MachineConfig, tool_table: str | Path | None = None) -> Dialect:
    """Build the interpreter's dialect; `tool_table` (LinuxCNC format) overrides the machine's nozzles."""
    m = config.mcodes
    mcodes: dict[int, tuple[str, ...]] = {}
    for action, code in (
        ("jet_on", m.jet_on), ("jet_off", m.jet_off), ("abrasive_on", m.abrasive_on),
        ("abrasive_off", m.abrasive_off), ("aux1_on", m.aux1_on), ("aux1_off", m.aux1_off),
    ):
        if code:
            mcodes[code] = mcodes.get(code, ()) + (action,)
    if tool_table is None and config.gcode.tool_table:
        tool_table = Path(config.source).parent / config.gcode.tool_table
    if tool_table is not None:
        tools = read_tool_table(tool_table)
    else:
        tools = {n.number: n.kerf_mm for n in config.nozzle}
    return Dialect(
        axes="".join(config.axis_names),
        mcodes=mcodes,
        tool_diameters_mm=tools,
        default_tolerance_mm=config.gcode.default_tolerance_mm,
        block_delete=config.gcode.block_delete,
        max_seconds=config.gcode.interpret_timeout_s,
        outputs=NUMBERED_OUTPUTS,
    )
