"""Every fault in every state, on the real-time side stepped tick by tick (`tests/tickrig.py`).

For each cell that applies: the fault is put on the machine while it is in the state; the jet
must be closed at the board within one tick of the cause reaching the tick (the image, or the
PLC block, that first shows it), the axes must come to rest within the stop bound

    v T_detect + v^2 / (2 a) + v a / (2 j) + 1 mm       (a, j: the machine's deceleration and jerk)

(v: the head's speed by the tick that acted; where it was speeding up then, at a0, the speed it
still gains while the stop takes that acceleration out, v + a0^2 / (2 j), and v a0 / j more:
out of a corner, a fault finds the head accelerating)
(category 0 stops, e-stop and mains loss, coast: their distance is reported), the servo must
hold the trip that names the fault (and so its alarm), a reset while the axes still run out the
stop must change nothing, and once the fault is gone a reset must bring the machine back, and it
must move again, without a restart. The table of every cell is printed at the end of the run.
Cells that do not apply are listed with the reason (`NOT_APPLICABLE`). The same faults through
the real processes, each at least once, are in `test_fault_injection.py`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import pytest

from cnc.brake import stop_distance_bound_mm
from cnc.hw.board import DigitalOut
from cnc.interlock import StopCause
from cnc.data.layout import LinkState, Proc, ServoFault, ServoState
from cnc.planner.runner import RunState
from cnc.safety import fault_alarm

from .conftest import SAFETY_MATRIX, machine_config
from .tickrig import Rig

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

# a short pierce: the cells are about the cut, not the wait before it
QUICK_PIERCE = {"jet.on_delay_s": 0.0, "jet.pierce_dwell_s": 0.01}
CONFIG = machine_config(**{"sim.axes.x.start_position_mm": 100.0, "sim.axes.y.start_position_mm": 100.0, **QUICK_PIERCE})
HOMING_CONFIG = machine_config(**{"sim.axes.x.start_position_mm": 8.0, "sim.axes.y.start_position_mm": 100.0})
A = min(a.max_accel_mm_s2 for a in CONFIG.axes)
J = min(a.max_jerk_mm_s3 for a in CONFIG.axes)
DT = CONFIG.timing.period_s
JET = int(DigitalOut.JET_VALVE)
CUT = "G21 G90 G64 P0.05\nM3\nG1 X1500 F{feed}\nM5\nM2\n"
FLOOR_BAR = CONFIG.pump.cut_pressure_bar - CONFIG.pump.drop_bar


# -- the states ----------------------------------------------------------------------------
@dataclass
class State:
    name: str
    config: object
    enter: Callable[[Rig], None]
    moving: bool
    cutting: bool = False
    in_cycle: bool = True  # cutting in the automatic cycle (barriers armed), not by hand (MDI)


def _cut(feed_mm_s: float) -> Callable[[Rig], None]:
    def enter(rig: Rig) -> None:
        rig.set_command(arm=int(StopCause.BARRIER), pressure_floor_bar=FLOOR_BAR)  # the commander's cycle
        rig.run_program(CUT.format(feed=feed_mm_s * 60.0))
        rig.run_until(lambda: rig.speed_mm_s() > 0.99 * feed_mm_s and rig.jet[-1], 5000, f"cutting at {feed_mm_s} mm/s")
        rig.step(20)
    return enter


CORNER = "G21 G90 G64 P0.05\nM3\nG1 X400 F30000\nG1 X100 Y400\nM5\nM2\n"  # a 135 degree turn: X moves on
# a 45 degree turn: the planner moves the corner outward by P / 2 first (`sections._move_stop_corners`);
# X moves on (at a right angle a seized X would have nothing left to follow)
MOVED_CORNER = "G21 G90 G64 P0.05\nM3\nG1 X400 F30000\nG1 X700 Y400\nM5\nM2\n"
# the same turn compensated on its outside (G42, turning left): the kerf arc at the corner is folded
# into the corner of the two lines (`sections._fold_small_turns`), which the overlap passes
KERF_CORNER = "G21 G90 G64 P0.05\nM3\nG42 D1 G1 X300 F30000\nG1 X400\nG1 X700 Y400\nG40 G1 X700 Y420\nM5\nM2\n"


def _corner_overlap(program: str) -> Callable[[Rig], None]:
    def enter(rig: Rig) -> None:
        """Cutting through a corner the planner overlaps (`cnc/planner/overlap.py`): the second move
        has begun while the first still arrives, the head off both within P; the fault comes in the
        middle of it (no step after: the overlap lasts tens of ticks)."""
        rig.set_command(arm=int(StopCause.BARRIER), pressure_floor_bar=FLOOR_BAR)
        rig.run_program(program)

        def in_overlap() -> bool:  # still arriving in X (the first move) while the second has left in Y
            (x0, y0), (x1, y1) = rig.positions[-2][:2], rig.positions[-1][:2]
            return x1 > 399.0 and x1 > x0 + 1e-6 and y1 > y0 + 1e-6 and y1 > 99.0 and rig.jet[-1]
        rig.run_until(in_overlap, 5000, "the head cutting the corner's overlap")
    return enter


# a lead-out turned back 135 degrees into a rapid (the comparison nest's, `bench/linuxcnc_compare.py`): passed
# by a connection (`cnc/planner/connection.py`), both axes planned through the corner; no jet (it would close
# at the lead-out's end, a stop there)
CONNECTED_CORNER = "G21 G90 G64 P0.05\nG1 X120 Y100 F2400\nG1 X118 Y98\nG0 X175 Y97\nG1 Y100\nM2\n"


def _corner_connection(rig: Rig) -> None:
    """Moving through a connection's samples: the fault comes in the middle of them."""
    rig.run_program(CONNECTED_CORNER)
    rig.run_until(lambda: rig.feeder.runner is not None and rig.feeder.runner.connecting and rig.speed_mm_s() > 10.0,
                  5000, "the head in the corner's connection")


