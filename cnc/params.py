"""Control parameters (QMotor's): the machine-file options an engineer may change while the machine runs.

Each parameter is one option of the machine file (`axis.x.kp_1_s`, `planner.jog_velocity_mm_s`),
registered with the name, description, unit and allowed range its option declares, the process
that applies it and when it may change. The gateway validates a change and writes it into the
`params` block (its only writer); the owning process applies it at a tick boundary: the servo
checks the block's sequence number every tick (one 8-byte read) and copies the new values before
it computes that tick; the planner at its next wake, and only while no program runs. "Save"
writes the values in force back into the machine file, keeping its layout and comments.

The order of `registry(config)` is the order of the block's slots: every process builds the same
list from the same machine file.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

from .config import MachineConfig, loads_machine
from .data.layout import MAX_PARAMS

# (table, key, owner, when it may change, when it takes effect) per option. The axis control law's
# parameters are its control program's registrations (`cnc.control`); the servo's supervision
# keeps its own: the following-error limit of every axis.
_SERVO_AXIS_OPTIONS = ("following_error_limit_mm",)
_OTHERS = (
    ("planner", "jog_velocity_mm_s", "planner", "always", "the next jog"),
    ("planner", "arc_normal_share", "planner", "idle", "the next program start"),
    ("planner", "fifo_low_ms", "planner", "idle", "the next refill"),
    ("planner", "fifo_high_ms", "planner", "idle", "the next refill"),
    ("gcode", "default_tolerance_mm", "planner", "idle", "the next program loaded"),
    ("jet", "on_delay_s", "planner", "idle", "the next program loaded"),
    ("jet", "pierce_dwell_s", "planner", "idle", "the next program loaded"),
    ("jet", "off_delay_s", "planner", "idle", "the next program loaded"),
)
IDLE_STATES = ("IDLE", "HELD", "PAUSED", "JOGGING", "MOVING", "MDI", "HOMING")  # planner states with no program running


class ParamError(ValueError):
    """A parameter change refused: unknown name, out of range, or not now; the text says why."""


@dataclass(frozen=True)
class ParamSpec:
    """One control parameter: where it lives in the machine file and how it may change."""

    name: str  # "axis.x.kp_1_s"
    path: tuple[str, ...]  # tables down to the option: ("axis", "x")
    key: str  # the option: "kp_1_s"
    description: str
    unit: str
    lo: float
    hi: float
    owner: str  # "servo" | "planner": the process that applies it
    when: str  # "always" | "idle": changeable at any time, or only while no program runs
    effect: str  # when the machine feels it
    index: int  # slot in the params block
    default: float | None = None  # a control program's own parameter: its registered value (the file may omit it)

    def check(self, value: float, planner_state: str) -> None:
        """ParamError when `value` may not be set now: not a finite number, out of range, or the state forbids it."""
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
            raise ParamError(f"{self.name}: {value!r} is not a finite number")
        if not self.lo <= value <= self.hi:
            raise ParamError(f"{self.name}: {value:g} is out of range: allowed {self.lo:g} to {self.hi:g}"
                             + (f" {self.unit}" if self.unit else ""))
        if self.when == "idle" and planner_state not in IDLE_STATES:
            raise ParamError(f"{self.name}: not changeable while the planner is {planner_state} "
                             f"(a program is running); it takes effect at {self.effect}")


def registry(config: MachineConfig) -> list[ParamSpec]:
    """Every control parameter of this machine, in block-slot order: its control program's (an
    `[axis]` option per axis, `axis.<a>.<key>`; its own, `control.<name>` or `control.<a>.<name>`),
    the servo's following-error limits, then the planner's."""
    from .control.loader import build  # noqa: PLC0415 - the loader imports the config, as this module does

    program = build(config)
    specs: list[ParamSpec] = []

    def add(path: tuple[str, ...], key: str, doc: str, unit: str, lo: float, hi: float, owner: str, when: str,
            effect: str, default: float | None = None) -> None:
        shown = ("control", *path[2:]) if path[:2] == ("control", "parameters") else path  # control.<a>.<name>
        name = ".".join((*shown, key))
        specs.append(ParamSpec(name, path, key, doc, unit, lo, hi, owner, when, effect, len(specs), default))

    for axis in config.axis_names:
        for p in program.parameters:
            if p.option:
                meta = _meta(config.axis[axis], p.option)
                add(("axis", axis), p.option, meta["doc"], meta["unit"], float(meta["lo"]), float(meta["hi"]),
                    "servo", "always", "the next tick")
        for key in _SERVO_AXIS_OPTIONS:
            meta = _meta(config.axis[axis], key)
            add(("axis", axis), key, meta["doc"], meta["unit"], float(meta["lo"]), float(meta["hi"]), "servo", "always",
                "the next tick")
    for p in program.parameters:
        if p.option:
            continue
        if p.per_axis:
            for k, axis in enumerate(config.axis_names):
                add(("control", "parameters", axis), p.name, p.doc, p.unit, p.lo, p.hi, "servo", "always", "the next tick",
                    float(p.value[k]))
        else:
            add(("control", "parameters"), p.name, p.doc, p.unit, p.lo, p.hi, "servo", "always", "the next tick",
                float(p.value))
    for table, key, owner, when, effect in _OTHERS:
        meta = _meta(_table(config, (table,)), key)
        add((table,), key, meta["doc"], meta["unit"], float(meta["lo"]), float(meta["hi"]), owner, when, effect)
    if len(specs) > MAX_PARAMS:
        raise ValueError(f"{len(specs)} control parameters do not fit the params block ({MAX_PARAMS})")
    return specs


def _meta(table: object, key: str) -> dict:
    return {f.name: f.metadata for f in dataclasses.fields(table)}[key]


def _table(config: MachineConfig, path: tuple[str, ...]) -> object:
    node: object = config
    for part in path:
        node = node.get(part, {}) if isinstance(node, dict) else getattr(node, part)
    return node


def value_of(config: MachineConfig, spec: ParamSpec) -> float:
    table = _table(config, spec.path)
    if isinstance(table, dict):  # [control.parameters]: what the file leaves out is the program's registered value
        return float(table.get(spec.key, spec.default))
    return float(getattr(table, spec.key))


def values_of(config: MachineConfig, specs: list[ParamSpec]) -> list[float]:
    return [value_of(config, s) for s in specs]


def with_values(config: MachineConfig, specs: list[ParamSpec], values: list[float]) -> MachineConfig:
    """The configuration with these parameter values in it (the rest untouched)."""
    for spec, value in zip(specs, values):
        if value_of(config, spec) == value:
            continue
        table = _table(config, spec.path)
        config = _replace(config, spec.path, spec.key, float(value) if isinstance(table, dict) else
                          type(getattr(table, spec.key))(value))
    return config


def _replace(node: object, path: tuple[str, ...], key: str, value: object) -> object:
    if not path:
        if isinstance(node, dict):
            return {**node, key: value}
        return dataclasses.replace(node, **{key: value})
    head, rest = path[0], path[1:]
    if isinstance(node, dict):
        return {**node, head: _replace(node.get(head, {}), rest, key, value)}
    return dataclasses.replace(node, **{head: _replace(getattr(node, head), rest, key, value)})


def find(specs: list[ParamSpec], name: str) -> ParamSpec:
    for spec in specs:
        if spec.name == name:
            return spec
    raise ParamError(f"no control parameter {name!r} (known: {', '.join(s.name for s in specs)})")


# -- saving into the machine file ------------------------------------------------------------

_HEADER = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\-\"]+)\s*\]\s*(#.*)?$")
_ARRAY_HEADER = re.compile(r"^\s*\[\[")


def save(path: str | Path, changes: dict[tuple[tuple[str, ...], str], float]) -> list[str]:
    """Write `changes` ({(table path, key): value}) into the machine file at `path`, keeping every
    other line, comment and the order as they are; an option the file leaves to its default is
    added to its table (the table too, at the end, when the file has none). The result is
    validated as a machine file before it replaces the original, which is kept as `<file>.bak`.
    Returns the dotted names written. ConfigError when the result would not load."""
    # TOML reads Python's shortest float repr back exactly ("120.0", "1e-05")
    return save_literals(path, {where: repr(float(value)) for where, value in changes.items()})


def save_literals(path: str | Path, changes: dict[tuple[tuple[str, ...], str], str]) -> list[str]:
    """`save` with the TOML literals given (`'"pip"'`, `'120.0'`): the same edit, check and backup."""
    path = Path(path)
    text, written = check_literals(path, changes)
    tmp = path.with_name(f".{path.name}.new")
    tmp.write_text(text, encoding="utf-8")
    backup = path.with_name(path.name + ".bak")
    backup.write_bytes(path.read_bytes())
    os.replace(tmp, path)
    return written


def toml_string(text: str) -> str:
    """`text` as a TOML basic string literal, for `save_literals` and `check_literals`."""
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def check_literals(path: str | Path, changes: dict[tuple[tuple[str, ...], str], str]) -> tuple[str, list[str]]:
    """The machine file's text with the literals changed, and the keys written; ConfigError, naming
    the key, for anything the edit would break. Writes nothing."""
    path = Path(path)
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    written = []
    for (table, key), literal in changes.items():
        lines = _set_line(lines, ".".join(table), key, literal)
        written.append(".".join((*table, key)))
    text = "".join(lines)
    loads_machine(text, str(path))  # refuses, naming the key, anything the edit broke
    return text, written


def _set_line(lines: list[str], table: str, key: str, literal: str) -> list[str]:
    start, end = _table_span(lines, table)
    assign = re.compile(rf"^(\s*){re.escape(key)}(\s*=\s*)([^#\n]*?)(\s*#.*)?(\n?)$")
    if start is None:
        tail = "" if not lines or lines[-1].endswith("\n") else "\n"
        return [*lines, f"{tail}\n[{table}]\n", f"{key} = {literal}\n"]
    for i in range(start + 1, end):
        m = assign.match(lines[i])
        if m:
            lines = list(lines)
            lines[i] = f"{m.group(1)}{key}{m.group(2)}{literal}{m.group(4) or ''}{m.group(5)}"
            return lines
    insert = end
    while insert > start + 1 and not lines[insert - 1].strip():
        insert -= 1  # after the table's last option, before the blank lines that end it
    return [*lines[:insert], f"{key} = {literal}\n", *lines[insert:]]


def _table_span(lines: list[str], table: str) -> tuple[int | None, int]:
    """(index of the `[table]` header, index of the next header or the end)."""
    start = None
    for i, line in enumerate(lines):
        m = _HEADER.match(line)
        is_header = bool(m) or bool(_ARRAY_HEADER.match(line))
        if start is not None and is_header:
            return start, i
        if m and m.group(1).replace('"', "") == table:
            start = i
    return start, len(lines)

