"""Shared fixtures: the shipped machine file on a free loopback port, and running controllers."""

from __future__ import annotations

import gc
import os
import socket
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from cnc.config import MachineConfig, load_machine
from cnc.runtime.supervisor import DIRECT_FEED, MOTION_ONLY, Supervisor
from cnc.sim.operator import logic_block, press_button_when_asked  # noqa: F401 - the scripted operator, for the tests

from . import lanes

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")  # Qt tests render without a display
# A test waits on events; its limits only say when to give up. Four times the written limits: a
# busy two-core host (a CI runner) never misses one, and a wait that succeeds returns as soon as it does.
Supervisor.wait_margin = 4.0

REPO = Path(__file__).resolve().parent.parent
MACHINE_FILE = REPO / "machines" / "waterjet.toml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


MID_TRAVEL = {"sim.axes.x.start_position_mm": 800.0, "sim.axes.y.start_position_mm": 600.0}


def machine_config(**overrides) -> MachineConfig:
    """The shipped machine on its own loopback port, the table switched on in the middle of its
    travel (tests have room to move either way), with optional dotted-key overrides. The program
    library's background checks are off (child processes competing for the 2 cores with the
    controller under test): the library's tests switch them on."""
    return load_machine(MACHINE_FILE, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **MID_TRAVEL,
                                       "gateway.library_checks": False, **overrides})


# The whole controller with the PLC simulator: a plant that moves fast, the table switched on near
# home (homing is short), and a slower, more patient PLC link: the virtual clock runs the controller
# flat out on this 2-core machine (about 3.4 ticks a wall millisecond) while the serial link lives in
# wall time, and must not be starved. The tick finds the PLC's inputs stale after (lost_after_cycles
# + 1) x timeout_ms of ticks, so with 3 x 250 ms a host that did not run the link's processes for a
# third of a second (it happened with nothing else running: the simulator 345 and 763 ms behind)
# tripped a test's cut, and one 763 ms behind lost the link (3 exchanges of 250 ms). 8 x 400 ms: the
# inputs stale after 3.6 s of ticks (about a wall second), the link lost after 3.2 s of failed
# exchanges. The link's own tests keep the shipped file's timing.
NEAR_HOME = {"sim.axes.x.start_position_mm": 30.0, "sim.axes.y.start_position_mm": 30.0,
             "plc.cycle_ms": 100.0, "plc.timeout_ms": 400.0, "plc.lost_after_cycles": 8}


# the Reaction of every fault injected through the real processes in this run: printed at its end
FAULT_REACTIONS: list = []
# the cells of the safety matrix (test_safety_matrix.Cell), printed at the end too
SAFETY_MATRIX: list = []


def pytest_configure(config) -> None:
    """`make test`'s computes lane (tests/lanes.py): idle priority and its own segment prefix
    (and, once the tests are collected, nothing that waits: `pytest_collection_finish`)."""
    if lanes.in_computes_lane():
        lanes.enter_computes_lane()


def pytest_collection_finish(session) -> None:
    if lanes.in_computes_lane():
        lanes.refuse_waiting()


def pytest_collection_modifyitems(config, items) -> None:
    lanes.last_the_alone(items)


@pytest.fixture(autouse=True)
def _alone_after_the_computes_lane(request):
    """A test marked `alone` starts once `make test`'s computes lane has ended (tests/lanes.py)."""
    if request.node.get_closest_marker(lanes.ALONE) is not None:
        lanes.await_the_computes_lane()
    yield


def pytest_terminal_summary(terminalreporter) -> None:
    if SAFETY_MATRIX:
        terminalreporter.section("safety matrix: every fault in every state (the tick rig: real hardware server, "
                                 "board and servo)")
        for line in matrix_table(SAFETY_MATRIX):
            terminalreporter.write_line(line)
    if FAULT_REACTIONS:
        from cnc.sim.faultinject import table

        terminalreporter.section("faults injected through the real processes (virtual clock)")
        terminalreporter.write_line(table(FAULT_REACTIONS))