# a 30 degree turn between two long cuts at F12000: passed by a programmed connection
# (`cnc/planner/programme.py`: the samples through the corner solved for, up to 120 ms of them, the
# head drifting out within P and crossing the corner), where the overlap would all but stop
PROGRAMMED_CORNER = "G21 G90 G64 P0.05\nM3\nG1 X400 F12000\nG1 X573.205 Y200\nM5\nM2\n"


def _programmed_connection(rig: Rig) -> None:
    """Cutting through a programmed connection's samples (longer than any connection of Ruckig's,
    60 ms): the fault comes in the middle of them."""
    rig.set_command(arm=int(StopCause.BARRIER), pressure_floor_bar=FLOOR_BAR)
    rig.run_program(PROGRAMMED_CORNER)
    rig.run_until(lambda: rig.feeder.runner is not None and rig.feeder.runner.connecting
                  and rig.feeder.runner.overlap_left > 40 and rig.speed_mm_s() > 50.0 and rig.jet[-1],
                  5000, "the head cutting the corner's programmed connection")
    rig.step(20)


def _mdi_cut(rig: Rig) -> None:
    """Cutting by hand (MDI in MANUAL): the pressure floor holds, the barriers are not armed."""
    rig.set_command(pressure_floor_bar=FLOOR_BAR)
    rig.run_program("M3\nG1 X1500 F30000\nM5\nM2\n")
    rig.run_until(lambda: rig.speed_mm_s() > 0.99 * 500.0 and rig.jet[-1], 5000, "cutting by hand at 500 mm/s")
    rig.step(20)


def _held(rig: Rig) -> None:
    _cut(50.0)(rig)
    rig.feeder.runner.hold()
    rig.run_until(lambda: rig.feeder.runner.state == RunState.HELD and rig.fifo.fill() == 0 and rig.speed_mm_s() < 0.5
                  and not rig.jet[-1], 2000, "held at rest")
    rig.step(20)


def _jet_test(rig: Rig) -> None:
    rig.set_command(output_force=JET)
    rig.run_until(lambda: rig.jet[-1], 10, "the jet test's jet")
    rig.step(20)


def _jogging(rig: Rig) -> None:
    rig.jog(0, CONFIG.planner.jog_velocity_mm_s, CONFIG.axis["x"].travel_max_mm)
    rig.run_until(lambda: rig.speed_mm_s() > 0.99 * CONFIG.planner.jog_velocity_mm_s, 2000, "jogging")
    rig.step(20)


def _homing(rig: Rig) -> None:
    rig.home(["x"])
    search = abs(CONFIG.axis["x"].home_search_velocity_mm_s)
    rig.run_until(lambda: rig.speed_mm_s() > 0.99 * search, 2000, "searching the home switch")
    rig.step(20)


