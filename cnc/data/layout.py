"""The controller's shared-memory blocks: what each holds and which process writes it.

| block       | writer             | holds |
|-------------|--------------------|-------|
| hw          | hardware server    | hardware image: tick counter, encoders, digital in, read-backs, watchdog |
| servo       | servo              | speed commands, drive enables, outputs, commanded/actual position, following error, faults, counters |
| command     | commander          | what the servo and the board are asked to do: drives enable, fault reset, the commander's token, epoch and heartbeat |
| supervisor  | supervisor         | safe state forced on a lost process, shutdown, virtual-clock gate, servo tracing |
| motion      | FIFO producer      | the planner's state and progress, and homing's position references for the servo |
| sim         | supervisor         | simulated-board environment: e-stop, doors, mains, drive faults, friction |
| plc         | PLC link           | the external PLC's input image, link state and counters |
| plc_out     | control logic      | the external PLC's output image |
| logic       | control logic      | mode, machine state, cycle phase, alarms summary, procedure, scan time |
| hw_timing   | hardware server    | histogram of tick wake latency (1 us bins) |
| logic_scan, logic_wake | control logic | histograms of the soft-PLC's scan time and wake latency (1 us bins) |
| servo_timing| servo              | histogram of tick-to-speed-command latency (1 us bins) |
| heartbeat   | one slot each      | per-process heartbeat counter and pid |

The commander is the control-logic process when it runs; a controller started without it
(tests of the servo and the planner alone) has the supervisor's process as its commander. The FIFO producer is the planner
process; a controller started without it (tests of the servo alone) feeds the FIFO and
writes `motion` from the supervisor's process instead.
"""

from __future__ import annotations

import enum

from ..bus.states import ClockKind, LinkState, PlannerState, RunResult, ServoFault, ServoState  # noqa: F401 - the schema's
from .dataserver import BlockLayout, FieldSpec as F

HIST_BINS = 5000  # 1 us bins: 0..4999 us, the last bin collects everything later
MAX_PROCESSES = 8


class Proc(enum.IntEnum):
    """Heartbeat slot of each controller process."""

    SUPERVISOR = 0
    HARDWARE = 1
    SERVO = 2
    GATEWAY = 3
    PLANNER = 4
    LOGIC = 5
    PLC_LINK = 6
    LOGGER = 7


def hw_layout(n: int) -> BlockLayout:
    return BlockLayout(
        "hw",
        [
            F("tick", "Q"),
            F("tick_time_ns", "q"),  # deadline of this tick (virtual: tick * period)
            F("wake_time_ns", "q"),  # when the hardware server actually woke (realtime clock)
            F("encoder_counts", "q", n),
            F("index_latch_counts", "q", n),
            F("index_latch_seq", "Q", n),
            F("axis_inputs", "I", n),
            F("digital_in", "I"),
            F("digital_out", "I"),  # read-back from the board
            F("watchdog_tripped", "I"),
            F("watchdog_missed", "I"),  # consecutive ticks the servo has missed
            F("watchdog_trip_tick", "Q"),
            F("servo_missed_total", "Q"),
            F("late_ticks", "Q"),  # ticks the hardware server itself woke a whole period late
            F("clock_kind", "I"),
            F("safe_state", "I"),  # the board is being held in the safe state
            F("reset_seq", "Q"),  # last command.reset_seq the hardware server acted on
            F("paused", "I"),  # virtual clock: held at command.virtual_run_until
            F("jet_off_tick", "Q"),  # tick at which the board's jet valve output last closed
            F("last_motion_tick", "Q"),  # last tick at which an axis moved faster than STILL_MM_S
            F("braking", "I"),  # the hardware server ramps the speed commands to 0 itself (watchdog, safe state)
            F("commander_token", "Q"),  # the commander whose reset_seq the hardware server follows
        ],
    )


