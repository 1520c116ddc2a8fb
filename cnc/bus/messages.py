"""Typed messages on the bus, declared once and shared by the controller and the HMI.

Payloads are JSON (Zenoh encoding application/json). Every top-level message carries
`version`: a reader refuses, clearly, a message whose major version it does not know.
Commands (and the settings inside them) refuse fields they do not declare: a misspelt optional
field would otherwise be dropped in silence (`Jog` with `distance` for `distance_mm` is a
continuous jog).
"""

from __future__ import annotations

from typing import Annotated

import msgspec

SCHEMA_VERSION = 1
MAX_CYCLES = 1_000_000  # cycles one CycleStart may ask for (JSON integers are unbounded; 0 runs until stopped)
MAX_MDI_CHARS = 20_000  # characters one MDI entry may hold: lines typed by hand, not a program (upload those)


class SchemaVersionError(ValueError):
    """The peer speaks a message schema this side does not understand."""


class AxisStatus(msgspec.Struct, frozen=True):
    name: str
    position_mm: float
    commanded_mm: float
    following_error_mm: float
    max_following_error_mm: float
    velocity_mm_s: float
    speed_command_v: float
    limit_min: bool
    limit_max: bool
    home_switch: bool
    drive_ready: bool
    drive_enabled: bool
    homed: bool = False
    travel_min_mm: float = 0.0  # the axis' travel (soft limits): a remote screen needs no machine file
    travel_max_mm: float = 0.0


class InterruptedCut(msgspec.Struct, frozen=True):
    """Where the jet last cut in the loaded program, a run that did not reach its end: what
    "continue" (`cmd/recover`) takes up, backed up by the overlap."""

    line: int  # its source line
    x_mm: float  # machine coordinates
    y_mm: float


class ProgramProgress(msgspec.Struct, frozen=True):
    """Where the planner is with the loaded program (in Status)."""

    name: str  # file name of the loaded program ("" when none)
    hash: str  # sha256 of its text
    lines: int
    segment: int  # segment the head is on (-1 before the first)
    line: int  # its source line
    done_mm: float
    remaining_mm: float
    progress: float  # 0..1 of the path
    eta_s: float  # time left from the planned profile (-1 at 0 % override or while the program is being planned)
    planned_s: float  # cycle time at 100 % override (-1 while it is being planned)
    run: int  # runs started since the controller came up
    result: str  # RunResult name of the last run
    cut: str = ""  # the cutting job in force ("leather 2 mm quality 3, by the program"); "" cuts at F
    interrupted: InterruptedCut | None = None  # the cut "continue" would take up; None when none is known


class ControlLaw(msgspec.Struct, frozen=True):
    """The axis control program and what it costs (in Status): its CPU time per period over the
    last second (-1: it did not run), its budget, and its failures (`cnc.control`)."""

    program: str  # "cross_coupled (CrossCoupled)"
    p50_us: float
    p99_us: float
    max_us: float
    budget_us: float
    failures: int  # times it was stopped since the controller started
    failure: str = ""  # what it did the last time


class Status(msgspec.Struct, frozen=True):
    """Cyclic controller status (`<root>/status`)."""

    machine: str
    seq: int
    stamp_ns: int  # wall-clock time of publication, ns since the epoch
    tick: int
    clock: str  # virtual | realtime | realtime-fallback
    servo_state: str  # ServoState name
    fault: str  # ServoFault name, NONE when healthy
    fault_axis: str  # axis name or "" when the fault is not an axis's
    watchdog_tripped: bool
    safe_state: bool
    estop_ok: bool
    doors_closed: bool
    jet_on: bool
    axes: list[AxisStatus]
    overruns: int
    underruns: int
    late_ticks: int
    servo_missed_ticks: int
    fifo_fill: int
    planner_state: str = "IDLE"  # PlannerState name
    feed_override: float = 1.0  # ratio, 0..2
    feed_commanded_mm_s: float = 0.0  # path speed of the setpoints
    feed_actual_mm_s: float = 0.0  # path speed the encoders measure
    homing_axis: str = ""
    program: ProgramProgress | None = None
    event: str = ""  # last program event (message, program stop)
    error: str = ""  # last failure the planner reported
    machine_state: str = "IDLE"  # MachineState name (the control logic's)
    mode: str = "MANUAL"  # Mode name
    cycle_phase: str = "NONE"  # CyclePhase name
    cycles_done: int = 0
    cycles_target: int = 0
    plc_link: str = "DOWN"  # LinkState name
    plc_exchanges: int = 0
    plc_failed: int = 0  # exchanges without a valid answer since the link process started
    plc_dropped: int = 0  # answers dropped as not the one asked for (late ones): a line worth a look
    pump_on: bool = False
    pump_set_bar: float = 0.0
    pump_pressure_bar: float = 0.0
    alarms_active: int = 0
    alarm_level: str = ""  # most severe active level ("" none)
    alarm_seq: int = 0  # newest history entry: a subscriber that missed one catches up from here
    procedure: str = ""  # id of the procedure shown
    logic_message: str = ""  # last refusal or notice of the control logic
    plc_inputs: dict[str, float] = msgspec.field(default_factory=dict)  # the PLC's input image by id (mains, air, transport...); empty while the link is not OK
    operator: str = ""  # the station holding the command lock ("" none)
    stations: list[str] = msgspec.field(default_factory=list)  # operator stations whose liveliness token is alive
    network_alive: bool = False  # the lock holder's station is connected
    control: ControlLaw | None = None  # the control program's timing (None: not told)
    version: int = SCHEMA_VERSION