def _loading(rig: Rig) -> None:
    """The planner checks and plans a program: nothing queued, the axes hold."""
    rig.step(20)


STATES = [
    State("cutting 50 mm/s", CONFIG, _cut(50.0), True, cutting=True),
    State("cutting 500 mm/s", CONFIG, _cut(500.0), True, cutting=True),
    State("MDI cutting 500 mm/s", CONFIG, _mdi_cut, True, cutting=True, in_cycle=False),
    State("in a corner's overlap at F30000", CONFIG, _corner_overlap(CORNER), True, cutting=True),
    State("in a moved corner's overlap at F30000", CONFIG, _corner_overlap(MOVED_CORNER), True, cutting=True),
    State("in a folded kerf corner's overlap at F30000", CONFIG, _corner_overlap(KERF_CORNER), True, cutting=True),
    State("in a corner's connection (lead-out into a rapid)", CONFIG, _corner_connection, True),
    State("in a programmed connection at F12000", CONFIG, _programmed_connection, True, cutting=True),
    State("held", CONFIG, _held, False),
    State("jet test", CONFIG, _jet_test, False),
    State("jogging", CONFIG, _jogging, True),
    State("homing", HOMING_CONFIG, _homing, True),
    State("loading a program", CONFIG, _loading, False),
]


# -- the faults ----------------------------------------------------------------------------
@dataclass
class Fault:
    name: str
    inject: Callable[[Rig], None]
    clear: Callable[[Rig], None]
    trip: ServoFault  # what the servo must hold (and so the alarm it raises)
    applies: Callable[[State], str]  # "" when the cell applies, else why not
    category0: bool = False
    via_plc: bool = False  # the cause reaches the tick through the PLC block


def _everywhere(state: State) -> str:
    return ""


def _moving_only(state: State) -> str:
    return "" if state.moving else "nothing moves: nothing to follow or run dry"


def _cycle_only(state: State) -> str:
    return "" if state.cutting and state.in_cycle else "armed only in the automatic cycle (the barriers guard the transport zone)"


def _jet_cut_only(state: State) -> str:
    return "" if state.cutting else "the pressure floor holds only while the jet cuts"


def _plc_cut(rig: Rig) -> None:
    rig.alive.plc_link = False  # no exchange answers: the image stops; the link declares LOST after its cycles
    rig.lost_at = rig.tick + rig.plc_ticks * CONFIG.plc.lost_after_cycles


def _revive_plc(rig: Rig) -> None:
    rig.alive.plc_link = True
    rig.plc.set("state", int(LinkState.OK))
    rig.pids[Proc.PLC_LINK] = rig.pids[Proc.SUPERVISOR]


def _revive_commander(rig: Rig) -> None:
    rig.alive.commander = True
    rig.pids[Proc.LOGIC] = rig.pids[Proc.SUPERVISOR]
    rig.command.publish()  # a new commander writes its block whole


def _revive_servo(rig: Rig) -> None:
    from cnc.servo import Servo

    rig.servo.close()
    rig.servo = Servo(rig.config, rig.area, rig.fifo, record_latency=False, clock_ns=lambda: rig.tick * rig.period_ns)
    rig.alive.servo = True


def _nothing(rig: Rig) -> None:
    return None


def _law(control: Callable | None) -> Callable[[Rig], None]:
    """The servo's control program's `control` replaced by `control` (None: its own again)."""
    def put(rig: Rig) -> None:
        if control is None:
            rig.servo.program.__dict__.pop("control", None)
        else:
            rig.servo.program.control = control
    return put


def _raises(inputs) -> list[float]:  # noqa: ANN001
    raise ZeroDivisionError("division by zero")


def _nan(inputs) -> list[float]:  # noqa: ANN001
    return [math.nan, 0.0]


def _spins(inputs) -> list[float]:  # noqa: ANN001 - two periods of CPU time each period
    until = time.thread_time_ns() + int(2e9 * DT)
    while time.thread_time_ns() < until:
        pass
    return [0.0, 0.0]


