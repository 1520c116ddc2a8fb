"""Machine file: typed, validated configuration loaded from `machines/*.toml`.

The schema is declared once, as frozen dataclasses whose fields carry unit, allowed range
and documentation. The same declarations drive validation (every error names the file,
the table and the key, with the allowed range), defaults, and the generated reference
`machines/reference.toml`, so the documentation cannot drift from the code.
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .bus.states import ALARM_CODE_MAX
from .safety import below, minimum_levels

AXIS_NAMES = ("x", "y", "z")
_REQUIRED: Any = object()


DEFAULT_MACHINE = "machines/waterjet.toml"  # the machine file every command uses unless told otherwise

class ConfigError(ValueError):
    """A machine file is malformed; the message names file, table and key."""

    def __init__(self, path: str, table: str, key: str | None, message: str) -> None:
        self.path, self.table, self.key = path, table, key
        if not table and key is None:
            super().__init__(f"{path}: {message}")
            return
        where = (table if table.startswith("[[") else f"[{table}]") if table else "(top level)"
        if key is not None:
            where += f" {key}"
        super().__init__(f"{path}: {where}: {message}")


def opt(
    default: Any = _REQUIRED,
    unit: str = "",
    doc: str = "",
    lo: float | None = None,
    hi: float | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """A documented configuration option with an optional allowed range or set of choices."""
    meta = {"unit": unit, "doc": doc, "lo": lo, "hi": hi, "choices": choices}
    if default is _REQUIRED:
        return field(metadata=meta)
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class MachineInfo:
    """Identity of the machine; `name` is the `<machine>` part of every Zenoh key."""

    name: str = opt("waterjet", doc="machine id used in Zenoh keys (letters, digits, - and _)")
    description: str = opt("", doc="free text shown to operators")


@dataclass(frozen=True)
class TimingConfig:
    """Base tick of the hardware server and the divisors of its timer clients."""

    base_rate_hz: float = opt(1000.0, "Hz", "base tick rate of the hardware server (250 us to 4 ms)", 250.0, 4000.0)
    logic_divisor: int = opt(4, "ticks", "control logic runs every Nth base tick", 1, 100)
    watchdog_missed_ticks: int = opt(
        5, "ticks", "consecutive ticks the servo may miss before the board disables the drives", 1, 1000
    )
    realtime_priority: int = opt(80, "", "SCHED_FIFO priority of the hardware server (servo runs just below)", 1, 98)
    virtual_client_timeout_s: float = opt(
        0.2, "s", "virtual clock: how long a tick waits for a timer client before counting it as missed", 0.001, 10.0
    )
    commander_timeout_ms: float = opt(
        100.0, "ms", "the tick stops the machine when the commander's (control logic's) heartbeat is this late", 10.0, 10000.0
    )
    max_overruns_per_s: int = opt(
        20, "ticks", "servo ticks late within one second beyond which the cut stops (an error); "
        "fewer raise a warning", 1, 100000,
    )

    @property
    def period_s(self) -> float:
        return 1.0 / self.base_rate_hz


@dataclass(frozen=True)
class AxisConfig:
    """One linear servo axis: travel, kinematic limits, drive scaling and position-loop gains."""

    travel_min_mm: float = opt(_REQUIRED, "mm", "lower end of travel (soft limit)", -100000.0, 100000.0)
    travel_max_mm: float = opt(_REQUIRED, "mm", "upper end of travel (soft limit)", -100000.0, 100000.0)
    max_velocity_mm_s: float = opt(500.0, "mm/s", "maximum axis velocity", 0.1, 10000.0)
    max_accel_mm_s2: float = opt(5000.0, "mm/s^2", "maximum axis acceleration", 1.0, 1.0e6)
    max_jerk_mm_s3: float = opt(200000.0, "mm/s^3", "maximum axis jerk", 10.0, 1.0e9)
    encoder_resolution_mm: float = opt(0.001, "mm/count", "linear distance of one encoder count", 1.0e-6, 1.0)
    drive_full_scale_v: float = opt(10.0, "V", "speed-command voltage at full scale (symmetric +-)", 0.1, 100.0)
    drive_full_scale_mm_s: float = opt(
        1000.0, "mm/s", "axis velocity the drive runs at full-scale command", 1.0, 100000.0
    )
    following_error_limit_mm: float = opt(0.5, "mm", "following error that trips the servo", 0.001, 100.0)
    soft_limit_tolerance_mm: float = opt(
        0.005, "mm", "a setpoint or start position this close beyond a travel end counts as on it (rounding, a park's "
        "overshoot); farther beyond, a setpoint trips the soft limit", 0.0, 1.0,
    )
    kp_1_s: float = opt(100.0, "1/s", "position-loop proportional gain (mm/s of command per mm of error)", 0.0, 10000.0)
    ki_1_s2: float = opt(1000.0, "1/s^2", "position-loop integral gain", 0.0, 1.0e7)
    velocity_ff: float = opt(1.0, "", "velocity feed-forward gain (1 = full setpoint velocity)", 0.0, 2.0)
    accel_ff_s: float = opt(
        0.003, "s", "acceleration feed-forward: about the drive's lag (less overshoots at stops)", 0.0, 1.0
    )
    integral_limit_mm_s: float = opt(
        50.0, "mm/s", "clamp of the integral term's contribution to the speed command", 0.0, 10000.0
    )
    home_search_velocity_mm_s: float = opt(
        -20.0, "mm/s", "speed and direction of the home-switch search (negative: towards travel_min)", -1000.0, 1000.0
    )
    home_latch_velocity_mm_s: float = opt(
        2.0, "mm/s", "speed at which the axis backs off the switch to the index pulse", 0.01, 100.0
    )
    home_index_position_mm: float = opt(
        0.0, "mm", "machine position of the first index pulse after the home switch releases", -100000.0, 100000.0
    )
    home_final_position_mm: float = opt(5.0, "mm", "where the axis parks after homing", -100000.0, 100000.0)

    @property
    def counts_per_mm(self) -> float:
        return 1.0 / self.encoder_resolution_mm

    @property
    def volts_per_mm_s(self) -> float:
        return self.drive_full_scale_v / self.drive_full_scale_mm_s


@dataclass(frozen=True)
class BoardConfig:
    """Which I/O board the hardware server drives."""

    kind: str = opt("sim", doc="I/O board implementation", choices=("sim",))
    output_watchdog_ms: float = opt(
        20.0, "ms", "the board drops its outputs (drives off, jet closed) when the hardware server has not "
        "refreshed them for this long", 1.0, 1000.0,
    )


@dataclass(frozen=True)
class SimAxisConfig:
    """Plant model of one simulated axis (drive, mechanics, switches, encoder index)."""

    drive_time_constant_s: float = opt(0.003, "s", "first-order lag of the drive's P velocity loop", 1.0e-5, 1.0)
    viscous_friction_1_s: float = opt(2.0, "1/s", "viscous friction as deceleration per unit velocity", 0.0, 1000.0)
    coulomb_friction_mm_s2: float = opt(50.0, "mm/s^2", "Coulomb (dry) friction as deceleration", 0.0, 1.0e5)
    max_accel_mm_s2: float = opt(20000.0, "mm/s^2", "peak acceleration the drive's current limit allows", 1.0, 1.0e7)
    limit_switch_overtravel_mm: float = opt(
        5.0, "mm", "hard limit switches sit this far beyond the travel ends", 0.0, 1000.0
    )
    hard_stop_overtravel_mm: float = opt(
        15.0, "mm", "mechanical end stops sit this far beyond the travel ends", 0.0, 1000.0
    )
    home_switch_mm: float = opt(-2.0, "mm", "position where the home switch becomes active (active below)", -1.0e5, 1.0e5)
    index_pitch_mm: float = opt(10.0, "mm", "distance between encoder index pulses (screw pitch)", 0.01, 1000.0)
    encoder_zero_mm: float = opt(
        0.0, "mm", "table position where the incremental encoder counter reads 0 at power-up", -1.0e5, 1.0e5
    )
    start_position_mm: float = opt(
        math.nan, "mm", "position of the table at power-up (default: middle of travel)", -1.0e5, 1.0e5
    )


@dataclass(frozen=True)
class SimConfig:
    """The simulated board: per-axis plant models keyed by axis name, sharing defaults."""

    substeps: int = opt(4, "", "integration sub-steps per base tick", 1, 64)
    axes: dict[str, SimAxisConfig] = field(default_factory=dict, metadata={"table_of": SimAxisConfig})

    def axis(self, name: str) -> SimAxisConfig:
        return self.axes.get(name, SimAxisConfig())


@dataclass(frozen=True)
class McodeConfig:
    """The M codes that switch the jet and the auxiliary outputs (0: not used)."""

    jet_on: int = opt(3, "", "M code that opens the jet valve", 0, 199)
    jet_off: int = opt(5, "", "M code that closes the jet valve", 0, 199)
    abrasive_on: int = opt(7, "", "M code that starts the abrasive feed", 0, 199)
    abrasive_off: int = opt(9, "", "M code that stops the abrasive feed", 0, 199)
    aux1_on: int = opt(8, "", "M code that switches auxiliary output 1 on", 0, 199)
    aux1_off: int = opt(9, "", "M code that switches auxiliary output 1 off", 0, 199)


@dataclass(frozen=True)
class NozzleConfig:
    """One entry of the nozzle table: the kerf width G41/G42 D<number> compensates for."""

    number: int = opt(_REQUIRED, "", "nozzle (tool) number used by T and by G41/G42 D", 0, 99999)
    kerf_mm: float = opt(_REQUIRED, "mm", "kerf width: the compensation radius is half of it", 0.0, 100.0)
    description: str = opt("", doc="free text, e.g. orifice and focusing tube sizes")


@dataclass(frozen=True)
class GcodeConfig:
    """How programs are interpreted on this machine."""

    default_tolerance_mm: float = opt(
        0.05, "mm", "corner tolerance at program start and for G64 without P (0: no limit)", 0.0, 10.0
    )
    tool_table: str = opt(
        "", doc="LinuxCNC-format tool table (path relative to the machine file) whose diameters are kerf widths; replaces [[nozzle]]"
    )
    block_delete: bool = opt(False, doc="block-delete switch at start: skip lines that begin with '/'")
    max_program_bytes: int = opt(64 * 1024 * 1024, "bytes", "largest program accepted", 1024, 2**31 - 1)
    interpret_timeout_s: float = opt(
        120.0, "s", "a program whose interpretation takes longer is refused as a runaway (an endless loop)", 1.0, 3600.0
    )


@dataclass(frozen=True)
class PlannerConfig:
    """How the path planner shares the axes' limits and keeps the setpoint FIFO fed."""

    arc_normal_share: float = opt(
        0.5, "", "largest share of an axis' acceleration the path may spend turning on curves", 0.05, 0.9
    )
    fifo_low_ms: float = opt(
        20.0, "ms", "refill the setpoint FIFO when it holds less motion than this (more than twice the planner's period)",
        2.0, 2000.0,
    )
    fifo_high_ms: float = opt(40.0, "ms", "fill the setpoint FIFO up to this much motion (bounds the reaction to hold and override)", 4.0, 4000.0)
    corner_overlap_ms: float = opt(
        40.0, "ms", "at a corner the head would stop at (G64 P > 0, nothing switching there), the next move may start "
        "this much before the last one comes to rest, the two added within the axis limits and P; a hold or override "
        "change in an overlap acts when it ends (0: stop at every such corner)", 0.0, 200.0,
    )
    corner_connection_ms: float = opt(
        60.0, "ms", "where it passes such a corner sooner than the overlap, the axes leave the last move while it "
        "still brakes and join the next while it speeds up by one time-optimal motion of both, lasting at most this, "
        "within the axis limits, the feeds and P; a hold or override change in a connection acts when it ends "
        "(0: overlaps only)", 0.0, 200.0,
    )
    corner_programme_ms: float = opt(
        120.0, "ms", "where two long straight moves meet at such a corner, the samples through it may also be solved "
        "for at once (a linear programme: the path drifts out within P, then crosses the corner), lasting at most "
        "this, within the axis limits, the feeds and P, taken where it passes sooner than the connection; a hold or "
        "override change in one acts when it ends (0: none; needs corner_connection_ms, whose reach it shares)",
        0.0, 200.0,
    )
    corner_move_share: float = opt(
        0.5, "", "share of P by which such a corner is moved outward first, where a straight move alone meets it at "
        "up to 90 degrees, so that the overlap uses the tolerance on both sides of the corner and passes faster "
        "(0: corners only cut on their inside)", 0.0, 0.9,
    )
    lead_move_share: float = opt(
        0.7, "", "the same share where the straight move alone is a lead-in or lead-out meeting a longer section (its "
        "contour): the corner moves back along the contour's line, so it takes more of P for the same use of the band "
        "(corner_move_share 0 keeps these too)", 0.0, 0.9,
    )
    divisor: int = opt(5, "ticks", "the planner runs every Nth base tick", 1, 100)
    jog_velocity_mm_s: float = opt(50.0, "mm/s", "default jog speed", 0.01, 10000.0)
    jog_deadman_ms: float = opt(
        250.0, "ms", "a continuous jog stops unless its station refreshes it within this time (a held key: "
        "the screen refreshes every 100 ms)", 150.0, 10000.0,
    )
    load_timeout_s: float = opt(
        900.0, "s", "how long loading a program may take: interpreting and checking it, its first steps planned (seconds for a million lines)", 10.0, 7200.0
    )