class Position(msgspec.Struct, frozen=True):
    """The head for the live path (`<root>/position`, 50 Hz by default)."""

    seq: int
    stamp_ns: int
    tick: int
    position_mm: list[float]  # measured, per axis in machine order
    commanded_mm: list[float]
    velocity_mm_s: list[float]  # commanded
    segment: int  # program segment (-1 none)
    line: int
    jet_on: bool
    version: int = SCHEMA_VERSION


# -- the operator's door: lock, programs, jobs ----------------------------------------------


class LockRequest(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Take (or release) the command lock for the station named in the query's attachment."""

    take: bool = True
    version: int = SCHEMA_VERSION


class LockState(msgspec.Struct, frozen=True):
    """Who holds the command lock (`<root>/lock`, on change and queryable)."""

    holder: str  # station id ("" nobody)
    since_ns: int
    stations: list[str]  # operator stations alive (their liveliness tokens)
    seq: int
    version: int = SCHEMA_VERSION
    holder_user: str = ""  # the user the holding station logged in as ("local" on the controller's host)


class UploadProgram(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A program sent over Zenoh: checked (size, encoding), interpreted, and loaded when valid."""

    name: str  # file name, e.g. "nest.ngc"
    text: str
    version: int = SCHEMA_VERSION


class ProgramPath(msgspec.Struct, frozen=True):
    """The interpreted path of a program, one column per field, one row per motion (machine mm).
    kind: 0 rapid, 1 line, 2 arc (gcode.program's numbering); arcs have a centre and a direction."""

    kind: list[int]
    start_x: list[float]
    start_y: list[float]
    end_x: list[float]
    end_y: list[float]
    center_x: list[float]
    center_y: list[float]
    cw: list[bool]
    line: list[int]


class ProgramInfo(msgspec.Struct, frozen=True):
    """The loaded program for the preview (`<root>/program`): its text and interpreted path when it
    was uploaded over Zenoh (`?text=0` leaves the text out, `?path=1` adds the path)."""

    name: str
    hash: str
    bytes: int
    lines: int
    planned_s: float  # -1 while it is being planned
    text: str = ""
    path: ProgramPath | None = None
    errors: list[ProgramDiagnostic] = msgspec.field(default_factory=list)  # a stored program's preview: why it is refused
    version: int = SCHEMA_VERSION


class ProgramEntry(msgspec.Struct, frozen=True):
    """One program of the controller's program directory, as the library lists it. The figures come
    from checking it as `waterjet check` does (in the background, once per version of the file):
    -1 until then (`summary` pending), and when it is refused (`summary` refused, `error` says
    where and why: `cnc.bus.states.ProgramCheck`)."""

    name: str
    bytes: int
    modified_ns: int
    summary: str  # a ProgramCheck: "ready", "pending" or "refused"
    lines: int = -1
    segments: int = -1
    cut_length_mm: float = -1.0
    pierces: int = -1
    planned_s: float = -1.0  # cycle time at 100 % override, from X0 Y0
    error: str = ""
    last_run_end_ns: int = 0  # when its last run ended (0: never run)
    last_result: str = ""  # how it ended: DONE, ABORTED or FAULT
    last_cycle_s: float = -1.0
    loaded: bool = False  # the program the controller has loaded now


class ProgramList(msgspec.Struct, frozen=True):
    """Answer of `<root>/programs`: the program directory, by name."""

    directory: str
    max_bytes: int
    entries: list[ProgramEntry]
    version: int = SCHEMA_VERSION


class MaterialEntry(msgspec.Struct, frozen=True):
    """One material of the library (`cnc.materials`), as the job set-up offers it."""

    id: str
    name: str
    kind: str  # "abrasive" or "water"
    source: str  # where its numbers come from
    thicknesses_mm: list[float]  # its chart's rows (empty: not calibrated yet, it cannot be chosen)
    speeds_mm_min: list[list[float]]  # per row, the speed of quality 1..5
    corners: bool  # the chart has the trail-back and corner figures: corners and arcs are slowed


class MaterialList(msgspec.Struct, frozen=True):
    """Answer of `<root>/materials`: the machine's material library; `error` names a broken file
    (the others are listed)."""

    directory: str
    entries: list[MaterialEntry]
    error: str = ""
    version: int = SCHEMA_VERSION


class ControlParameter(msgspec.Struct, frozen=True):
    """One registered parameter of a control program (its value as the machine file gives it)."""

    name: str  # as the program registered it ("contour_gain_1_s")
    values: list[float]  # one, or one per axis
    unit: str
    lo: float
    hi: float
    doc: str
    per_axis: bool


class ControlProgramInfo(msgspec.Struct, frozen=True):
    """One control program the machine can run (`cnc.control`)."""

    name: str  # as `[control] program` names it
    class_name: str
    description: str
    parameters: list[ControlParameter]
    log_variables: list[str]  # the logger's names
    error: str = ""  # why it cannot be built ("" it can)


class ControlProgramList(msgspec.Struct, frozen=True):
    """Answer of `<root>/control/programs`: the shipped programs and the machine file's, which one
    the servo runs and which one the machine file names now (the next start's)."""

    programs: list[ControlProgramInfo]
    running: str
    selected: str
    budget_us: float
    version: int = SCHEMA_VERSION


class ControlSelect(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Make `program` the machine's control program (an engineer holding the lock; no program or
    control run under way): built and run on the simulated plant first (`waterjet control
    check`), then written into the machine file's `[control] program`; the controller runs it
    from its next start (its registrations size the shared-memory layouts at start)."""

    program: Annotated[str, msgspec.Meta(max_length=200)]
    version: int = SCHEMA_VERSION


class CalibrationLadder(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Make the speed ladder of a library material (`cnc.calibration`): `rungs` straight cuts from
    `slowest_mm_min` to `fastest_mm_min` in equal ratios, a `pierce_s` dwell each; checked against
    the machine, stored as ladder-<material>-<thickness>mm.ngc and loaded (at its programmed feeds)."""

    material: str
    thickness_mm: float
    slowest_mm_min: float
    fastest_mm_min: float
    rungs: int = 8
    pierce_s: float = 1.0
    version: int = SCHEMA_VERSION


class CalibrationRecord(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What a cut ladder showed, into the material's chart (an engineer's change): the row of
    `thickness_mm` with the fastest speed that cut through, the speed judged right per quality 1..5,
    the pierce time and kerf, and optionally the trail-back measured on each quality's rung."""

    material: str
    thickness_mm: float
    separation_mm_min: float
    quality_mm_min: list[float]
    pierce_s: float
    kerf_mm: float
    lag_mm: list[float] = msgspec.field(default_factory=list)
    version: int = SCHEMA_VERSION


class DeleteProgram(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Delete a program from the controller's program directory (not while it runs)."""

    name: str
    version: int = SCHEMA_VERSION


class JobRecord(msgspec.Struct, frozen=True):
    """One program run: what ran, when, how it ended, how long it took."""

    seq: int
    program: str
    hash: str
    start_ns: int
    end_ns: int
    result: str  # RunResult name
    cycle_time_s: float  # machine time from start to end
    planned_s: float = -1.0  # the planned cycle time at 100 % override (-1: not known when it ended)
    cut: str = ""  # the cutting job it ran with ("" at the programmed F)


class JobPage(msgspec.Struct, frozen=True):
    entries: list[JobRecord]
    more: bool
    version: int = SCHEMA_VERSION


class AuditRecord(msgspec.Struct, frozen=True):
    """One command a station sent (`<root>/audit/history`): who, from where, what, and its answer."""

    seq: int
    at_ns: int
    user: str  # the account it came from (the command key says so: only that user may send on it)
    station: str
    verb: str
    command: str  # the command as sent (JSON; an upload by its name and size)
    ok: bool
    reason: str


class AuditPage(msgspec.Struct, frozen=True):
    entries: list[AuditRecord]
    more: bool
    version: int = SCHEMA_VERSION


# -- alarms, messages and procedures (events) ------------------------------------------------


class AlarmEvent(msgspec.Struct, frozen=True):
    """One entry of the alarm and message history, published on `<root>/event/alarm` after it
    is stored. `seq` increases by one per entry across restarts: a subscriber that sees a gap
    asks the history for the entries it missed."""

    seq: int
    stamp_ns: int  # wall-clock time, ns since the epoch
    code: int
    id: str  # catalogue id
    level: str  # fatal | error | warning | info
    action: str  # raised | cleared | acknowledged | reset
    text: str
    detail: str = ""  # what was found: axis, value, line
    source: str = ""  # the process or subsystem that raised it
    cause: str = ""
    remedy: str = ""
    version: int = SCHEMA_VERSION


class ActiveAlarm(msgspec.Struct, frozen=True):
    """An alarm that is raised and not yet reset (in `AlarmList`)."""

    code: int
    id: str
    level: str
    text: str
    detail: str
    source: str
    raised_seq: int
    raised_ns: int
    active: bool  # its condition is still present (false: cleared, waits for reset)
    acknowledged: bool


class AlarmList(msgspec.Struct, frozen=True):
    """Answer of the active-alarms query."""

    alarms: list[ActiveAlarm]
    last_seq: int
    version: int = SCHEMA_VERSION


class HistoryPage(msgspec.Struct, frozen=True):
    """Answer of a history query: entries in sequence order, and whether more follow."""

    entries: list[AlarmEvent]
    last_seq: int  # newest sequence number in the history
    more: bool
    version: int = SCHEMA_VERSION


class ProcedureStep(msgspec.Struct, frozen=True):
    text: str
    state: str  # pending | awaited | done | timed_out
    instruction: str = ""
    action: str = ""  # "confirm" when the operator must confirm the step


class ProcedureState(msgspec.Struct, frozen=True):
    """A guided procedure as the operator sees it (`<root>/procedure`, on change)."""

    id: str  # "" when no procedure runs
    title: str
    state: str  # idle | running | done | stopped | timed_out
    step: int  # index of the step awaited (-1 when none)
    steps: list[ProcedureStep]
    instruction: str  # what the operator must do now
    seq: int  # +1 at every change
    by_cycle: bool = False  # the automatic cycle started it and goes on by itself once it is done
    version: int = SCHEMA_VERSION


class ProcedureInfo(msgspec.Struct, frozen=True):
    """One guided procedure of the machine file, as an operator screen offers it."""

    id: str
    title: str
    steps: list[str]  # the steps' texts, in order


class ProcedureCatalogue(msgspec.Struct, frozen=True):
    """The guided procedures an operator may start (`<root>/procedures`, queryable)."""

    procedures: list[ProcedureInfo]
    version: int = SCHEMA_VERSION


# -- control parameters (QMotor's), at `param/<name>` and `params` ----------------------------


class ParamInfo(msgspec.Struct, frozen=True):
    """One control parameter: what it is, its range, the value in force and the machine file's."""

    name: str  # "axis.x.kp_1_s": the machine-file option it is
    description: str
    unit: str
    min: float
    max: float
    value: float  # in force
    file_value: float  # what the machine file says (the value after a restart, unless saved)
    owner: str  # the process that applies it: servo | planner
    changeable: str  # always | idle (only while no program runs)
    effect: str  # when the machine feels a change: "the next tick", "the next program loaded", ...
    version: int = SCHEMA_VERSION


class ParamList(msgspec.Struct, frozen=True):
    """Every control parameter (`params`), and the sequence number of the last change."""

    params: list[ParamInfo]
    seq: int
    version: int = SCHEMA_VERSION


class SetParam(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Change one control parameter (a query on `param/<name>` with this payload; the command lock applies)."""

    value: float
    version: int = SCHEMA_VERSION


class SaveParams(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Write the control parameters in force into the machine file (a query on `params`; the lock applies)."""

    version: int = SCHEMA_VERSION


# -- data logging (QMotor's log variables), at `log/...` -----------------------------------------


class LogVariable(msgspec.Struct, frozen=True):
    """A variable the logger can record."""

    name: str  # "x.following_error"
    unit: str
    description: str


class LogSetting(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """How one variable is logged in a run (QMotor's modes), at every `divisor`-th base tick:
    timed: from `start_s` for `duration_s` after the run starts; continuous: the last `window_s`
    seconds, kept when the run ends; triggered: while `enable_when` holds (or, with `disable_when`,
    from `enable_when` becoming true until `disable_when` does). Conditions are over log variables:
    `x.following_error > 0.02 or jet`."""

    name: str
    mode: str = "timed"  # timed | continuous | triggered
    divisor: int = 1
    start_s: float = 0.0
    duration_s: float = 10.0
    window_s: float = 10.0
    enable_when: str = ""
    disable_when: str = ""


class LogStart(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Start a log run (a query on `log/start`); the reply names the run."""

    variables: list[LogSetting]
    title: str = ""
    version: int = SCHEMA_VERSION


class LogStop(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """End the log run now (a query on `log/stop`); what was recorded is kept."""

    version: int = SCHEMA_VERSION


class LogRunSummary(msgspec.Struct, frozen=True):
    run: int
    title: str
    started_ns: int
    ended_ns: int  # 0 while it runs
    duration_s: float
    variables: list[str]
    samples: int
    state: str  # running | done


class LogState(msgspec.Struct, frozen=True):
    """The logger (`log/state`): what can be logged, the run under way and the runs kept."""

    variables: list[LogVariable]
    period_s: float  # the base tick: divisors are of this
    running: int  # the run under way (0 none)
    runs: list[LogRunSummary]
    version: int = SCHEMA_VERSION


class LogSamples(msgspec.Struct, frozen=True):
    """Samples of one variable: times (s since the run's start) and values."""

    t: list[float]
    v: list[float]


class LogLive(msgspec.Struct, frozen=True):
    """Published on `log/live` about 10 times a second: the latest value of every variable (the
    watch window) and, while a run records, the samples taken since the last message (live plots)."""

    seq: int
    tick: int
    latest: dict[str, float]
    run: int = 0
    samples: dict[str, LogSamples] = msgspec.field(default_factory=dict)
    version: int = SCHEMA_VERSION


class LogColumn(msgspec.Struct, frozen=True):
    """A whole variable of a run: little-endian float64 arrays (exact, and compact as base64)."""

    t: bytes  # seconds since the run's start
    v: bytes


class LogRunData(msgspec.Struct, frozen=True):
    """A whole run (`log/runs/<n>`): settings, the samples, and the control parameters in force."""

    run: int
    title: str
    started_ns: int
    ended_ns: int
    period_s: float
    settings: list[LogSetting]
    columns: dict[str, LogColumn]
    units: dict[str, str]
    params_start: dict[str, float]  # control parameters when the run started
    params_end: dict[str, float]  # ... and when it ended
    param_changes: list[tuple[float, str, float]]  # (s since the start, name, new value) during the run
    truncated: list[str]  # variables that hit the sample limit
    control_program: str = ""  # the axis control program that ran ("cross_coupled (CrossCoupled)")
    control_us: list[float] = msgspec.field(default_factory=list)  # its CPU time per period during the run: p50, p99, max
    version: int = SCHEMA_VERSION


# -- commands to the planner (answered with a Reply) ------------------------------------------


class Stamp(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Who issued a motion command, and when: the commander's per-start token and the epoch (its
    count of stops) it was issued in. The planner carries out a motion command only with the
    current commander's token and epoch: one issued before a stop or a fault never moves the
    machine after it. Set by the commander (the control logic); an operator's is replaced."""

    token: int
    epoch: int


class SetCut(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The cutting job of the loaded program (`cnc.cutmodel`): a `material` of the machine's library,
    its `thickness_mm`, the edge `quality` 1-5, the `mode` ("quality": the model sets the speed and F
    is only an upper bound; "feed": F as programmed), the lead-ins' `pierce_quality`. An empty
    `material` goes back to what the program says (its `(MATERIAL, ...)` comment, or its F). Only
    while no program runs; the loaded program's cycle time is planned again with it."""

    material: str = ""
    thickness_mm: float = 0.0
    quality: int = 3
    mode: str = "quality"
    pierce_quality: int = 5
    version: int = SCHEMA_VERSION


class LoadProgram(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Interpret and check a program file; it becomes the program `Start` runs. `cut`: its cutting
    job, when the operator chose one for it (the gateway remembers it per program); else what the
    program says."""

    path: str
    cut: SetCut | None = None
    version: int = SCHEMA_VERSION


class RestartAt(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Where a run starts when not at the program's beginning (`cnc.planner.recovery`): "continue"
    the cut stopped on `segment` at (`x_mm`, `y_mm`), backed up by `overlap_mm`; "part" `number`
    (its Nth pierce); or "line" `number`. `start_mm`: where the interrupted run started from (one
    value per machine axis), for a program whose moves depend on it (G91): the program is placed as
    that run placed it, also when it was loaded again elsewhere; empty: as it is loaded."""

    kind: str
    number: int = 0
    segment: int = -1
    x_mm: float = 0.0
    y_mm: float = 0.0
    overlap_mm: float = 0.0
    segment_mm: float = -1.0  # roughly how far into `segment` the jet stopped (-1 unknown): an arc's turn
    start_mm: tuple[float, ...] = ()


class Start(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Run the loaded program from its beginning (cycle start), or from `restart`."""

    stamp: Stamp | None = None
    restart: RestartAt | None = None
    version: int = SCHEMA_VERSION


class CheckRestart(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Would `restart` start in the loaded program from where the head stands (the part, the line,
    the cut point, the travel)? Asked before the cycle ramps the pump for it; nothing moves."""

    restart: RestartAt
    version: int = SCHEMA_VERSION


class Hold(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Feed hold: decelerate along the path and stay there."""

    why: str = ""  # the controller's own hold says why (the operator's station was lost): in the history
    version: int = SCHEMA_VERSION


class Resume(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Continue after a hold or a program stop."""

    stamp: Stamp | None = None
    version: int = SCHEMA_VERSION


class Stop(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Decelerate to rest and end the program (or the manual motion)."""

    version: int = SCHEMA_VERSION
    # why, when the control logic stops the planner for a cause of its own (a safe stop, a control
    # run's end): what the planner reports instead of "by the operator" (a station's is not passed on)
    reason: Annotated[str, msgspec.Meta(max_length=200)] = ""


class Override(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Feed override in percent, 0 to 200 (rapids follow it up to 100)."""

    percent: float
    version: int = SCHEMA_VERSION


class Jog(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Jog one axis: continuously (until JogStop) when distance_mm is None, else by that distance.
    The sign of velocity_mm_s gives the direction of a continuous jog; 0 means the default speed."""

    axis: str
    velocity_mm_s: float = 0.0
    distance_mm: float | None = None
    stamp: Stamp | None = None
    version: int = SCHEMA_VERSION


class JogStop(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """End a continuous jog: decelerate to rest."""

    version: int = SCHEMA_VERSION


class JogRefresh(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The station still holds the jog key: a continuous jog not refreshed within `[planner]
    jog_deadman_ms` stops by itself (a crashed screen or a pulled cable must not jog on). It
    travels on the same lane as a stop."""

    stamp: Stamp | None = None
    version: int = SCHEMA_VERSION


class GoTo(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Move in a straight line to a position (axes left out stay); at feed_mm_s, or the axis limits when None."""

    position_mm: dict[str, float]
    feed_mm_s: float | None = None
    stamp: Stamp | None = None
    version: int = SCHEMA_VERSION


class Home(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Home these axes in this order (all axes, in machine order, when empty)."""

    axes: list[str] = msgspec.field(default_factory=list)
    stamp: Stamp | None = None
    version: int = SCHEMA_VERSION


class Mdi(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Run G-code typed by hand (manual data input): one or more lines, in MANUAL mode, on a homed
    machine. Checked as a program is (an error names its line and column) and against the travel
    before anything moves; interpreted from where the head stands, each entry from the machine's
    default modal state. The jet opens only where the lines ask for it (the jet-on M-code) and
    only when the interlocks and the pump's pressure allow it; program stops (M0, M1, M60) are
    refused: there is no cycle start in MANUAL to go on with."""

    text: Annotated[str, msgspec.Meta(max_length=MAX_MDI_CHARS)]
    stamp: Stamp | None = None
    jet_refused: str = ""  # set by the commander: why the jet may not open now ("" it may); an operator's is replaced
    version: int = SCHEMA_VERSION


class ControlRun(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """QMotor's timed run of the control alone: in MANUAL, on a homed machine at rest, the axes
    hold position ("hold") or follow a test trajectory from where the head stands ("step",
    "ramp", "circle", or "fig10", the paper's contour) for `duration_s`, the jet closed; then
    they stop on the path. Stop and hold end it earlier (`cnc.control.trajectories.run_text`)."""

    trajectory: str
    duration_s: float
    version: int = SCHEMA_VERSION


class ProgramDiagnostic(msgspec.Struct, frozen=True):
    """Where a program is wrong: its line and column (1-based) and what is wrong there."""

    line: int
    column: int
    message: str
    source_line: str = ""


class Reply(msgspec.Struct, frozen=True):
    """A command's answer: ok, or refused with the reason (a program's errors with line and column)."""

    ok: bool
    reason: str = ""
    errors: list[ProgramDiagnostic] = msgspec.field(default_factory=list)
    version: int = SCHEMA_VERSION


PLANNER_COMMANDS: dict[str, type[msgspec.Struct]] = {
    "load": LoadProgram, "start": Start, "hold": Hold, "resume": Resume, "stop": Stop, "override": Override,
    "jog": Jog, "jog_stop": JogStop, "jog_refresh": JogRefresh, "goto": GoTo, "home": Home, "mdi": Mdi,
    "cut_setup": SetCut, "check_restart": CheckRestart,
}
MOTION_COMMANDS = (Start, Resume, Jog, JogRefresh, GoTo, Home, Mdi)  # carried out only with the commander's Stamp
REALTIME_VERBS = ("stop", "hold", "jog_stop", "jog_refresh", "reset", "stop_all")  # never queued behind slow work
# Verbs whose handlers command motion or the jet: a bug met while serving one brings the machine to
# its safe state (cnc.bus.service). A stop is among them: a stop that failed must still stop.
MOTION_VERBS = frozenset({
    "start", "resume", "jog", "jog_refresh", "goto", "home", "mdi", "control_run", "recover", "drives", "pump", "jet_test", "override",
    "stop", "hold", "jog_stop", "reset", "procedure_start", "procedure_confirm", "procedure_stop", "stop_all",
})
LOCK_FREE_VERBS = frozenset({"stop_all"})  # any operator station, with or without the command lock
ENGINEER_VERBS = frozenset({"control_run"})  # the tuning tools: the engineer's role (where logins are on)


class InternalError(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A bug a controller process met while serving a request (STYLE.md's third tier), told to the
    control logic (`internal/logic/bug`), which raises the internal-error alarm and, with `motion`,
    first brings the machine to its safe state."""

    process: str
    what: str  # the request that failed ("jog", "param axis.x.kp_1_s", ...)
    detail: str  # the exception, as repr
    motion: bool = False
    version: int = SCHEMA_VERSION


# -- commands to the control logic (the machine's commander; answered with a Reply) ---------


class SetMode(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Operation mode: MANUAL (jog, home, pump and jet by hand) or AUTO (the automatic cycle)."""

    mode: str
    version: int = SCHEMA_VERSION


class CycleStart(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Start the automatic cycle for `cycles` cycles (0: until stopped)."""

    cycles: Annotated[int, msgspec.Meta(le=MAX_CYCLES)] = 1  # the logic refuses a negative count
    version: int = SCHEMA_VERSION


class Recover(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Start the automatic cycle inside the loaded program, with the material already in place (no
    transport): `kind` "continue" the cut interrupted last (where the jet last cut, backed up by
    `overlap_mm`, default `[cycle] recovery_overlap_mm`), "part" `number` (1-based), or "line"
    `number`. The rest of the program runs, then the cycle unloads as after any cut."""

    kind: str
    number: int = 0
    overlap_mm: float | None = None
    version: int = SCHEMA_VERSION


class StopAll(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Stop everything, from any operator station, with or without the command lock: the jet closed
    at once, the axes stopped on their braking distance, then the drives off; latched (alarm 1097,
    naming the station) until reset. A software stop: the hardwired e-stop circuit stays the
    category-0 stop, and this does not replace it."""

    station: str = ""  # who asked: the gateway writes it (what a client sends here is replaced)
    version: int = SCHEMA_VERSION


class Reset(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Reset faults and alarms whose cause has gone, and switch the drives on."""

    version: int = SCHEMA_VERSION


class Drives(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Switch the axis drives on or off (manual mode or idle)."""

    on: bool
    version: int = SCHEMA_VERSION


class Pump(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Run the high-pressure pump (manual mode), at `pressure_bar` or the machine's cutting pressure."""

    on: bool
    pressure_bar: float | None = None
    version: int = SCHEMA_VERSION


class JetTest(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Open the jet at standstill (manual mode, pump at pressure), or close it."""

    on: bool
    version: int = SCHEMA_VERSION


class Acknowledge(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The operator has seen alarm `code` (all active alarms when None)."""

    code: int | None = None
    version: int = SCHEMA_VERSION


class ProcedureStart(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Start the guided procedure `id` of the machine file."""

    id: str
    version: int = SCHEMA_VERSION


class ProcedureConfirm(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The operator did what the awaited step asks."""

    version: int = SCHEMA_VERSION


class ProcedureStop(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """"Procedure stopped": abandon the running procedure."""

    version: int = SCHEMA_VERSION


class ProcedureEnd(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """"End the procedure": close a finished or stopped procedure."""

    version: int = SCHEMA_VERSION


# -- the simulated machine's inputs (`cmd/sim`, `<root>/sim`; the supervisor owns them) -------------


class SimInput(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Change one input of the simulated machine: press a button (value 1), throw a switch (0 or
    1), set a value within its range (`SimInputs` lists them). Refused on a real board."""

    input: str
    value: float
    version: int = SCHEMA_VERSION


class SimInputInfo(msgspec.Struct, frozen=True):
    """One input of the simulated machine, its value now and what it may be set to."""

    name: str
    kind: str  # "button" (pressed by 1), "switch" (0 or 1) or "value"
    value: float
    unit: str
    minimum: float
    maximum: float
    doc: str


class SimInputs(msgspec.Struct, frozen=True):
    """Answer of `<root>/sim`: every input of the simulated machine."""

    inputs: list[SimInputInfo]
    version: int = SCHEMA_VERSION


class Notice(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Controller-internal: an info entry for the alarm history, which the control logic keeps
    (the gateway tells it what an operator changed on the simulated machine)."""

    id: str
    detail: str
    version: int = SCHEMA_VERSION


LOGIC_COMMANDS: dict[str, type[msgspec.Struct]] = {
    "mode": SetMode, "start": CycleStart, "hold": Hold, "resume": Resume, "stop": Stop, "reset": Reset,
    "drives": Drives, "home": Home, "jog": Jog, "jog_stop": JogStop, "jog_refresh": JogRefresh, "goto": GoTo,
    "mdi": Mdi, "control_run": ControlRun, "recover": Recover, "load": LoadProgram, "cut_setup": SetCut,
    "override": Override, "pump": Pump, "jet_test": JetTest, "acknowledge": Acknowledge,
    "procedure_start": ProcedureStart, "procedure_confirm": ProcedureConfirm, "procedure_stop": ProcedureStop,
    "procedure_end": ProcedureEnd, "stop_all": StopAll,
}


_encoder = msgspec.json.Encoder()


def encode(msg: msgspec.Struct) -> bytes:
    return _encoder.encode(msg)


def decode(payload: bytes, kind: type[msgspec.Struct]) -> msgspec.Struct:
    """Decode and check the schema version; raises SchemaVersionError or msgspec.ValidationError."""
    why = ""
    try:
        version = msgspec.json.decode(payload, type=_Versioned).version
    except msgspec.ValidationError as exc:  # not an object, or a version that is not an integer
        version, why = None, f" ({exc})"
    if version != SCHEMA_VERSION:
        raise SchemaVersionError(
            f"{kind.__name__}: message schema version {version} is not the supported version {SCHEMA_VERSION}{why}"
        )
    return msgspec.json.decode(payload, type=kind)


class _Versioned(msgspec.Struct):
    version: int | None = None