FAULTS = [
    Fault("e-stop", lambda r: r.board.set_estop(True), lambda r: r.board.set_estop(False), ServoFault.ESTOP, _everywhere,
          category0=True),
    Fault("door opened", lambda r: r.board.set_doors(True), lambda r: r.board.set_doors(False), ServoFault.DOORS, _everywhere),
    Fault("light barrier", lambda r: r.set_plc_input(barrier_front_ok=0.0), lambda r: r.set_plc_input(barrier_front_ok=1.0),
          ServoFault.BARRIER, _cycle_only, via_plc=True),
    Fault("hard limit switch", lambda r: r.board.force_limit_switch(0, True, False),
          lambda r: r.board.force_limit_switch(0, False, False), ServoFault.HARD_LIMIT, _everywhere),
    Fault("drive fault", lambda r: r.board.set_drive_fault(1, True), lambda r: r.board.set_drive_fault(1, False),
          ServoFault.DRIVE_FAULT, _everywhere),
    Fault("mains loss", lambda r: r.board.set_mains(False), lambda r: r.board.set_mains(True), ServoFault.MAINS,
          _everywhere, category0=True),
    Fault("PLC link cut", _plc_cut, _revive_plc, ServoFault.PLC_LINK, _everywhere, via_plc=True),
    Fault("PLC link process hung", lambda r: setattr(r.alive, "plc_link", False), _revive_plc, ServoFault.PLC_LINK,
          _everywhere, via_plc=True),
    Fault("PLC link killed mid-write", lambda r: (setattr(r.alive, "plc_link", False), r.kill_mid_write("plc", Proc.PLC_LINK)),
          _revive_plc, ServoFault.PLC_LINK, _everywhere, via_plc=True),
    Fault("pump fault", lambda r: r.set_plc_input(pump_fault=1.0), lambda r: r.set_plc_input(pump_fault=0.0),
          ServoFault.PUMP, _everywhere, via_plc=True),
    Fault("pump pressure drop", lambda r: r.set_plc_input(pump_pressure=500.0),
          lambda r: r.set_plc_input(pump_pressure=CONFIG.pump.cut_pressure_bar), ServoFault.PUMP, _jet_cut_only, via_plc=True),
    Fault("following error (friction x400)", lambda r: r.board.set_friction_scale(0, 400.0),
          lambda r: r.board.set_friction_scale(0, 1.0), ServoFault.FOLLOWING_ERROR, _moving_only),
    Fault("planner hung or killed (FIFO underrun)", lambda r: setattr(r.alive, "planner", False),
          lambda r: setattr(r.alive, "planner", True), ServoFault.UNDERRUN, _moving_only),
    Fault("logic hung", lambda r: setattr(r.alive, "commander", False), _revive_commander, ServoFault.COMMANDER, _everywhere),
    Fault("logic killed mid-write", lambda r: (setattr(r.alive, "commander", False), r.kill_mid_write("command", Proc.LOGIC)),
          _revive_commander, ServoFault.COMMANDER, _everywhere),
    Fault("control program raises", _law(_raises), _law(None), ServoFault.CONTROL_PROGRAM, _everywhere),
    Fault("control program returns NaN", _law(_nan), _law(None), ServoFault.CONTROL_PROGRAM, _everywhere),
    Fault("control program over its budget", _law(_spins), _law(None), ServoFault.CONTROL_PROGRAM, _everywhere),
    Fault("servo hung", lambda r: setattr(r.alive, "servo", False), _revive_servo, ServoFault.WATCHDOG, _everywhere),
    Fault("servo killed mid-write", lambda r: (setattr(r.alive, "servo", False), r.kill_mid_write("servo", Proc.SERVO)),
          _revive_servo, ServoFault.WATCHDOG, _everywhere),
]
CELLS = [(s, f) for s in STATES for f in FAULTS]


@dataclass
class Cell:
    state: str
    fault: str
    jet_ticks: str  # board ticks from the tick that acted on the cause to the jet closed ("-": it was closed)
    detect_ticks: int  # ticks from the cause (at the board, in the PLC's image, a process falling silent) to that tick
    speed_mm_s: float
    stop_mm: float
    bound_mm: float | None  # None: category 0 (coasting)
    trip: str
    alarm: str
    recovered: bool
    note: str = ""