def matrix_table(cells: list) -> list[str]:
    rows = [("state", "fault", "detect", "jet off", "v mm/s", "stop mm", "bound mm", "trip", "alarm", "reset+move")]
    for c in cells:
        if c.trip == "n/a":
            rows.append((c.state, c.fault, "-", "-", "-", "-", "-", "n/a", c.alarm, "-"))
            continue
        bound = "coast (cat. 0)" if c.bound_mm is None else f"{c.bound_mm:.2f}"
        rows.append((c.state, c.fault, str(c.detect_ticks), c.jet_ticks, f"{c.speed_mm_s:.0f}", f"{c.stop_mm:.2f}", bound,
                     c.trip + (f" ({c.note})" if c.note else ""), c.alarm, "ok" if c.recovered else "FAILED"))
    from cnc.sim.faultinject import text_table

    lines = text_table(rows)
    lines.append("detect: ticks (1 ms) from the cause (at the board, in the PLC's image, a process falling silent) to the "
                 "tick that acted; jet off: ticks from that tick to the board's jet valve closed ('-': it was closed); "
                 "bound: v T_detect + v^2/2a + v a/2j + 1 mm (v by the tick that acted; speeding up at a0 then: "
                 "v + a0^2/2j, and v a0/j more); n/a: the reason is in the alarm column")
    return lines


# The simulated PLC's CNC watchdog stops a moving transport when the CNC's heartbeat, written over
# the PLC link, has not changed for `watchdog_s` of wall time (1 s: a real PLC's). The controller tests
# give the link 3.2 s of failed exchanges (NEAR_HOME); with the watchdog at 1 s, a host that did not
# run the link's process for a second during an unload (the 1M-line upload of test_load.py being
# checked beside the cut) stopped the cycle with "PLC alarm 1". The tests' plant waits as long as
# their link does; the watchdog's own test (test_plc_sim.py) keeps its second.
PATIENT_WATCHDOG_S = 4.0


def fast_plant():
    import dataclasses

    from cnc.sim.faultinject import FAST_PLANT

    return dataclasses.replace(FAST_PLANT, watchdog_s=PATIENT_WATCHDOG_S)


@contextmanager
def full_controller(config: MachineConfig, history_path: Path):
    """Every controller process and the PLC simulator on the virtual clock, the PLC link up."""
    from cnc.data.layout import LinkState

    with Supervisor(config, clock="virtual", history_path=history_path, plc_sim_times=fast_plant()) as sup:
        sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 20.0, "the PLC link")
        yield sup


def reset_and_home(sup: Supervisor, request) -> None:
    """Reset (the drives come on a few ticks after the reply), then home once the servo holds:
    `request(msg)` sends a command and returns its Reply (an operator station's, or the logic's)."""
    from cnc.bus.messages import Home, Reset
    from cnc.data.layout import ServoState

    reply = request(Reset())
    assert reply.ok, reply.reason
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 10.0, "the drives on after the reset")
    reply = request(Home())
    assert reply.ok, reply.reason


logic = logic_block  # the control logic's block (mode, state, phase, cycles, procedure), as the tests name it


SHM = Path("/dev/shm")


@pytest.fixture(autouse=True, scope="session")
def _dev_shm_left_as_found(request):
    """No test leaves a file in /dev/shm: the controller's segments, a station's, Zenoh's own
    (its shared-memory transport is configured off in every session, `cnc.bus.session`).
    Checked once, at the end of the run: what is there then and was not at its start fails the
    run, named. Python's multiprocessing semaphores (`sem.mp-*`) are not counted here: their
    objects may outlive this check, and its resource tracker removes them when the test process
    ends (`make test` checks /dev/shm after it). Nor are the other lane's (tests/lanes.py), which
    `make test` checks once both have ended. After a failed test only a warning: its report keeps
    the test's objects alive past this check."""
    before = set(os.listdir(SHM)) if SHM.is_dir() else set()
    yield
    gc.collect()
    left = sorted(n for n in set(os.listdir(SHM)) - before
                  if not n.startswith("sem.mp-") and not lanes.other_lanes_segment(n)) if SHM.is_dir() else []
    if left and request.session.testsfailed:
        import warnings

        warnings.warn(f"a failed test left these in {SHM}: {left}")
        return
    assert not left, f"the tests left these in {SHM}: {left}"