@dataclass(frozen=True)
class JetConfig:
    """The cutting jet: how long its valve takes, and what happens to it when motion holds."""

    on_delay_s: float = opt(0.05, "s", "after the valve opens, before motion: the jet establishes itself", 0.0, 60.0)
    pierce_dwell_s: float = opt(0.1, "s", "after the on delay, standing still to pierce the material", 0.0, 600.0)
    off_delay_s: float = opt(0.02, "s", "after the valve closes, before motion: the jet dies away", 0.0, 60.0)
    close_on_hold: bool = opt(True, doc="close the jet while motion is held or paused (it re-pierces on resume)")


@dataclass(frozen=True)
class CuttingConfig:
    """The cutting model (`cnc.cutmodel`): where the material library is."""

    materials_dir: str = opt(
        "materials", doc="the material library: one TOML file per material (relative to the machine file, or absolute)"
    )


@dataclass(frozen=True)
class ControlConfig:
    """The axis control law: the control program the servo runs (`cnc.control`), its CPU budget, its parameters."""

    program: str = opt(
        "pip", doc="the control program: a shipped one (pip, friction_ff, cross_coupled, fault_injection), 'package.module:Class', "
        "or 'file.py:Class' beside the machine file",
    )
    budget_share: float = opt(
        0.5, "", "CPU time a control program may use per servo period, as a share of the period", 0.01, 0.95
    )
    budget_overruns: int = opt(
        3, "periods", "consecutive periods over the budget that stop a control program (1: the first)", 1, 1000
    )
    check_periods: int = opt(2000, "periods", "how long `waterjet control check` runs a program on the simulated plant",
                             10, 1000000)
    parameters: dict = field(default_factory=dict, metadata={
        "free_numbers": True, "unit": "", "lo": None, "hi": None, "choices": None,
        "doc": "the control program's own parameters: name = value; per axis in [control.parameters.<axis>] "
               "(`waterjet control list` names them)"})