def _run_cell(state: State, fault: Fault) -> Cell:
    with Rig(state.config) as rig:
        state.enter(rig)
        jet_was = rig.jet[-1]
        injected = rig.tick
        fault.inject(rig)
        start = len(rig.positions) - 1
        speed = rig.speed_mm_s()
        lost_at = getattr(rig, "lost_at", None)
        reset_tried = False
        for _ in range(4000):
            rig.step()
            if lost_at is not None and rig.tick == lost_at:
                rig.plc.set("state", int(LinkState.LOST))
                rig.plc.publish()
            s = rig.servo_block()
            if s["state"] == ServoState.STOPPING and not reset_tried and s["brake_distance_mm"] > 0.0:
                # an operator pressing reset while the axes still run out the stop: nothing may change
                reset_tried = True
                rig.reset()
                rig.step()
                assert rig.servo_block()["state"] == ServoState.STOPPING, "a reset during the stop changed it"
                assert not rig.jet[-1], "a reset during the stop opened the jet"
            if rig.hw_block()["braking"] and not reset_tried:
                reset_tried = True
                rig.reset()
                rig.step()
                assert rig.hw_block()["watchdog_tripped"] and not rig.jet[-1], "a reset during the ramp changed it"
            if s["state"] == ServoState.FAULT and rig.speed_mm_s() < 0.5 and not rig.hw_block()["braking"]:
                break
            if not rig.alive.servo and rig.hw_block()["safe_state"] and rig.speed_mm_s() < 0.5:
                break
        rig.step(20)
        s, hw = rig.servo_block(), rig.hw_block()
        cause = injected + 1  # the first image that can show it: the board's next sample, the PLC's next block
        watchdog = fault.trip == ServoFault.WATCHDOG
        trip = ServoFault.WATCHDOG if watchdog and hw["watchdog_tripped"] else (
            ServoFault(s["fault"]) if s["state"] == ServoState.FAULT else ServoFault.NONE)
        acted = hw["watchdog_trip_tick"] if watchdog else s["fault_tick"]
        detect = acted - cause
        path = rig.positions[start:]
        stop_mm = sum(math.dist(a, b) for a, b in zip(path, path[1:]))
        # a head speeding up (out of a corner) runs faster by the reaction than at the cause, and a
        # jerk-limited stop must first take its acceleration out: the bound is taken from the
        # speed it then reaches (the same as at the cause where it cruises)
        speeds = [math.dist(a, b) / DT for a, b in zip(path, path[1:])]
        k = min(max(acted - injected, 0), len(speeds) - 1)
        speeding_up = max(speeds[k] - speeds[k - 1], 0.0) / DT if k >= 1 else 0.0
        reached = max([speed] + speeds[:k + 1]) + speeding_up**2 / (2.0 * J)
        speed = reached
        bound = None if fault.category0 else (
            stop_distance_bound_mm(reached, max(detect, 0) * DT, A, J) + reached * speeding_up / J)
        jet_ticks = "-"
        if jet_was:
            jet_ticks = str(hw["jet_off_tick"] - acted) if not rig.jet[-1] else "OPEN"
        elif any(rig.jet[start:]):
            jet_ticks = "OPENED"
        alarm_id = fault_alarm(trip, CONFIG.axis_names, s["trip_axis"]) if trip != ServoFault.NONE else "-"
        # recovery: the fault goes, the processes come back, a reset, and the machine moves again
        fault.clear(rig)
        if not rig.alive.servo:
            _revive_servo(rig)
        rig.step(rig.plc_ticks * 2 if fault.via_plc else 5)  # the PLC's next image, for what it reports
        rig.reset()
        rig.step(5)
        recovered = rig.servo_block()["state"] == ServoState.HOLDING and not rig.hw_block()["watchdog_tripped"]
        if recovered:
            here = rig.servo_block()["commanded_mm"][0]
            target = here + 2.0 if here < 1500.0 else here - 2.0
            rig.jog(0, 50.0, target)
            rig.run_until(lambda: rig.feeder.runner.finished and rig.fifo.fill() == 0, 2000, "a move after the reset")
            rig.step(30)
            after = rig.servo_block()
            recovered = after["state"] == ServoState.HOLDING and abs(after["actual_mm"][0] - target) < 0.05
        return Cell(state.name, fault.name, jet_ticks, detect, speed, stop_mm, bound, trip.name,
                    alarm_id, recovered, "" if fault.trip == trip else f"expected {fault.trip.name}")


NOT_APPLICABLE: list[tuple[str, str, str]] = []


