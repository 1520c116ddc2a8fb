"""What the interpreter needs to know about the machine: axes, the M-code map, the nozzle table.

The controller builds a `Dialect` from its machine file; `gcode` itself never reads the
machine file, so the library stays usable on its own (the HMI preview, tools, tests).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from .errors import GCodeError

AUX_BITS = {"abrasive": 0, "aux1": 1, "aux2": 2, "aux3": 3, "aux4": 4}
ACTIONS = ("jet_on", "jet_off") + tuple(f"{n}_{s}" for n in AUX_BITS for s in ("on", "off"))

DEFAULT_MCODES = {
    3: ("jet_on",),
    5: ("jet_off",),
    7: ("abrasive_on",),
    8: ("aux1_on",),
    9: ("abrasive_off", "aux1_off"),
}


@dataclass(frozen=True)
class Dialect:
    """The machine-dependent part of the G-code language."""

    axes: str = "xyz"  # axis letters the machine has, lower case
    mcodes: dict[int, tuple[str, ...]] = field(default_factory=lambda: dict(DEFAULT_MCODES))
    tool_diameters_mm: dict[int, float] = field(default_factory=dict)  # tool (nozzle) number -> kerf width
    default_tolerance_mm: float = 0.0  # G64 without P, and the mode at program start; 0 = no limit given
    start_position_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    block_delete: bool = False  # the block-delete switch: skip lines starting with '/' when on
    max_blocks: int = 20_000_000  # executed blocks before the program is judged to loop forever
    max_seconds: float = 0.0  # interpreting longer than this is judged a runaway too (0: no limit)
    max_call_depth: int = 10
    outputs: int = 32  # numbered outputs M62-M65 may switch: P0 .. P(outputs - 1)

    def __post_init__(self) -> None:
        for code, actions in self.mcodes.items():
            for a in actions:
                if a not in ACTIONS:
                    raise ValueError(f"M{code}: unknown action {a!r} (known: {', '.join(ACTIONS)})")


_TOOL_FIELD = re.compile(r"([TPDXYZABCUVWIJQR])\s*([-+]?(?:\d+\.?\d*|\.\d+))", re.IGNORECASE)


def read_tool_table(path: str | Path, scale_to_mm: float = 1.0) -> dict[int, float]:
    """Tool number -> diameter (mm) from a LinuxCNC tool table (`T1 P1 D2.0 ;comment` lines)."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8", errors="replace")
    except OSError as exc:
        raise GCodeError(f"cannot read tool table: {exc.strerror}", code="tool-table", file=str(path)) from None
    tools: dict[int, float] = {}
    for n, raw in enumerate(text.splitlines(), start=1):
        body = raw.split(";", 1)[0].strip()
        if not body:
            continue
        fields, pos = {}, 0
        for m in _TOOL_FIELD.finditer(body):
            if body[pos : m.start()].strip():
                break
            fields[m.group(1).upper()] = float(m.group(2))
            pos = m.end()
        if body[pos:].strip() or "T" not in fields:
            raise GCodeError(
                "tool table line must be fields like 'T1 P1 D2.0' (T is required)",
                code="tool-table", file=str(path), line=n, column=pos + 1, source_line=raw,
            )
        t = fields["T"]
        if t != int(t) or t < 0:
            raise GCodeError(f"tool number T{t:g} must be a whole number >= 0", code="tool-table", file=str(path), line=n, column=1, source_line=raw)
        d = fields.get("D", 0.0) * scale_to_mm
        if d < 0 or not math.isfinite(d):
            raise GCodeError(f"tool T{int(t)} diameter {d:g} must be >= 0", code="tool-table", file=str(path), line=n, column=1, source_line=raw)
        tools[int(t)] = d
    return tools
