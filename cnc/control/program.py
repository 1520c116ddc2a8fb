"""Control programs (QMotor's): the axis control law as a user program the servo runs each period.

QMotor 2.0 let the engineer write `init_control`/`control`/`output`/`end_control`; QMotor 3.0 a
`ControlProgram` class whose `registerControlVariable` makes a member a tunable parameter and
`registerLogVariable` a loggable one. This is that interface with Python names:

    class MyLaw(ControlProgram):
        def __init__(self, machine):
            super().__init__(machine)
            self.register_parameter("kp", 80.0, "1/s", (0.0, 1000.0), "position gain", per_axis=True)
            self.register_log_variable("u", "mm/s", "the speed command", per_axis=True)

        def start_control(self):            # the loop closes (drives on, after a reset)
            ...
        def control(self, inputs):          # every servo period: ControlInputs -> speed commands, mm/s
            self.u = [self.kp[i] * inputs.error_mm[i] + inputs.setpoint_velocity_mm_s[i] for i in range(self.n_axes)]
            return self.u
        def stop_control(self):             # the loop opens (drives off, a trip)
            ...

A registered parameter is a member: a float, or a list with one value per axis that the servo
updates in place when the engineer changes it (`axis.<a>.<name>` for per-axis options the
machine file already has, else `control.<name>` / `control.<a>.<name>`, their values under
`[control.parameters]`). A registered log variable is a member the program assigns each period
(a float, a list per axis, or a list of `size` floats); the servo copies it into its trace, and
the data logger, the scope and the `.mat` export take it like any other variable.

What stays outside (the servo's, and no control program can bypass it): the following-error
limit, soft and hard limits, the jet interlocks, the watchdog, the FIFO and the controlled stop.
The servo scales the returned speed commands into volts and clamps them to the drive's full
scale. A program that raises, returns something that is not one finite number per axis, or
uses more CPU time than its budget (`[control] budget_share` of the period) is stopped: the
servo trips (CONTROL_PROGRAM), brings the axes to rest along the path with its own fallback
law (the PI-P of the machine file's gains) and the alarm names the program and what it did.
One that never returns stops the servo itself: the hardware server's watchdog takes the
drives off (a category 0 stop), the one failure the servo cannot stop under control.

A program's constructor must not touch the machine: every process of the controller builds
one to learn its registrations (the gateway to validate parameter changes, the logger to name
its variables); only the servo calls `start_control`/`control`/`stop_control`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

if TYPE_CHECKING:
    from ..config import MachineConfig


class ControlProgramError(ValueError):
    """A control program that cannot run: its module, its class, its registrations, its values."""


@dataclass(frozen=True)
class ParameterSpec:
    """One registered control parameter."""

    name: str
    value: float | tuple[float, ...]  # as registered (per axis: one per axis)
    unit: str
    lo: float
    hi: float
    doc: str
    per_axis: bool
    option: str = ""  # the [axis.<a>] option of the machine file it is (per-axis only), "" when none


@dataclass(frozen=True)
class LogSpec:
    """One registered log variable: `size` floats (per axis: one per axis)."""

    name: str
    unit: str
    doc: str
    per_axis: bool
    size: int

    def names(self, axes: Sequence[str]) -> list[str]:
        """Its names as the logger lists them: `<axis>.<name>`, `control.<name>` or `control.<name>[k]`."""
        if self.per_axis:
            return [f"{a}.{self.name}" for a in axes]
        if self.size == 1:
            return [f"control.{self.name}"]
        return [f"control.{self.name}[{k}]" for k in range(self.size)]


class ControlInputs:
    """What a control program sees each period. Lists per axis, in the machine's axis order;
    the servo fills one instance in place every period (do not keep references to its lists)."""

    __slots__ = ("setpoint_mm", "setpoint_velocity_mm_s", "setpoint_accel_mm_s2", "actual_mm", "velocity_mm_s",
                 "error_mm", "dt_s", "flags", "moving")

    def __init__(self, n: int) -> None:
        self.setpoint_mm = [0.0] * n  # the setpoint record's position (the planner's path, or the servo's own stop)
        self.setpoint_velocity_mm_s = [0.0] * n
        self.setpoint_accel_mm_s2 = [0.0] * n  # from the setpoint velocity's change over the period
        self.actual_mm = [0.0] * n  # the encoders
        self.velocity_mm_s = [0.0] * n  # estimated: the encoders' change over the period
        self.error_mm = [0.0] * n  # setpoint minus actual
        self.dt_s = 0.0  # the time this step covers (a period; more after an overrun)
        self.flags = 0  # the setpoint's output bits (the jet: SetpointFlag.JET_ON)
        self.moving = False  # the setpoint moves (False: holding position)


class ControlProgram:
    """Base class of a control program. Subclasses register their parameters and log variables in
    `__init__` (after `super().__init__(machine)`) and implement `control`."""

    description = ""  # one line for `waterjet control list` and the screen

    def __init__(self, machine: "MachineConfig") -> None:
        self._machine = machine
        self._axes = tuple(machine.axis_names)
        self._period_s = float(machine.timing.period_s)
        self._ticks = 0
        self._elapsed_s = 0.0
        self._parameters: dict[str, ParameterSpec] = {}
        self._logs: dict[str, LogSpec] = {}

    # -- read-only members ------------------------------------------------------------------
    @property
    def machine(self) -> "MachineConfig":
        """The machine file this program runs on (read it in `__init__`; do not change it)."""
        return self._machine

    @property
    def axes(self) -> tuple[str, ...]:
        return self._axes

    @property
    def n_axes(self) -> int:
        return len(self._axes)

    @property
    def period_s(self) -> float:
        """The servo period (the control frequency's inverse)."""
        return self._period_s

    @property
    def ticks(self) -> int:
        """Periods computed since `start_control`."""
        return self._ticks

    @property
    def elapsed_s(self) -> float:
        """Time since `start_control`, in the servo's periods."""
        return self._elapsed_s

    # -- registration -----------------------------------------------------------------------
    def register_parameter(self, name: str, value: float | Sequence[float], unit: str = "",
                           range: tuple[float, float] = (-math.inf, math.inf), doc: str = "",  # noqa: A002 - QMotor's word
                           per_axis: bool = False, option: str = "") -> None:
        """Make member `name` a control parameter: the engineer tunes it while the machine runs
        (within `range`), saves it into the machine file; `per_axis`: a list, one value per axis.
        `option`: the per-axis option of `[axis.<a>]` it is (its value and range come from there)."""
        self._check_name(name)
        lo, hi = (float(range[0]), float(range[1]))
        if not lo <= hi:
            raise ControlProgramError(f"{type(self).__name__}: parameter {name!r}: range {range!r} is empty")
        if option:
            if not per_axis:
                raise ControlProgramError(f"{type(self).__name__}: parameter {name!r}: an [axis] option is per axis")
            from ..config import AxisConfig  # noqa: PLC0415 - the config imports nothing of ours
            import dataclasses  # noqa: PLC0415

            meta = {f.name: f.metadata for f in dataclasses.fields(AxisConfig)}.get(option)
            if meta is None:
                raise ControlProgramError(f"{type(self).__name__}: parameter {name!r}: [axis] has no option {option!r}")
            values = tuple(float(getattr(a, option)) for a in self._machine.axes)
            lo, hi, unit, doc = float(meta["lo"]), float(meta["hi"]), meta["unit"], doc or meta["doc"]
        elif per_axis:
            values = (tuple(float(x) for x in value) if isinstance(value, (list, tuple))
                      else tuple(float(value) for _ in self._axes))
            if len(values) != self.n_axes:
                raise ControlProgramError(f"{type(self).__name__}: parameter {name!r}: {len(values)} values for "
                                          f"{self.n_axes} axes")
        else:
            if isinstance(value, (list, tuple)):
                raise ControlProgramError(f"{type(self).__name__}: parameter {name!r}: a list needs per_axis=True")
            values = (float(value),)
        for v in values:
            if not (math.isfinite(v) and lo <= v <= hi):
                raise ControlProgramError(f"{type(self).__name__}: parameter {name!r}: {v!r} is outside its range "
                                          f"{lo:g} to {hi:g}")
        spec = ParameterSpec(name, values if per_axis else values[0], unit, lo, hi, doc, per_axis, option)
        self._parameters[name] = spec
        setattr(self, name, list(values) if per_axis else values[0])

    def register_log_variable(self, name: str, unit: str = "", doc: str = "", per_axis: bool = False,
                              size: int = 1) -> None:
        """Make member `name` loggable: a float, a list per axis, or a list of `size` floats the
        program assigns each period."""
        self._check_name(name)
        if per_axis:
            size = self.n_axes
        if not 1 <= size <= 16:
            raise ControlProgramError(f"{type(self).__name__}: log variable {name!r}: size {size} is not 1 to 16")
        self._logs[name] = LogSpec(name, unit, doc, per_axis, size)
        setattr(self, name, [0.0] * size if (per_axis or size > 1) else 0.0)

    def _check_name(self, name: str) -> None:
        if not name.isidentifier() or name.startswith("_"):
            raise ControlProgramError(f"{type(self).__name__}: {name!r} is not a member name")
        if name in self._parameters or name in self._logs:
            raise ControlProgramError(f"{type(self).__name__}: {name!r} is registered twice")
        if hasattr(type(self), name):
            raise ControlProgramError(f"{type(self).__name__}: {name!r} is a method or property of the class")

    @property
    def parameters(self) -> list[ParameterSpec]:
        return list(self._parameters.values())

    @property
    def log_variables(self) -> list[LogSpec]:
        return list(self._logs.values())

    # -- what a program implements ----------------------------------------------------------
    def start_control(self) -> None:
        """The loop closes: reset the law's state (integrators, filters, observers)."""

    def control(self, inputs: ControlInputs) -> Sequence[float]:
        """One period: the speed command of each axis, mm/s (the servo scales and clamps it)."""
        raise NotImplementedError

    def stop_control(self) -> None:
        """The loop opens (drives off, a trip, the end of a run)."""

    def position_referenced(self, axis: int) -> None:
        """Homing re-referenced this axis while it held still: its setpoint and measured position
        were shifted together (the error is 0 again); reset what integrates that axis' error."""

    # -- the servo's side -------------------------------------------------------------------
    def _started(self) -> None:
        self._ticks, self._elapsed_s = 0, 0.0
        self.start_control()

    def _counted(self, dt: float) -> None:
        self._ticks += 1
        self._elapsed_s += dt


def outputs_problem(u: object, names: Sequence[str]) -> str:
    """'' when `u` is one finite real number per axis (in `names`' order), else what is wrong with
    it, as the alarm says it."""
    try:
        count = len(u)  # type: ignore[arg-type]
    except TypeError:
        return f"returned {type(u).__name__}, not one speed command per axis"
    if count != len(names):
        return f"returned {count} speed commands for {len(names)} axes"
    for i, name in enumerate(names):
        x = u[i]  # type: ignore[index]
        try:
            finite = math.isfinite(x)  # any real number: float, int, numpy's
        except TypeError:
            finite = False
        if not finite or isinstance(x, (bool, complex)):
            return f"returned {x!r} as the speed command of axis {name.upper()}"
    return ""