def servo_layout(n: int) -> BlockLayout:
    return BlockLayout(
        "servo",
        [
            F("tick", "Q"),  # hardware tick these outputs belong to
            F("state", "I"),
            F("fault", "I"),
            F("fault_axis", "i"),
            F("fault_value", "d"),
            F("fault_tick", "Q"),
            F("speed_cmd_v", "d", n),
            F("drive_enable_mask", "I"),
            F("digital_out", "I"),
            F("commanded_mm", "d", n),
            F("commanded_velocity_mm_s", "d", n),
            F("actual_mm", "d", n),
            F("following_error_mm", "d", n),
            F("max_following_error_mm", "d", n),
            F("setpoint_flags", "I"),
            F("setpoint_segment", "I"),
            F("setpoint_line", "i"),
            F("ticks_processed", "Q"),
            F("overruns", "Q"),  # ticks the servo skipped (its count fell behind the tick counter)
            F("overrun_last_ticks", "Q"),  # ticks skipped at its latest overrun (how late it was, in periods)
            F("underruns", "Q"),  # ticks the FIFO ran dry during a motion
            F("underrun_tick", "Q"),  # first tick of the latest dry spell (the jet closed on it)
            F("loop_ns", "q"),  # compute time of the last tick
            F("reset_seq", "Q"),  # last command.reset_seq the servo acted on
            F("position_offset_mm", "d", n),  # machine position = encoder counts * resolution + offset
            F("position_ref_seq", "Q"),  # last command.position_ref_seq the servo applied
            F("homed_mask", "I"),  # bit i: axis i has a position reference (is homed)
            F("params_change", "Q"),  # the params block's change the servo applies (0: the machine file's values)
            F("params_tick", "Q"),  # the tick it was first applied at
            F("stop_causes", "I"),  # StopCause bits in effect this tick (cnc.interlock): the jet is held closed
            F("trip_seq", "Q"),  # +1 at every trip: the commander reports each one, however soon a reset follows
            F("fault_causes", "I"),  # StopCause bits in effect when the servo tripped
            F("trip_fault", "I"),  # the last trip (ServoFault), its axis, value and causes: kept after a reset
            F("trip_axis", "i"),
            F("trip_value", "d"),
            F("trip_causes", "I"),
            F("trip_speed_mm_s", "d"),  # path speed of the setpoints when it tripped
            F("trip_actual_mm", "d", n),  # measured position when it tripped
            F("brake_distance_mm", "d"),  # path the servo's own stop has run so far (0 when none)
            F("brake_tick", "Q"),  # the tick the servo's latest own stop began (a trip's, or the commander's)
            F("motion_epoch", "Q"),  # +1 whenever the motion under way is void: setpoints of another epoch are dropped
            F("stale_dropped", "Q"),  # setpoints dropped because their epoch was not the servo's
            F("commander_token", "Q"),  # the commander whose reset_seq the servo follows
            F("jet_on_ticks", "Q"),  # ticks the jet valve was open; +1 at each
            F("jet_on_mm", "d", n),  # where the jet last cut: the setpoint of the last tick it was open ...
            F("jet_on_segment", "I"),  # ... its program segment and line (what "continue" continues from)
            F("jet_on_line", "i"),
            F("jet_on_tick", "Q"),  # ... and the tick (a restarted logic tells by it which run the point belongs to)
            F("control_failures", "Q"),  # +1 each time the control program failed (cnc.control)
            F("control_failure", "s", 200),  # what it did, the last time (kept after a reset)
        ],
    )


def command_layout(n: int) -> BlockLayout:
    return BlockLayout(
        "command",
        [
            F("servo_enable", "I"),
            F("reset_seq", "Q"),  # +1 = reset faults (servo and watchdog) ...
            F("reset_tick", "Q"),  # ... the watchdog that tripped at or before this hardware tick (the commander saw it)
            F("reset_trip_seq", "Q"),  # ... the servo, if it has not tripped again since this trip_seq (the commander saw it)
            F("output_inhibit", "I"),  # DigitalOut bits held off whatever the setpoints say (jet off first on a fault)
            F("output_force", "I"),  # DigitalOut bits switched on while the axes hold still (jet test)
            F("token", "Q"),  # random per commander start: a new commander's counters are a new baseline
            F("epoch", "Q"),  # +1 at every stop the commander decides: motion commands of an older epoch are void
            F("heartbeat", "Q"),  # +1 every scan: the tick watches it (StopCause.COMMANDER)
            F("arm", "I"),  # StopCause bits the commander arms besides those always armed (BARRIER in a cycle)
            F("pressure_floor_bar", "d"),  # while the jet is open the pump must hold at least this (0: no floor)
            F("stop_seq", "Q"),  # +1 = the servo stops the motion under way itself, along its path (an alarm's stop)
        ],
    )