@pytest.fixture(autouse=True, scope="module")
def _earlier_modules_objects_out_of_the_collectors_way():
    """What earlier modules left alive goes to the permanent generation, as the controller's
    processes do with theirs (cnc.runtime.rt): one test process accumulates it across the suite, and every
    full collection would scan it all again, the per-test collection below included. The tick rig's
    cells, CPU-bound and allocating, ran three times slower late in the suite than alone."""
    gc.collect()
    gc.freeze()
    yield


@pytest.fixture(autouse=True)
def _qt_garbage_collected_on_the_gui_thread():
    """After each test, collect garbage here, on the GUI thread: a Qt object left to the collector
    might otherwise be destroyed on some other thread later (a Zenoh callback's), and Qt crashes."""
    yield
    if "PySide6.QtCore" in sys.modules:
        gc.collect()


@pytest.fixture
def plc_controller(tmp_path):
    """The whole controller, PLC link and PLC simulator included, with a plant that moves fast."""
    with full_controller(machine_config(**NEAR_HOME), tmp_path / "history.sqlite") as sup:
        yield sup


@pytest.fixture
def library_controller(tmp_path):
    """The whole controller as `plc_controller`, with the program library's background checks on."""
    with full_controller(machine_config(**NEAR_HOME, **{"gateway.library_checks": True}), tmp_path / "history.sqlite") as sup:
        yield sup


@pytest.fixture
def machine() -> MachineConfig:
    return machine_config()


@pytest.fixture
def virtual_controller(machine):
    """The whole controller (the planner feeds the FIFO) on the virtual clock."""
    with Supervisor(machine, clock="virtual", processes=MOTION_ONLY) as sup:
        yield sup


@pytest.fixture
def direct_controller(machine):
    """The controller without a planner: the test feeds the FIFO itself (servo tests)."""
    with Supervisor(machine, clock="virtual", processes=DIRECT_FEED) as sup:
        yield sup


@pytest.fixture(scope="module")
def homed():
    """One motion controller (no control logic), homed, for a module's tests that leave it idle again."""
    config = machine_config(**{"sim.axes.x.start_position_mm": 30.0, "sim.axes.y.start_position_mm": 30.0})
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        home(sup)
        yield sup


@pytest.fixture
def realtime_controller(machine):
    with Supervisor(machine, clock="realtime", processes=MOTION_ONLY) as sup:
        yield sup


def feed(sup: Supervisor, setpoints: np.ndarray, timeout_s: float = 60.0) -> None:
    """Push all setpoints into the FIFO as space frees up, supervising meanwhile (no planner process:
    the FIFO has one producer)."""
    assert "planner" not in sup.process_names, "the planner process feeds this FIFO: start the controller with DIRECT_FEED"
    setpoints = setpoints.copy()
    setpoints["epoch"] = sup.servo()["motion_epoch"]  # the motion under way now: the servo drops any other
    pushed, deadline = 0, time.monotonic() + timeout_s
    while pushed < len(setpoints):
        pushed += sup.fifo.push(setpoints[pushed:])
        sup.poll()
        if time.monotonic() > deadline:
            raise TimeoutError(f"only {pushed} of {len(setpoints)} setpoints taken in {timeout_s} s")
        time.sleep(0.001)


def enable_and_hold(sup: Supervisor) -> list[float]:
    """Close the loop and wait until the servo holds; returns the held position."""
    from cnc.data.layout import ServoState

    sup.enable()
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 10.0, "the servo to hold position")
    return list(sup.servo()["commanded_mm"])


def ask(sup: Supervisor, command) -> None:
    """Send a command to the planner and insist it is accepted."""
    reply = sup.planner.request(command)
    assert reply.ok, reply.reason


def wait_planner_idle(sup: Supervisor, timeout_s: float = 120.0) -> dict:
    """Until the planner is idle again (homing, a program, a jog done); returns the motion block."""
    from cnc.data.layout import PlannerState

    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE, timeout_s, "the planner to be idle")
    return sup.motion()


def home(sup: Supervisor, axes: list[str] | None = None) -> None:
    """Home through the planner and wait until it is done; fails with the planner's error."""
    from cnc.bus.messages import Home

    errors = sup.motion()["error_seq"]
    ask(sup, Home(axes or []))
    m = wait_planner_idle(sup)
    assert m["error_seq"] == errors, m["error"]