PLC_VAR_KINDS = ("discrete_input", "input_register", "coil", "holding_register")
PLC_VAR_TYPES = ("bool", "uint16", "int16")
MAX_PLC_VARS = 64  # per direction: the shared-memory images hold this many values


@dataclass(frozen=True)
class PlcVarConfig:
    """One variable of the external PLC's image: where it lives and how to scale it."""

    id: str = opt(_REQUIRED, doc="identifier used by the control logic, procedures and the HMI (letters, digits, _)")
    kind: str = opt(
        _REQUIRED, doc="Modbus table: discrete_input and input_register are read (PLC -> CNC), coil and holding_register written",
        choices=PLC_VAR_KINDS,
    )
    address: int = opt(_REQUIRED, "", "0-based Modbus address in its table", 0, 65535)
    type: str = opt("bool", doc="value type (registers: uint16 or int16; bits: bool)", choices=PLC_VAR_TYPES)
    scale: float = opt(1.0, "", "engineering value = raw * scale (registers only)", -1.0e6, 1.0e6)
    unit: str = opt("", doc="engineering unit, for display")
    description: str = opt("", doc="what the variable means, for the operator and the integrator")


@dataclass(frozen=True)
class PlcConfig:
    """The Modbus RTU link to the external PLC (transport system and high-pressure pump)."""

    port: str = opt(
        "", doc="serial device of the external PLC; empty on the sim board: the PLC simulator on a pty pair"
    )
    baud: int = opt(19200, "baud", "serial speed", 1200, 921600)
    parity: str = opt("E", doc="parity (Modbus RTU default: even)", choices=("N", "E", "O"))
    stop_bits: int = opt(1, "", "stop bits", 1, 2)
    unit_id: int = opt(1, "", "Modbus unit (slave) address of the PLC", 1, 247)
    cycle_ms: float = opt(50.0, "ms", "target period of one exchange (read the input image, write the output image)", 5.0, 10000.0)
    timeout_ms: float = opt(100.0, "ms", "how long one request may wait for its response", 5.0, 10000.0)
    lost_after_cycles: int = opt(3, "cycles", "consecutive failed exchanges after which the link counts as lost", 1, 100)
    reconnect_s: float = opt(1.0, "s", "pause between reconnection attempts while the link is lost", 0.01, 600.0)
    local_echo: bool = opt(False, doc="the adapter hears its own requests (half-duplex RS-485 with the receiver on "
                           "while sending): each request's echo is dropped before its answer is read")
    var: list[PlcVarConfig] = field(default_factory=list, metadata={"array_of": PlcVarConfig})

    def inputs(self) -> list[PlcVarConfig]:
        """Variables read from the PLC, in image order."""
        return [v for v in self.var if v.kind in ("discrete_input", "input_register")]

    def outputs(self) -> list[PlcVarConfig]:
        """Variables written to the PLC, in image order."""
        return [v for v in self.var if v.kind in ("coil", "holding_register")]