def supervisor_layout() -> BlockLayout:
    return BlockLayout(
        "supervisor",
        [
            F("safe_state", "I"),  # hold the board in the safe state
            F("shutdown", "I"),  # bit per process (Proc): stop it
            F("virtual_run_until", "Q"),  # virtual clock: do not tick past this tick (0: run freely)
            F("trace_enable", "I"),  # the servo writes every tick into the trace ring
            F("lost_seq", "Q"),  # +1 each time a controller process dies or hangs
            F("lost_proc", "I"),  # the last one lost (Proc)
            F("lost_restarted", "I"),  # ... and whether it was restarted
            F("lost_why", "s", 120),  # ... and how it was lost
            F("members", "I"),  # bit per process (Proc) this controller runs: what the tick may expect to hear from
        ],
    )


def motion_layout(n: int) -> BlockLayout:
    return BlockLayout(
        "motion",
        [
            F("position_ref_seq", "Q"),  # +1 = apply the position reference below (homing)
            F("position_ref_mask", "I"),  # axes it applies to
            F("position_ref_counts", "q", n),  # this encoder count ...
            F("position_ref_mm", "d", n),  # ... is this machine position
            F("position_ref_unhome", "I"),  # axes that lose their reference with this request (homing them again)
            F("state", "I"),  # PlannerState
            F("homing_axis", "i"),  # axis being homed, -1
            F("program_seq", "Q"),  # +1 at every program loaded
            F("program_name", "s", 128),
            F("program_hash", "s", 64),  # sha256 of the program text, hex
            F("program_lines", "Q"),
            F("program_start_mm", "d", n),  # where the loaded program's run starts from (G91 moves add up from it)
            F("planned_s", "d"),  # cycle time of the loaded program at 100 % override (-1 while it is being planned)
            F("pierce_s", "d"),  # the pierce dwell of the run in force: its cutting job's chart, else [jet] (the latter from the planner's start)
            F("cut", "s", 96),  # its cutting job (`cnc.cutmodel`), as the operator reads it; "" at the programmed F
            F("total_mm", "d"),  # path length of the loaded program
            F("run_seq", "Q"),  # +1 at every start
            F("run_result", "I"),  # RunResult of the last run
            F("run_start_tick", "Q"),
            F("run_end_tick", "Q"),
            F("segment", "q"),  # program segment the servo is on (-1 when none)
            F("line", "q"),  # its source line
            F("done_mm", "d"),  # path done by the servo
            F("segment_mm", "d"),  # how far into that segment, roughly (-1 none): an arc's turn, for "continue"
            F("eta_s", "d"),  # time left, from the planned profile (-1 while unknown)
            F("override", "d"),  # feed override ratio in force (0..2)
            F("fifo_min_fill", "q"),  # lowest FIFO fill seen at a refill during the run (-1: none yet)
            F("records_pushed", "Q"),
            F("event_seq", "Q"),  # +1 at every program event (message, program stop)
            F("event", "s", 160),  # "kind: text (line N)"
            F("error_seq", "Q"),  # +1 at every failure the planner reports
            F("error", "s", 240),
            F("params_change", "Q"),  # the params block's change the planner applies
        ],
    )


def sim_layout(n: int) -> BlockLayout:
    return BlockLayout(
        "sim",
        [
            F("estop_pressed", "I"),
            F("doors_open", "I"),
            F("mains_off", "I"),
            F("drive_fault_mask", "I"),
            F("friction_scale", "d", n),
            F("planner_stall", "I"),  # the planner pushes no setpoints (a planner starved of CPU)
            F("limit_switch_mask", "I"),  # bits 2i, 2i+1: axis i's min, max limit switch forced active (a tripped switch)
            F("inject_bug", "s", 96),  # "<process>/<verb>,...": those handlers raise (cnc.bus.service, fault injection)
            F("servo_stall_seq", "Q"),  # +1: the servo sits out the next servo_stall_ticks ticks (a host hiccup)
            F("servo_stall_ticks", "I"),
        ],
    )


MAX_PLC_VARS = 64  # values per image direction (config.MAX_PLC_VARS)


