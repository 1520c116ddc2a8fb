"""Finding, building and checking a machine's control program (`[control] program`).

A program is named three ways: a shipped one by its short name (`SHIPPED`), a class in an
importable module (`package.module:Class`), or a class in a Python file beside the machine file
(`friction.py:Class`, the machine builder's own). `build` makes the program of a machine with
the values of its own parameters from `[control.parameters]`; every error names the machine
file, the key and what is wrong, and nothing is half-built.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path

from ..config import MachineConfig
from .program import ControlProgram, ControlProgramError

SHIPPED: dict[str, str] = {
    "pip": "cnc.control.pip:PIP",
    "friction_ff": "cnc.control.examples.friction:FrictionFeedForward",
    "cross_coupled": "cnc.control.examples.cross_coupled:CrossCoupled",
    "fault_injection": "cnc.control.examples.faulty:Faulty",
}


def _where(config: MachineConfig, key: str = "program") -> str:
    return f"{config.source}: [control] {key}"


def program_class(config: MachineConfig, spec: str | None = None) -> type[ControlProgram]:
    """The class `spec` (default the machine file's `[control] program`) names."""
    spec = config.control.program if spec is None else spec
    target = SHIPPED.get(spec, spec)
    module_name, _, class_name = target.partition(":")
    if not module_name or not class_name:
        raise ControlProgramError(f"{_where(config)}: {spec!r} is neither a shipped program ({', '.join(SHIPPED)}) nor "
                                  "'package.module:Class' nor 'file.py:Class'")
    try:
        if module_name.endswith(".py"):
            module = _file_module(config, module_name)
        else:
            module = importlib.import_module(module_name)
    except ControlProgramError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever a user module raises on import is the answer
        raise ControlProgramError(f"{_where(config)}: {spec!r}: importing {module_name} failed: "
                                  f"{type(exc).__name__}: {exc}") from None
    cls = getattr(module, class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, ControlProgram)) or cls is ControlProgram:
        raise ControlProgramError(f"{_where(config)}: {spec!r}: {module_name} has no ControlProgram subclass "
                                  f"{class_name!r}")
    return cls


def _file_module(config: MachineConfig, file_name: str):  # noqa: ANN202 - a module
    base = Path(config.source).parent if config.source not in ("<defaults>", "<string>") else Path.cwd()
    path = (base / file_name).resolve()
    if not path.is_file():
        raise ControlProgramError(f"{_where(config)}: {file_name!r}: no such file beside the machine file ({path})")
    name = f"wj_control_{path.stem}_{abs(hash(str(path))) & 0xFFFFFF:06x}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise ControlProgramError(f"{_where(config)}: {file_name!r} is not a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def build(config: MachineConfig, spec: str | None = None) -> ControlProgram:
    """The machine's control program, built, its registrations checked and its own parameters
    set from `[control.parameters]` (a per-axis one from `[control.parameters.<axis>]`)."""
    cls = program_class(config, spec)
    name = spec or config.control.program
    try:
        program = cls(config)
    except ControlProgramError as exc:
        raise ControlProgramError(f"{_where(config)}: {name!r}: {exc}") from None
    except Exception as exc:  # noqa: BLE001
        raise ControlProgramError(f"{_where(config)}: {name!r}: building it failed: {type(exc).__name__}: {exc}") from None
    if spec is None or spec == config.control.program:
        _apply_values(config, program)
    return program


def _apply_values(config: MachineConfig, program: ControlProgram) -> None:
    given = config.control.parameters
    own = {p.name: p for p in program.parameters if not p.option}
    for key, value in given.items():
        if isinstance(value, dict):  # [control.parameters.<axis>]
            if key not in config.axis_names:
                raise ControlProgramError(f"{config.source}: [control.parameters] {key}: this machine has no axis {key!r}")
            for pname, v in value.items():
                spec = own.get(pname)
                if spec is None or not spec.per_axis:
                    raise ControlProgramError(f"{config.source}: [control.parameters.{key}] {pname}: "
                                              f"{_known(program, True)}")
                _check_range(config, f"[control.parameters.{key}] {pname}", spec, v)
                getattr(program, pname)[config.axis_names.index(key)] = v
            continue
        spec = own.get(key)
        if spec is None or spec.per_axis:
            raise ControlProgramError(f"{config.source}: [control.parameters] {key}: {_known(program, False)}")
        _check_range(config, f"[control.parameters] {key}", spec, value)
        setattr(program, key, value)


def _known(program: ControlProgram, per_axis: bool) -> str:
    names = [p.name for p in program.parameters if not p.option and p.per_axis == per_axis]
    kind = "per-axis parameter" if per_axis else "parameter"
    return (f"{type(program).__name__} has no such {kind}" + (f" (known: {', '.join(names)})" if names else " (it has none)"))


def _check_range(config: MachineConfig, where: str, spec, value: float) -> None:  # noqa: ANN001
    if not spec.lo <= value <= spec.hi:
        raise ControlProgramError(f"{config.source}: {where}: {value:g} is out of range: allowed {spec.lo:g} to "
                                  f"{spec.hi:g}" + (f" {spec.unit}" if spec.unit else ""))