ALARM_LEVELS = ("fatal", "error", "warning", "info")
# ids the control logic raises by name: a catalogue must declare them (the others it raises when declared)
CONTROLLER_ALARM_IDS = (
    "estop", "mains_off", "doors_open", "barrier_interrupted", "following_error", "soft_limit", "hard_limit", "watchdog",
    "fifo_underrun", "process_lost", "plc_link_lost", "control_program",
    "plc_error", "pump_pressure_fault", "transport_timeout", "procedure_stop", "procedure_timeout", "program_error",
    "program_message", "wrong_mode", "cycle_done", "internal_error", "operator_lost", "press_button", "press_start",
    "feed_hold", "tick_overruns", "tick_overrun_rate", "simulator", "stop_all",
)  # and `<axis>_drive` for every axis (cnc.safety)


@dataclass(frozen=True)
class AlarmConfig:
    """One entry of the alarm and message catalogue."""

    code: int = opt(_REQUIRED, "", "stable numeric code, shown to the operator and kept in the history", 1, ALARM_CODE_MAX)
    id: str = opt(_REQUIRED, doc="name the controller raises it by (letters, digits, _)")
    text: str = opt(_REQUIRED, doc="what the operator reads")
    level: str = opt("error", doc="fatal and error stop the cut; warning and info do not", choices=ALARM_LEVELS)
    cause: str = opt("", doc="likely cause")
    remedy: str = opt("", doc="what to do about it")


@dataclass(frozen=True)
class ProcedureStepConfig:
    """One step of a guided procedure: a condition to become true, or an operator action."""

    text: str = opt(_REQUIRED, doc="the step as listed to the operator")
    condition: str = opt(
        "", doc="expression over named signals that completes the step, e.g. 'plc.transport_ready and din.doors_closed'"
    )
    action: str = opt("", doc="operator action that completes the step instead of a condition", choices=("", "confirm"))
    instruction: str = opt("", doc="what the operator must do while the step is awaited")
    timeout_s: float = opt(0.0, "s", "raise timeout_alarm when the step has waited this long (0: wait forever)", 0.0, 86400.0)
    timeout_alarm: str = opt("procedure_timeout", doc="alarm id raised on timeout")


@dataclass(frozen=True)
class ProcedureConfig:
    """A guided procedure: a title and ordered steps the operator is walked through."""

    id: str = opt(_REQUIRED, doc="name used by commands and by the automatic cycle (letters, digits, _)")
    title: str = opt(_REQUIRED, doc="shown at the top of the procedure window")
    step: list[ProcedureStepConfig] = field(default_factory=list, metadata={"array_of": ProcedureStepConfig})


@dataclass(frozen=True)
class PumpConfig:
    """The high-pressure pump, run by the external PLC."""

    cut_pressure_bar: float = opt(3800.0, "bar", "cutting pressure", 0.0, 10000.0)
    pierce_pressure_bar: float = opt(1200.0, "bar", "low pressure to pierce at", 0.0, 10000.0)
    pierce_at_low_pressure: bool = opt(True, doc="pierce at pierce_pressure_bar, then cut at cut_pressure_bar")
    tolerance_bar: float = opt(150.0, "bar", "pressure counts as reached within this band", 1.0, 5000.0)
    ramp_timeout_s: float = opt(20.0, "s", "raise pump_pressure_fault when the pressure is not reached in this time", 0.1, 600.0)
    drop_bar: float = opt(600.0, "bar", "a drop this far below the set pressure while cutting is a pump pressure fault", 1.0, 10000.0)


@dataclass(frozen=True)
class CycleConfig:
    """The automatic cycle: transport phase, cutting phase, unload."""

    transport_procedure: str = opt("transport", doc="procedure walked before the first transport phase")
    transport_timeout_s: float = opt(60.0, "s", "longest the PLC may take to feed material and close the gripper", 0.1, 3600.0)
    unload_timeout_s: float = opt(60.0, "s", "longest the PLC may take to open the gripper and unload", 0.1, 3600.0)
    recovery_overlap_mm: float = opt(2.0, "mm", "continuing an interrupted cut starts this far back along it (not "
                                     "before its pierce), so that the joined cut has no gap", 0.0, 100.0)
    recovery_save_mm: float = opt(5.0, "mm", "while cutting, where the jet is is written to the job record at "
                                  "least this often (and at every stop), for continuing after a restart", 0.5, 1000.0)


@dataclass(frozen=True)
class LogicConfig:
    """The control-logic process (soft-PLC)."""

    history: str = opt(
        "", doc="alarm and message history (SQLite); relative to the machine file; empty: a file in the run directory"
    )
    history_keep_days: float = opt(365.0, "days", "history entries older than this are deleted at start", 1.0, 36500.0)


@dataclass(frozen=True)
class LoggerConfig:
    """The data logger (QMotor's log variables): recording runs, the live stream, the runs kept."""

    wake_divisor: int = opt(50, "ticks", "the logger drains the servo's trace every Nth base tick", 1, 1000)
    live_rate_hz: float = opt(10.0, "Hz", "rate of the live stream (watch window, live plots)", 0.5, 100.0)
    live_points: int = opt(500, "", "most samples per variable in one live message (older ones are thinned)", 10, 100000)
    max_samples: int = opt(2_000_000, "", "most samples one variable keeps in a run", 1000, 100_000_000)
    runs_kept: int = opt(20, "", "finished runs kept for plots and export (the oldest go first)", 1, 1000)


@dataclass(frozen=True)
class GatewayConfig:
    """The HMI's door on Zenoh."""

    status_rate_hz: float = opt(20.0, "Hz", "rate of the cyclic status publication", 0.1, 200.0)
    position_rate_hz: float = opt(50.0, "Hz", "rate of the position stream (live path)", 1.0, 500.0)
    on_operator_lost: str = opt(
        "hold", doc="when the station holding the command lock disappears during a cut: hold the feed, or continue",
        choices=("hold", "continue"),
    )
    program_dir: str = opt(
        "", doc="where uploaded programs are kept (relative to the machine file); empty: beside the alarm history"
    )
    library_checks: bool = opt(True, doc="check each stored program in the background (a child process at low priority) "
                               "for the program library's figures; off: they stay pending")
    station_ping_ms: float = opt(1000.0, "ms", "how often the gateway asks the lock holder's station for an answer", 100.0, 10000.0)
    station_lost_ms: float = opt(
        6000.0, "ms", "no answer from the lock holder's station for this long: it is lost (as when its token goes)",
        500.0, 60000.0,
    )