@pytest.mark.parametrize(("state", "fault"), CELLS, ids=[f"{s.name}-{f.name}" for s, f in CELLS])
def test_the_fault_closes_the_jet_in_a_tick_stops_within_the_bound_latches_and_a_reset_recovers(state, fault):
    why_not = fault.applies(state)
    if why_not:
        NOT_APPLICABLE.append((state.name, fault.name, why_not))
        SAFETY_MATRIX.append(Cell(state.name, fault.name, "n/a", 0, 0.0, 0.0, 0.0, "n/a", why_not, True))
        return
    cell = _run_cell(state, fault)
    SAFETY_MATRIX.append(cell)
    assert cell.trip == fault.trip.name, f"tripped {cell.trip}, expected {fault.trip.name}"
    assert cell.jet_ticks in ("-", "0", "1"), f"jet: {cell.jet_ticks}"
    if cell.bound_mm is not None:
        assert cell.stop_mm <= cell.bound_mm, f"stopped after {cell.stop_mm:.2f} mm, bound {cell.bound_mm:.2f} mm"
    assert cell.recovered, "reset + move again"


@pytest.mark.parametrize("feed", [50.0, 500.0])
def test_override_0_while_cutting_holds_on_the_path_and_the_jet_closes_at_rest_until_an_explicit_resume(feed):
    """A feed hold, not a standstill with the jet open: the cut goes on while the head decelerates
    (resume leaves no gap), the jet closes the tick the head is at rest, raising the override does
    not restart it, resume pierces again (on delay, pierce dwell) and goes on."""
    state = next(s for s in STATES if s.name == f"cutting {feed:g} mm/s")
    with Rig(CONFIG) as rig:
        state.enter(rig)
        runner = rig.feeder.runner
        start, speed = len(rig.positions) - 1, rig.speed_mm_s()
        runner.set_override(0.0)  # what the planner does with Override(0)
        assert runner.state == RunState.HOLDING
        rig.run_until(lambda: runner.state == RunState.HELD and rig.fifo.fill() == 0 and rig.speed_mm_s() < 0.5, 3000,
                      "the hold")
        rig.run_until(lambda: not rig.jet[-1], 50, "the jet to close at rest")
        rest = next(k for k in range(start, len(rig.jet)) if all(
            math.dist(rig.positions[j], rig.positions[j - 1]) < 0.5 * DT for j in range(k, len(rig.jet))))
        jet_off = rig.jet.index(False, start)
        assert jet_off - rest <= 1, "the jet closed within a tick of the head coming to rest"
        path = rig.positions[start:]
        stop_mm = sum(math.dist(a, b) for a, b in zip(path, path[1:]))
        fifo_lead_mm = speed * CONFIG.planner.fifo_high_ms / 1000.0
        bound = stop_distance_bound_mm(speed, 0.0, A, J) + fifo_lead_mm
        SAFETY_MATRIX.append(Cell(state.name, "feed override 0 %", str(max(0, jet_off - rest)), 0, speed, stop_mm, bound,
                                  "NONE (held)", "feed_hold", True, "jet counted from rest; bound adds the FIFO lead"))
        assert stop_mm <= bound
        runner.set_override(1.0)
        rig.step(300)
        assert not any(rig.jet[-300:]) and runner.state == RunState.HELD, "the override alone restarts nothing"
        runner.resume()
        rig.run_until(lambda: rig.jet[-1], 100, "the re-pierce")
        rig.run_until(lambda: rig.speed_mm_s() > 0.9 * feed, 3000, "the cut going on")
        assert rig.servo_block()["state"] == ServoState.TRACKING