def plc_layout() -> BlockLayout:
    """The PLC's input image and the link's health (writer: the PLC-link process). Inputs are
    engineering values (raw * scale; bits 0/1) in the order of `PlcConfig.inputs()`."""
    return BlockLayout(
        "plc",
        [
            F("state", "I"),  # LinkState
            F("exchanges", "Q"),  # completed exchanges since start
            F("failed", "Q"),  # failed exchanges since start
            F("missed", "I"),  # consecutive failed exchanges now
            F("losses", "Q"),  # times the link was declared lost
            F("dropped", "Q"),  # answers dropped as not the one asked for (late, another unit's)
            F("noise", "Q"),  # bytes dropped as no frame (bad CRC, garbage on the line)
            F("cycle_us", "q"),  # duration of the last exchange
            F("input_seq", "Q"),  # +1 at every input image read
            F("output_seq_sent", "Q"),  # plc_out.image_seq of the last output image written to the PLC
            F("inputs", "d", MAX_PLC_VARS),
            F("error", "s", 160),  # last failure
        ],
    )


def plc_out_layout() -> BlockLayout:
    """The PLC's output image (writer: the control logic), in the order of `PlcConfig.outputs()`."""
    return BlockLayout("plc_out", [F("image_seq", "Q"), F("outputs", "d", MAX_PLC_VARS)])


def logic_layout() -> BlockLayout:
    """The control logic's state for the gateway and the tests (writer: control logic)."""
    return BlockLayout(
        "logic",
        [
            F("mode", "I"),  # Mode
            F("state", "I"),  # MachineState
            F("phase", "I"),  # CyclePhase
            F("cycles_done", "Q"),
            F("cycles_target", "Q"),  # 0: until stopped
            F("drives_on", "I"),  # the commander asks for the drives
            F("pump_on", "I"),
            F("pump_set_bar", "d"),
            F("jet_test", "I"),
            F("alarm_seq", "Q"),  # newest history sequence number
            F("alarms_active", "I"),  # entries in the active list
            F("alarm_level", "i"),  # most severe level in the active list (AlarmLevel), -1 none
            F("blocking", "I"),  # a fatal or error alarm is in the active list
            F("procedure_seq", "Q"),
            F("procedure", "s", 32),  # id of the procedure shown ("" none)
            F("procedure_state", "s", 16),
            F("scans", "Q"),
            F("scan_us", "q"),  # duration of the last scan
            F("message", "s", 200),  # last refusal or notice
            F("lost_seen", "Q"),  # the supervisor's lost_seq this logic (or the one before it) has reported
            F("trip_seen", "Q"),  # the servo's trip_seq the logic (or the one before it) has reported
            F("watchdog_seen", "Q"),  # the hardware server's watchdog_trip_tick the logic has reported
            F("cut_point_hash", "s", 64),  # the program the interrupted cut below belongs to ("" none known)
            F("cut_point_line", "q"),  # its source line
            F("cut_point_mm", "d", 2),  # where the jet last cut: X, Y (machine coordinates)
        ],
    )


MAX_PARAMS = 64  # control parameters the params block holds


def params_layout() -> BlockLayout:
    """The control parameters in force (writer: the gateway), slots in `cnc.params.registry` order."""
    return BlockLayout("params", [F("change", "Q"), F("values", "d", MAX_PARAMS)])  # change: +1 per change


def timing_layout(name: str) -> BlockLayout:
    return BlockLayout(name, [F("count", "Q"), F("max_ns", "q"), F("hist", "Q", HIST_BINS)])


def heartbeat_layout() -> BlockLayout:
    return BlockLayout("heartbeat", [F("beat", "Q", MAX_PROCESSES), F("pid", "q", MAX_PROCESSES)])


def controller_layouts(n_axes: int) -> list[BlockLayout]:
    """Every block of the data area, in placement order."""
    return [
        hw_layout(n_axes),
        servo_layout(n_axes),
        command_layout(n_axes),
        supervisor_layout(),
        motion_layout(n_axes),
        sim_layout(n_axes),
        plc_layout(),
        plc_out_layout(),
        logic_layout(),
        params_layout(),
        timing_layout("hw_timing"),
        timing_layout("servo_timing"),
        timing_layout("control_timing"),  # the control program's CPU time per period (the servo's `_run_law`)
        timing_layout("logic_scan"),
        timing_layout("logic_wake"),
        heartbeat_layout(),
    ]