@dataclass(frozen=True)
class AccessConfig:
    """Who may reach the controller from the network: accounts, or this host only (`cnc.bus.access`).

    Each station acts in its account's role; without accounts the controller serves its own host
    only, unless `open_network` opens it to anyone."""

    users_file: str = opt(
        "", doc="accounts file (name:role:password, mode 0600; `waterjet users`); empty: <machine>.users beside the machine file"
    )
    open_network: bool = opt(
        False, doc="UNSAFE: without accounts, let any host on the network command the machine in `open_role`"
    )
    open_role: str = opt("operator", doc="role of every station when open_network: observer, operator or engineer")
    local_role: str = opt(
        "engineer", doc="role of a station on the controller's own host (its own account, no login needed)"
    )
    tls_dir: str = opt(
        "", doc="the machine's TLS directory (`waterjet certs`; relative to the machine file), for tls/ endpoints"
    )
    observers_may_stop_all: bool = opt(
        False, doc="let observer stations (read-only screens) send stop_all too: every operator station may"
    )


@dataclass(frozen=True)
class ZenohConfig:
    """Where the controller's Zenoh router listens and how keys are prefixed."""

    listen: list[str] = opt(["tcp/0.0.0.0:7447"], doc="endpoints the controller's router listens on")
    connect: list[str] = opt([], doc="routers the controller's router connects to (a shop router: `waterjet router`)")
    key_prefix: str = opt("wj", doc="first element of every key: <prefix>/<machine>/...")
    access: "AccessConfig" = field(default_factory=lambda: AccessConfig())


@dataclass(frozen=True)
class SupervisorConfig:
    """How the supervisor watches its processes."""

    heartbeat_timeout_s: float = opt(
        2.0, "s", "a process whose heartbeat has not advanced for this long is considered hung", 0.05, 600.0
    )
    start_timeout_s: float = opt(30.0, "s", "how long a process may take to report ready", 1.0, 600.0)


