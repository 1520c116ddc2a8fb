"""Calibrating a material on the machine: the speed ladder checked against this machine, and what the
operator judged recorded into the library (`cnc.materials` has the format and the ladder itself).

The guided procedure (the screen's "Calibrate" on the cutting job, or over Zenoh):

1. `calibration_ladder`: the ladder for a material and thickness, between two speeds, is made,
   checked against the machine (its feed limit, its travel) and stored and loaded as
   `ladder-<material>-<thickness>mm.ngc`, at the programmed feeds whatever cutting job the program
   had before (each rung is announced by a message);
2. the operator cuts it in the automatic cycle, and judges the edges;
3. `calibration_record`: per quality the fastest rung whose edge was good enough, the fastest that
   cut through (separation), the pierce time and kerf, and optionally the trail-back measured on each
   quality's rung, written into the material's file (an engineer's change: it is machine data; the
   source line names who, the audit trail keeps the command).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from .cutmodel import MATERIAL_ID, library_of
from .materials import Ladder, Material, MaterialError, ladder_program, load_material

if TYPE_CHECKING:
    from .config import MachineConfig


def library_material(material_id: str, config: "MachineConfig") -> tuple[Material, Path]:
    """The material `material_id` of the machine's library and its file; MaterialError says why not."""
    if not MATERIAL_ID.fullmatch(material_id):
        raise MaterialError(f"{material_id!r} is not a material id (letters, digits, _ . -)")
    path = library_of(config) / f"{material_id}.toml"
    if not path.is_file():
        raise MaterialError(f"material {material_id!r} is not in the library {library_of(config)}")
    return load_material(path), path


def machine_ladder(material: Material, ladder: Ladder, config: "MachineConfig") -> str:
    """The ladder's G-code, checked against this machine: the fastest rung within its feed limit, the
    whole within its travel (interpreted as `waterjet check` would); MaterialError says why not."""
    from gcode.errors import GCodeError
    from gcode.interp import Interpreter

    from .machine_dialect import dialect_for
    from .planner.preflight import PreflightError, preflight

    fastest_axis = min(a.max_velocity_mm_s for a in config.axes) * 60.0
    if ladder.fastest_mm_min > fastest_axis:
        raise MaterialError(f"ladder: the fastest rung {ladder.fastest_mm_min:g} mm/min is beyond this machine's "
                            f"{fastest_axis:g} mm/min")
    text = ladder_program(material, ladder, config.mcodes.jet_on, config.mcodes.jet_off)
    try:
        program = Interpreter(dialect_for(config), "ladder").run(text.encode())
        preflight(program.segments, config, dict.fromkeys(config.axis_names, True), "ladder")
    except (GCodeError, PreflightError) as exc:
        raise MaterialError(f"ladder: {exc}") from None
    return text


def ladder_name(material_id: str, thickness_mm: float) -> str:
    """The program name a ladder is stored under."""
    return f"ladder-{material_id}-{thickness_mm:g}mm.ngc"