def test_a_servo_restarted_before_the_hardware_server_saw_its_loss_still_gets_the_ramp_from_full_speed():
    """The supervisor asks for the safe state and starts a new servo; the new one (drives off, speed
    0) may publish before the hardware server's next tick. The hardware server's ramp starts from
    what it last gave the board, not from that block: the axes are braked, not left to coast."""
    with Rig(CONFIG) as rig:
        _cut(500.0)(rig)
        start, speed = len(rig.positions) - 1, rig.speed_mm_s()
        rig.alive.servo = False  # killed between two ticks
        sup = rig.area.writer("supervisor")
        sup.load_current()
        sup.set("safe_state", 1)
        sup.publish()
        _revive_servo(rig)
        rig.servo.tick()  # its first tick comes before the hardware server's next: tripped RESTARTED, drives off
        assert rig.servo_block()["drive_enable_mask"] == 0 and not any(rig.servo_block()["speed_cmd_v"])
        rig.step(1)
        assert rig.hw_block()["braking"], "the ramp began"
        rig.run_until(lambda: rig.hw_block()["safe_state"] and rig.speed_mm_s() < 0.5, 2000, "the ramp to run out")
        path = rig.positions[start:]
        stop_mm = sum(math.dist(a, b) for a, b in zip(path, path[1:]))
        assert stop_mm <= stop_distance_bound_mm(speed, DT, A, J), f"{stop_mm:.2f} mm from {speed:.0f} mm/s"


def test_a_reset_pressed_while_the_supervisor_still_holds_the_board_safe_waits_and_then_clears_the_restart():
    """The servo killed mid-cut and restarted (tripped RESTARTED), the operator's reset pressed at once,
    while the supervisor still holds the board safe (it gives it back only once the new servo runs):
    the reset waits, and clears the restart's trip when the board is given back. It used to be
    taken and clear nothing (the board safe), the machine left tripped until a second reset."""
    with Rig(CONFIG) as rig:
        _cut(500.0)(rig)
        rig.alive.servo = False
        sup = rig.area.writer("supervisor")
        sup.load_current()
        sup.set("safe_state", 1)
        sup.publish()
        _revive_servo(rig)
        rig.run_until(lambda: rig.hw_block()["safe_state"] and rig.speed_mm_s() < 0.5, 2000, "the ramp to run out")
        assert ServoFault(rig.servo_block()["fault"]) == ServoFault.RESTARTED
        rig.reset()
        rig.step(20)
        assert rig.servo_block()["state"] == ServoState.FAULT, "the board still held safe: nothing cleared yet"
        assert rig.hw_block()["reset_seq"] < rig.command.get("reset_seq"), "the reset waits"
        sup.set("safe_state", 0)  # the supervisor gives the board back
        sup.publish()
        rig.step(2)
        assert rig.servo_block()["state"] != ServoState.FAULT and ServoFault(rig.servo_block()["fault"]) == ServoFault.NONE


def test_an_axis_that_cannot_follow_the_stop_loses_its_drive_and_the_others_still_brake_under_control():
    """A diagonal cut at 500 mm/s, X seized (friction x400): the following error trips, and X cannot
    follow the servo's own stop either. Its drive goes off; Y goes on braking along the stop's path
    and comes to rest within the bound of the head's speed. (All drives went off before: Y
    coasted, 30 mm and more at a corner.)"""
    with Rig(CONFIG) as rig:
        rig.set_command(arm=int(StopCause.BARRIER), pressure_floor_bar=FLOOR_BAR)
        rig.run_program("G21 G90 G64 P0.05\nM3\nG1 X900 Y900 F30000\nM5\nM2\n")
        rig.run_until(lambda: rig.speed_mm_s() > 0.99 * 500.0 and rig.jet[-1], 5000, "cutting diagonally at 500 mm/s")
        start, injected = len(rig.positions) - 1, rig.tick
        speed = rig.speed_mm_s()
        rig.board.set_friction_scale(0, 400.0)
        masks = []
        for _ in range(4000):
            rig.step()
            masks.append(rig.servo_block()["drive_enable_mask"])
            if rig.servo_block()["state"] == ServoState.FAULT and rig.speed_mm_s() < 0.5:
                break
        s = rig.servo_block()
        assert ServoFault(s["fault"]) == ServoFault.FOLLOWING_ERROR and not rig.jet[-1]
        assert 0b10 in masks, "Y's drive on, X's off, while Y brakes"
        detect = s["fault_tick"] - (injected + 1)
        travel_y = abs(rig.positions[-1][1] - rig.positions[start][1])
        # the stop brakes along the path (Y's share of it): within the path's bound from the head's speed
        assert travel_y <= stop_distance_bound_mm(speed, detect * DT, A, J), f"Y ran {travel_y:.2f} mm from {speed:.0f} mm/s"
        rig.board.set_friction_scale(0, 1.0)
        rig.step(5)
        rig.reset()
        rig.step(5)
        assert rig.servo_block()["state"] == ServoState.HOLDING, "a reset recovers"