@dataclass(frozen=True)
class MachineConfig:
    """Everything one machine file says, validated."""

    machine: MachineInfo = field(default_factory=MachineInfo)
    timing: TimingConfig = field(default_factory=TimingConfig)
    axis: dict[str, AxisConfig] = field(default_factory=dict, metadata={"table_of": AxisConfig, "required": True})
    board: BoardConfig = field(default_factory=BoardConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    mcodes: McodeConfig = field(default_factory=McodeConfig)
    gcode: GcodeConfig = field(default_factory=GcodeConfig)
    nozzle: list[NozzleConfig] = field(default_factory=list, metadata={"array_of": NozzleConfig})
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    jet: JetConfig = field(default_factory=JetConfig)
    cutting: CuttingConfig = field(default_factory=CuttingConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    plc: PlcConfig = field(default_factory=PlcConfig)
    pump: PumpConfig = field(default_factory=PumpConfig)
    cycle: CycleConfig = field(default_factory=CycleConfig)
    logic: LogicConfig = field(default_factory=LogicConfig)
    alarm: list[AlarmConfig] = field(default_factory=list, metadata={"array_of": AlarmConfig})
    procedure: list[ProcedureConfig] = field(default_factory=list, metadata={"array_of": ProcedureConfig})
    gateway: GatewayConfig = field(default_factory=GatewayConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)
    supervisor: SupervisorConfig = field(default_factory=SupervisorConfig)
    source: str = field(default="<defaults>", metadata={"internal": True})

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(self.axis)

    @property
    def axes(self) -> tuple[AxisConfig, ...]:
        return tuple(self.axis.values())


# ---------------------------------------------------------------------------------------
# loading


def machine_for_command(path: str, command: str) -> MachineConfig | None:
    """The machine file a shell command (`waterjet <command>`) names, loaded; the default one is
    also found beside this package when the command runs elsewhere. None (the error printed,
    naming the file and the key) when it does not load."""
    if not Path(path).exists() and path == DEFAULT_MACHINE:
        here = Path(__file__).resolve().parent.parent / DEFAULT_MACHINE
        if here.exists():
            path = str(here)
    try:
        return load_machine(path)
    except ConfigError as exc:
        print(f"waterjet {command}: {exc}", file=sys.stderr)
        return None


def load_machine(path: str | Path, overrides: dict[str, Any] | None = None) -> MachineConfig:
    """Read and validate a machine file; `overrides` ({"zenoh.listen": [...]}) apply on top."""
    path = Path(path)
    shown = str(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(shown, "", None, "file not found") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(shown, "", None, f"not UTF-8 text (byte {exc.start})") from None
    return loads_machine(text, shown, overrides)


def loads_machine(text: str, source: str = "<string>", overrides: dict[str, Any] | None = None) -> MachineConfig:
    """Validate machine-file text; `source` is the name used in error messages."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        where = re.search(r"\(at line (\d+), column (\d+)\)", str(exc))
        text_ = re.sub(r" \(at line \d+, column \d+\)", "", str(exc))
        loc = f":{where.group(1)}:{where.group(2)}" if where else ""
        raise ConfigError(f"{source}{loc}", "", None, f"TOML syntax error: {text_}") from None
    for dotted, value in (overrides or {}).items():
        *tables, key = dotted.split(".")
        node = raw
        for t in tables:
            node = node.setdefault(t, {})
        node[key] = value
    cfg = _build(MachineConfig, raw, source, "")
    cfg = dataclasses.replace(cfg, source=source)
    _cross_check(cfg)
    return cfg


def _build(cls: type, table: dict[str, Any], source: str, where: str) -> Any:
    if not isinstance(table, dict):
        raise ConfigError(source, where, None, f"expected a table, got {_tname(table)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    unknown = [k for k in table if k not in fields]
    if unknown:
        raise ConfigError(
            source, where, unknown[0], f"unknown key (known keys: {', '.join(sorted(fields))})"
        )
    values: dict[str, Any] = {}
    for name, f in fields.items():
        sub = f"{where}.{name}" if where else name
        if f.metadata.get("free_numbers"):
            values[name] = _free_numbers(table.get(name, {}), source, sub)
        elif "table_of" in f.metadata:
            values[name] = _build_table_of(f, table.get(name), source, sub, name, where)
        elif "array_of" in f.metadata:
            values[name] = _build_array_of(f.metadata["array_of"], table.get(name, []), source, sub)
        elif dataclasses.is_dataclass(hints[name]):
            values[name] = _build(hints[name], table.get(name, {}), source, sub)
        elif name in table:
            values[name] = _check_value(table[name], hints[name], f.metadata, source, where, name)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(source, where, name, f"missing required key{_range_text(f.metadata)}")
    return cls(**values)


def _free_numbers(raw: Any, source: str, where: str) -> dict:
    """A table whose keys its user declares (a control program's parameters): numbers, and
    per-axis tables of numbers (`[control.parameters.x]`). Which names are known is the
    program's to say (`cnc.control.loader`)."""
    if not isinstance(raw, dict):
        raise ConfigError(source, where, None, f"expected a table, got {_tname(raw)}")
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if isinstance(value, dict):
            if key not in AXIS_NAMES:
                raise ConfigError(source, where, key, f"a table here is an axis' parameters (allowed: {', '.join(AXIS_NAMES)})")
            out[key] = _free_numbers(value, source, f"{where}.{key}")
            if any(isinstance(v, dict) for v in out[key].values()):
                raise ConfigError(source, f"{where}.{key}", None, "an axis' parameters are numbers, not tables")
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
            raise ConfigError(source, where, key, f"expected a number, got {value!r}")
        out[key] = float(value)
    return out


def _build_table_of(f: dataclasses.Field, raw: Any, source: str, sub: str, name: str, where: str) -> dict:
    """Build `[name.<axis>]` tables keyed by axis name; scalar keys beside them belong to the parent."""
    if raw is None:
        if f.metadata.get("required"):
            raise ConfigError(source, where, name, "missing required table (declare at least one axis, e.g. [axis.x])")
        return {}
    if not isinstance(raw, dict):
        raise ConfigError(source, where, name, f"expected a table of axes, got {_tname(raw)}")
    out = {}
    for axis, body in raw.items():
        if axis not in AXIS_NAMES:
            raise ConfigError(source, sub, axis, f"unknown axis (allowed: {', '.join(AXIS_NAMES)})")
        out[axis] = _build(f.metadata["table_of"], body, source, f"{sub}.{axis}")
    return out


def _build_array_of(cls: type, raw: Any, source: str, where: str) -> list:
    """`[[name]]` arrays of tables; errors name the entry as `[[name]] #k`."""
    if not isinstance(raw, list):
        raise ConfigError(source, where, None, f"expected an array of tables [[{where}]], got {_tname(raw)}")
    return [_build(cls, body, source, f"[[{where}]] #{k + 1}") for k, body in enumerate(raw)]


def _check_value(value: Any, hint: Any, meta: dict, source: str, table: str, key: str) -> Any:
    err = lambda msg: ConfigError(source, table, key, msg)  # noqa: E731
    if hint is bool:
        if not isinstance(value, bool):
            raise err(f"expected true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise err(f"expected an integer, got {value!r}{_range_text(meta)}")
    elif hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise err(f"expected a number, got {value!r}{_range_text(meta)}")
        value = float(value)
        if math.isnan(value):
            raise err(f"expected a number, got nan{_range_text(meta)}")
    elif hint is str:
        if not isinstance(value, str):
            raise err(f"expected a string, got {value!r}")
    elif typing.get_origin(hint) is list:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise err(f"expected a list of strings, got {value!r}")
        return list(value)
    lo, hi, choices = meta.get("lo"), meta.get("hi"), meta.get("choices")
    if choices is not None and value not in choices:
        raise err(f"{value!r} is not one of: {', '.join(choices)}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        unit = f" {meta['unit']}" if meta.get("unit") else ""
        raise err(f"{value!r} is out of range: allowed {lo:g} to {hi:g}{unit}")
    return value


def _check_control_program(cfg: MachineConfig) -> None:
    """The control program the file names is found, builds, registers what it may and takes the
    values of `[control.parameters]` (ConfigError names the key): a machine whose law cannot be
    built never starts."""
    from .control.loader import build  # noqa: PLC0415 - the loader imports this module
    from .control.program import ControlProgramError  # noqa: PLC0415

    try:
        build(cfg)
    except ControlProgramError as exc:
        text = str(exc)
        prefix = f"{cfg.source}: "
        raise ConfigError(cfg.source, "", None, text[len(prefix):] if text.startswith(prefix) else text) from None


def cross_check(cfg: MachineConfig) -> None:
    """The checks between keys and tables of a machine file (ConfigError names the key): for a
    config changed after loading, such as a control parameter changed online."""
    _cross_check(cfg)


def _cross_check(cfg: MachineConfig) -> None:
    src = cfg.source
    _check_control_program(cfg)
    name = cfg.machine.name
    if not name or not all(c.isalnum() or c in "-_" for c in name):
        raise ConfigError(src, "machine", "name", f"{name!r} must be letters, digits, '-' or '_'")
    for axis, a in cfg.axis.items():
        if a.travel_min_mm >= a.travel_max_mm:
            raise ConfigError(
                src, f"axis.{axis}", "travel_max_mm",
                f"{a.travel_max_mm:g} must be greater than travel_min_mm {a.travel_min_mm:g}",
            )
    for axis, a in cfg.axis.items():
        if a.home_search_velocity_mm_s == 0.0:
            raise ConfigError(src, f"axis.{axis}", "home_search_velocity_mm_s", "must not be 0: its sign is the search direction")
        if not a.travel_min_mm <= a.home_final_position_mm <= a.travel_max_mm:
            raise ConfigError(
                src, f"axis.{axis}", "home_final_position_mm",
                f"{a.home_final_position_mm:g} is outside the travel {a.travel_min_mm:g} to {a.travel_max_mm:g} mm",
            )
    for axis in cfg.sim.axes:
        if axis not in cfg.axis:
            raise ConfigError(src, "sim.axes", axis, f"no such axis declared (declared: {', '.join(cfg.axis)})")
    for axis, s in cfg.sim.axes.items():
        if s.hard_stop_overtravel_mm <= s.limit_switch_overtravel_mm:
            raise ConfigError(
                src, f"sim.axes.{axis}", "hard_stop_overtravel_mm",
                f"{s.hard_stop_overtravel_mm:g} must exceed limit_switch_overtravel_mm "
                f"{s.limit_switch_overtravel_mm:g} so that the limit switch trips before the end stop",
            )
    planner_ms = 1000.0 * cfg.planner.divisor * cfg.timing.period_s
    if cfg.planner.fifo_low_ms <= 2.0 * planner_ms:
        raise ConfigError(
            src, "planner", "fifo_low_ms",
            f"{cfg.planner.fifo_low_ms:g} ms must be more than twice the planner's period ({cfg.planner.divisor} ticks = "
            f"{planner_ms:g} ms): the FIFO runs one period between two of its refills, and one more when the planner "
            "wakes late; less, and it runs dry (the servo trips: FIFO underrun)",
        )
    if cfg.planner.fifo_high_ms <= cfg.planner.fifo_low_ms + planner_ms:
        raise ConfigError(
            src, "planner", "fifo_high_ms",
            f"{cfg.planner.fifo_high_ms:g} ms must exceed fifo_low_ms {cfg.planner.fifo_low_ms:g} ms by more than "
            f"the planner's period ({cfg.planner.divisor} ticks = {planner_ms:g} ms)",
        )
    seen: dict[int, int] = {}
    for k, nz in enumerate(cfg.nozzle, start=1):
        if nz.number in seen:
            raise ConfigError(src, f"[[nozzle]] #{k}", "number", f"nozzle {nz.number} is already entry #{seen[nz.number]}")
        seen[nz.number] = k
    _check_access(cfg)
    _check_plc(cfg)
    _check_alarms(cfg)
    _check_procedures(cfg)
    if not cfg.zenoh.listen:
        raise ConfigError(src, "zenoh", "listen", "needs at least one endpoint, e.g. tcp/127.0.0.1:7447")
    for prefix_part in cfg.zenoh.key_prefix.split("/"):
        if not prefix_part or any(c in prefix_part for c in "*$?#"):
            raise ConfigError(src, "zenoh", "key_prefix", f"{cfg.zenoh.key_prefix!r} is not a valid key prefix")


_IDENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


def beside(cfg: MachineConfig, value: str) -> Path:
    """A path from the machine file, relative paths taken from the machine file's directory."""
    path = Path(value)
    if not path.is_absolute() and cfg.source not in ("<defaults>", "<string>"):
        path = Path(cfg.source).resolve().parent / path
    return path


def users_path(cfg: MachineConfig) -> Path:
    """`[zenoh.access] users_file`, resolved against the machine file's directory; by default
    `<machine file stem>.users` beside the machine file."""
    if cfg.zenoh.access.users_file:
        return beside(cfg, cfg.zenoh.access.users_file)
    if cfg.source in ("<defaults>", "<string>"):
        return Path(f"{cfg.machine.name}.users").resolve()
    return Path(cfg.source).resolve().with_suffix(".users")


def read_credentials(path: Path) -> dict[str, str]:
    """user -> password from a station's `user:password` login file (blank lines and # comments ignored)."""
    users: dict[str, str] = {}
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        user, sep, password = line.partition(":")
        if not sep or not user or not password:
            raise ValueError(f"{path}:{n}: expected user:password")
        users[user] = password
    return users


def _check_access(cfg: MachineConfig) -> None:
    from .bus.users import ROLES, UsersError, read_users  # the bus builds on this module

    src, a = cfg.source, cfg.zenoh.access
    for key in ("open_role", "local_role"):
        if getattr(a, key) not in ROLES:
            raise ConfigError(src, "zenoh.access", key, f"{getattr(a, key)!r} is not one of {', '.join(ROLES)}")
    tls = [ep for ep in [*cfg.zenoh.listen, *cfg.zenoh.connect] if ep.startswith("tls/")]
    if tls and not a.tls_dir:
        raise ConfigError(src, "zenoh.access", "tls_dir", f"{tls[0]} needs the machine's TLS directory "
                          "(make it with `waterjet certs ca` and `waterjet certs controller --host ...`)")
    try:
        read_users(users_path(cfg))
    except UsersError as exc:
        raise ConfigError(src, "zenoh.access", "users_file", str(exc)) from None
    except OSError as exc:
        raise ConfigError(src, "zenoh.access", "users_file", f"{users_path(cfg)}: {exc.strerror}") from None


def _check_plc(cfg: MachineConfig) -> None:
    src = cfg.source
    ids: dict[str, int] = {}
    used: dict[tuple[str, int], int] = {}
    for k, v in enumerate(cfg.plc.var, start=1):
        where = f"[[plc.var]] #{k}"
        if not _IDENT.match(v.id):
            raise ConfigError(src, where, "id", f"{v.id!r} must be letters, digits and _, not starting with a digit")
        if v.id in ids:
            raise ConfigError(src, where, "id", f"{v.id!r} is already entry #{ids[v.id]}")
        ids[v.id] = k
        bit = v.kind in ("discrete_input", "coil")
        if bit != (v.type == "bool"):
            raise ConfigError(src, where, "type", f"{v.type!r} does not fit a {v.kind} (bits are bool, registers uint16 or int16)")
        if (v.kind, v.address) in used:
            raise ConfigError(src, where, "address", f"{v.kind} {v.address} is already entry #{used[(v.kind, v.address)]}")
        used[(v.kind, v.address)] = k
    for direction, group in (("read", cfg.plc.inputs()), ("written", cfg.plc.outputs())):
        if len(group) > MAX_PLC_VARS:
            raise ConfigError(src, "plc", "var", f"{len(group)} variables {direction}; at most {MAX_PLC_VARS} each way")
    if cfg.plc.timeout_ms >= cfg.plc.cycle_ms * cfg.plc.lost_after_cycles:
        raise ConfigError(
            src, "plc", "timeout_ms",
            f"{cfg.plc.timeout_ms:g} ms must be shorter than lost_after_cycles x cycle_ms "
            f"({cfg.plc.lost_after_cycles} x {cfg.plc.cycle_ms:g} ms) so that a loss is seen in time",
        )


def _check_alarms(cfg: MachineConfig) -> None:
    src = cfg.source
    codes: dict[int, int] = {}
    ids: dict[str, int] = {}
    for k, a in enumerate(cfg.alarm, start=1):
        where = f"[[alarm]] #{k}"
        if a.code in codes:
            raise ConfigError(src, where, "code", f"{a.code} is already entry #{codes[a.code]}")
        if not _IDENT.match(a.id):
            raise ConfigError(src, where, "id", f"{a.id!r} must be letters, digits and _, not starting with a digit")
        if a.id in ids:
            raise ConfigError(src, where, "id", f"{a.id!r} is already entry #{ids[a.id]}")
        codes[a.code], ids[a.id] = k, k
    if not cfg.alarm:
        return
    minimum = minimum_levels(cfg.axis_names)
    missing = [i for i in (*CONTROLLER_ALARM_IDS, *minimum) if i not in ids]
    if missing:
        raise ConfigError(src, "[[alarm]]", "id",
                          f"the catalogue lacks alarms the controller raises: {', '.join(dict.fromkeys(missing))}")
    for k, a in enumerate(cfg.alarm, start=1):
        if a.id in minimum and below(a.level, minimum[a.id]):
            raise ConfigError(
                src, f"[[alarm]] #{k} ({a.id})", "level",
                f"{a.level!r} is below {minimum[a.id]!r}: a safety alarm stops the cut and blocks a start; a machine "
                "file may reword it or make it graver, never demote it",
            )


def _check_procedures(cfg: MachineConfig) -> None:
    src = cfg.source
    alarm_ids = {a.id for a in cfg.alarm}
    ids: dict[str, int] = {}
    for k, p in enumerate(cfg.procedure, start=1):
        where = f"[[procedure]] #{k}"
        if not _IDENT.match(p.id):
            raise ConfigError(src, where, "id", f"{p.id!r} must be letters, digits and _, not starting with a digit")
        if p.id in ids:
            raise ConfigError(src, where, "id", f"{p.id!r} is already entry #{ids[p.id]}")
        ids[p.id] = k
        if not p.step:
            raise ConfigError(src, where, "step", "a procedure needs at least one [[procedure.step]]")
        for j, st in enumerate(p.step, start=1):
            swhere = f"[[procedure]] #{k} ({p.id}) step #{j}"
            if bool(st.condition) == bool(st.action):
                raise ConfigError(src, swhere, "condition", "give exactly one of condition or action")
            if st.timeout_s > 0 and alarm_ids and st.timeout_alarm not in alarm_ids:
                raise ConfigError(src, swhere, "timeout_alarm", f"{st.timeout_alarm!r} is not an [[alarm]] id")
    if cfg.procedure and cfg.cycle.transport_procedure and cfg.cycle.transport_procedure not in ids:
        raise ConfigError(src, "cycle", "transport_procedure", f"{cfg.cycle.transport_procedure!r} is not a [[procedure]] id")


def _range_text(meta: dict) -> str:
    lo, hi, choices = meta.get("lo"), meta.get("hi"), meta.get("choices")
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    if choices:
        return f" (one of: {', '.join(choices)})"
    if lo is not None and hi is not None:
        return f" (allowed {lo:g} to {hi:g}{unit})"
    return ""


def _tname(value: Any) -> str:
    return type(value).__name__


# ---------------------------------------------------------------------------------------
# reference documentation


def reference_toml() -> str:
    """Render every option with unit, range and default, as `machines/reference.toml`."""
    lines = [
        "# Reference of every machine-file option: unit, allowed range and default.",
        "# Generated from cnc/config.py (python -m cnc.config > machines/reference.toml);",
        "# a test keeps it in sync. Keys shown commented out are optional.",
        "",
    ]
    _render(MachineConfig, "", lines)
    return "\n".join(lines).rstrip() + "\n"


def _render(cls: type, table: str, lines: list[str]) -> None:
    hints = typing.get_type_hints(cls)
    scalars, subtables = [], []
    for f in dataclasses.fields(cls):
        if f.metadata.get("internal"):
            continue
        if "table_of" in f.metadata or "array_of" in f.metadata or dataclasses.is_dataclass(hints[f.name]):
            subtables.append(f)
        else:
            scalars.append(f)
    if scalars:
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        lines.append(f"[{table}]" if table else "")
        lines.append(f"# {doc}")
        for f in scalars:
            lines.extend(_render_option(f))
        lines.append("")
    for f in subtables:
        sub = f"{table}.{f.name}" if table else f.name
        if "array_of" in f.metadata:
            _render_array(f.metadata["array_of"], sub, lines)
        elif "table_of" in f.metadata:
            _render(f.metadata["table_of"], f"{sub}.x", lines)
        else:
            _render(hints[f.name], sub, lines)


def _render_array(cls: type, sub: str, lines: list[str]) -> None:
    """`[[sub]]` with its options, then any arrays nested in it (`[[sub.name]]`)."""
    lines.append(f"[[{sub}]]")
    lines.append(f"# {(cls.__doc__ or '').strip().splitlines()[0]} (repeat the table for each entry)")
    nested = []
    for g in dataclasses.fields(cls):
        if "array_of" in g.metadata:
            nested.append(g)
        else:
            lines.extend(_render_option(g))
    lines.append("")
    for g in nested:
        _render_array(g.metadata["array_of"], f"{sub}.{g.name}", lines)


def _render_option(f: dataclasses.Field) -> list[str]:
    meta = f.metadata
    required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
    unit = f" [{meta['unit']}]" if meta.get("unit") else ""
    comment = f"# {meta.get('doc', '')}{unit}{_range_text(meta)}"
    if required:
        return [comment + " REQUIRED", f"{f.name} = {'0' if f.type == 'int' else '0.0'}"]
    if isinstance(default, float) and math.isnan(default):
        return [comment, f"# {f.name} = (unset)"]
    return [comment, f"# {f.name} = {_toml_value(default)}"]


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


if __name__ == "__main__":
    print(reference_toml(), end="")
