"""`waterjet demo`: the simulated machine end to end, with the operator screen when there is a display.

Starts the whole controller on the simulated board, with the PLC simulator on a pty pair
behind the PLC link, and a separate subscriber process that prints the status, the alarms
and the guided procedure it receives over Zenoh. Then it plays the operator: reset (drives
on), home in MANUAL, load a small nest of leather parts, switch to AUTO and start two
automatic cycles; the transport procedure asks for the transport-station button, which the
demo presses. Each cycle feeds material and closes the gripper (transport phase), ramps the
pump to its pierce pressure, cuts the nest (pierce low, cut high), and unloads. During the
second cut a safety door is opened (fault injection): the jet closes in the tick the servo sees
the door, the servo stops the axes on the path itself, alarm 2292 is raised; the door is closed,
the alarm reset, and one more cycle cut.
Finally it checks the history (every alarm stored, sequence numbers without a gap), that no
servo fault or FIFO underrun happened, and that no shared memory is left behind.

The program goes to the controller the way an operator station sends it (command lock, upload
over Zenoh). With a display, the operator screen (`waterjet hmi`) opens at the start and watches;
once the scripted part is over the machine is the operator's until the window is closed (a
helper presses the transport-station button when the procedure asks). Without one, the operator
screen is rendered headless once, at the end, to a PNG.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

from ..alarms import AlarmHistory
from ..bus.keys import Keys
from ..bus.messages import (
    AlarmEvent, CycleStart, Home, ProcedureState, Reset, SetMode, Status, decode,
)
from ..bus.operator import OperatorStation
from ..bus.session import connect_endpoints, open_client
from ..config import load_machine
from ..hw.board import DigitalOut
from ..data.layout import PlannerState, RunResult, ServoState
from ..logic.states import CyclePhase, MachineState
from ..runtime.supervisor import Supervisor, SupervisorError
from .operator import ScriptError, ask, logic_block, press_button_when_asked, reset_until_clear

POSITION_TOLERANCE_MM = 0.005


def demo_program() -> str:
    """Two leather parts and a polyline strap, cut with pierces and lead-ins, then park."""
    strap = "\n".join(
        f"G1 X{600 + 2.0 * k:.3f} Y{400 + 30.0 * math.sin(k / 8.0):.3f}" for k in range(1, 101)
    )
    return f"""(waterjet demo: two parts and a strap)
G21 G90 G17
G64 P0.05
F6000
G0 X210 Y150
M3                               (pierce)
G1 X220 Y150                     (lead-in)
G1 X380 Y150
G3 X400 Y170 R20
G1 X400 Y280
G3 X380 Y300 R20
G1 X220 Y300
G3 X200 Y280 R20
G1 X200 Y170
G3 X220 Y150 R20
M5
G0 X480 Y200
M3
G2 X480 Y200 I40 J0              (a round part)
M5
G0 X600 Y400
M3
{strap}
M5
G0 X50 Y50
M2
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def print_status(endpoint: str, prefix: str, machine: str, stop, ready, counter, alarms) -> None:
    """Subscriber process: print about one status message a second, and every alarm and procedure
    change, as received over Zenoh."""
    import threading

    session = open_client([endpoint])
    keys = Keys(prefix, machine)
    got_one = threading.Event()

    def on_status(sample) -> None:
        st: Status = decode(sample.payload.to_bytes(), Status)
        with counter.get_lock():
            counter.value += 1
            n = counter.value
        got_one.set()
        if n % 20 == 1:
            pos = "  ".join(f"{a.name.upper()} {a.position_mm:8.2f}" for a in st.axes)
            prog = st.program
            where = f"line {prog.line:4d} {100 * prog.progress:5.1f}% ETA {prog.eta_s:5.1f}s" if prog and prog.segment >= 0 else ""
            print(
                f"[subscriber] #{st.seq:<4} {st.mode:<6} {st.machine_state:<8} {st.cycle_phase:<9} {pos}"
                f"  F {st.feed_commanded_mm_s:6.1f} mm/s  jet {'ON ' if st.jet_on else 'off'}"
                f"  pump {st.pump_pressure_bar:6.0f} bar  PLC {st.plc_link} {where}",
                flush=True,
            )

    def on_alarm(sample) -> None:
        ev: AlarmEvent = decode(sample.payload.to_bytes(), AlarmEvent)
        with alarms.get_lock():
            alarms.value += 1
        print(f"[subscriber] alarm #{ev.seq} {ev.action:<9} {ev.code:5d} {ev.level:<7} {ev.text}: {ev.detail}", flush=True)

    def on_procedure(sample) -> None:
        p: ProcedureState = decode(sample.payload.to_bytes(), ProcedureState)
        if p.id and 0 <= p.step < len(p.steps):
            print(f"[subscriber] procedure {p.title}: step {p.step + 1}/{len(p.steps)} {p.steps[p.step].text!r}: "
                  f"{p.instruction}", flush=True)
        elif p.id:
            print(f"[subscriber] procedure {p.title}: {p.state}", flush=True)

    subs = [session.declare_subscriber(keys.status, on_status), session.declare_subscriber(keys.event_alarm, on_alarm),
            session.declare_subscriber(keys.procedure, on_procedure)]
    if got_one.wait(15.0):
        ready.set()
    stop.wait(600.0)
    for sub in subs:
        sub.undeclare()
    session.close()


HOST_LATE_ALARMS = (1013, 1016)  # the drive watchdog, too many servo ticks late: the host did not run the servo in time


def run_demo(machine_path: str, clock: str = "realtime") -> int:
    """The demo on `clock`. On the real-time clock, where the host did not run the servo every
    period (a virtual machine, a kernel without PREEMPT_RT, a busy CPU: the controller then stops
    the cut safely, as it must, alarm 1013 or 1016), it says so and runs again on the virtual clock,
    whose ticks wait for the processes: what failed was the host, and the demo still shows the
    controller end to end. 0 when it behaved."""
    code, host_late = _demo(machine_path, clock)
    if code and host_late and clock == "realtime":
        print("demo: this host did not run the servo every millisecond (alarm 1013 or 1016 above): the controller "
              "stopped safely, as it must on a machine; it is not a real-time host (a PREEMPT_RT kernel and an idle "
              "CPU are: README, Faults, networks and bad input). The demo runs again on the virtual clock, whose "
              "ticks wait for every process.", flush=True)
        code, _ = _demo(machine_path, "virtual")
    return code


def _demo(machine_path: str, clock: str) -> tuple[int, bool]:
    """One run of the demo: its exit code, and whether the host ran the servo late enough to stop it."""
    from plc_link.sim_model import PlantTimes

    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    config = load_machine(machine_path, {"zenoh.listen": [endpoint]})
    ctx = multiprocessing.get_context("spawn")
    stop, ready, counter, alarms = ctx.Event(), ctx.Event(), ctx.Value("q", 0), ctx.Value("q", 0)
    print(f"demo: controller for {config.machine.name!r} on the {clock} clock, Zenoh at {endpoint}", flush=True)
    errors: list[str] = []
    names: set[str] = set()
    screen: subprocess.Popen | None = None
    with tempfile.TemporaryDirectory() as tmp:
        history = Path(tmp) / "history.sqlite"
        # a brisk transport system, so that the demo spends its time cutting
        sup = Supervisor(config, clock=clock, history_path=history,
                         plc_sim_times=PlantTimes(feed_s=1.0, gripper_s=0.3, unload_s=1.0))
        program = Path(tmp) / "demo_nest.ngc"
        program.write_text(demo_program())
        try:
            sup.start()
            names = {sup.area.shm.name, sup.fifo.shm.name, sup.trace.shm.name}
            print(f"demo: PLC simulator on {sup.plc_sim.device}; alarm history {history}", flush=True)
            subscriber = ctx.Process(
                target=print_status, args=(endpoint, config.zenoh.key_prefix, config.machine.name, stop, ready, counter, alarms)
            )
            subscriber.start()
            if _display():
                screen = subprocess.Popen(_hmi(endpoint, config, "--station", "operator"))
                print("demo: operator screen opened (waterjet hmi); it watches while the demo plays the operator",
                      flush=True)
            if not ready.wait(20.0):
                errors.append("the subscriber process received no status over Zenoh")
            errors += _run(sup, program)
            if not errors:  # the cycle's end is told off the scan (stored, then published): its entry follows in a moment
                sup.wait_until(lambda: _history_holds(history, 3001), 10.0, "the cycle's end in the alarm history")
            errors += _check_history(history)
            if screen is not None and screen.poll() is not None:
                print(f"demo: the operator screen could not open on this display (exit {screen.returncode}; its "
                      "messages are above); rendering it headless instead", flush=True)
                screen = None
            if screen is None:
                errors += _screen_headless(endpoint, config)
            elif not errors:
                _keep_running_with_screen(sup, screen)
            stop.set()
            subscriber.join(10.0)
            print(f"demo: the subscriber process received {counter.value} status messages and {alarms.value} alarm "
                  f"events over Zenoh", flush=True)
            if counter.value == 0:
                errors.append("no status message reached the subscriber")
        except (SupervisorError, ScriptError, TimeoutError) as exc:
            errors.append(str(exc))
        finally:
            stop.set()
            if screen is not None and screen.poll() is None:
                screen.terminate()
                screen.wait(10.0)
            sup.stop()
        host_late = bool(errors) and _raised(history, HOST_LATE_ALARMS)
    left = [n for n in names if os.path.exists(f"/dev/shm/{n}")]
    if left:
        errors.append(f"shared memory left behind: {', '.join(left)}")
    for e in errors:
        print(f"demo: FAILED: {e}", file=sys.stderr)
    if not errors:
        print("demo: OK: homed, automatic cycles cut, the door fault handled and reset, alarms stored and seen over Zenoh, "
              "shared memory freed", flush=True)
    return (1 if errors else 0), host_late


def _raised(path: Path, codes: tuple[int, ...]) -> bool:
    """Whether the history holds one of these alarms raised."""
    if not path.exists():
        return False
    with AlarmHistory(path, readonly=True) as history:
        return any(e.code in codes and e.action == "raised" for e in history.after(0, 1000).entries)


HOMING_ATTEMPTS = 3


def _home(sup: Supervisor) -> None:
    """Reset and home, as an operator would: on a busy host the PLC link may come up late, or miss
    its answers for a moment during the homing (a safe stop that ends it): then reset and home
    again, `HOMING_ATTEMPTS` times at most."""
    everything = (1 << len(sup.config.axis_names)) - 1
    for attempt in range(1, HOMING_ATTEMPTS + 1):
        reset_until_clear(sup)
        ask(sup, Home(), "home")
        sup.wait_until(lambda: logic_block(sup)["state"] == MachineState.FAULT
                       or (logic_block(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE),
                       120.0, "homing")
        if logic_block(sup)["state"] == MachineState.READY and sup.servo()["homed_mask"] & everything == everything:
            return
        why = logic_block(sup)["message"] or "not every axis homed"
        print(f"demo: homing {attempt} of {HOMING_ATTEMPTS} did not end homed ({why}); reset and home again", flush=True)
    raise ScriptError(f"homing did not end homed in {HOMING_ATTEMPTS} attempts")


def _run(sup: Supervisor, program: Path) -> list[str]:
    """Reset, home, load, two automatic cycles with a door opened in the second, reset, one more."""
    _home(sup)
    print(f"demo: homed; X {sup.servo()['actual_mm'][0]:.3f} Y {sup.servo()['actual_mm'][1]:.3f}", flush=True)
    _upload(sup, program)
    sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 120.0, "the cycle time to be planned")
    m = sup.motion()
    print(f"demo: loaded {m['program_name']}: {m['program_lines']} lines, {m['total_mm']:.0f} mm of path, "
          f"planned cycle time {m['planned_s']:.2f} s", flush=True)
    ask(sup, SetMode("AUTO"), "AUTO mode")
    ask(sup, CycleStart(cycles=2), "cycle start")
    print("demo: cycle start, 2 cycles", flush=True)
    t0, runs = sup.hw()["tick"], sup.motion()["run_seq"]

    def second_cut_under_way() -> bool:
        m = sup.motion()
        return (m["run_seq"] == runs + 2 and m["state"] == PlannerState.RUNNING and m["done_mm"] > 0.3 * m["total_mm"]
                and bool(sup.hw()["digital_out"] & DigitalOut.JET_VALVE))

    press_button_when_asked(sup, second_cut_under_way, 300.0, "the second cut")
    print("demo: opening a safety door during the second cut", flush=True)
    sup.set_sim(doors_open=1)
    sup.wait_until(lambda: logic_block(sup)["state"] == MachineState.FAULT and sup.motion()["state"] == PlannerState.IDLE
                   and sup.servo()["state"] == ServoState.FAULT, 30.0, "the safe stop")
    errors = []
    if sup.hw()["digital_out"] & DigitalOut.JET_VALVE:
        errors.append("the jet is open after the door fault")
    hw, s = sup.hw(), sup.servo()
    print(f"demo: the jet closed {hw['jet_off_tick'] - s['fault_tick']} tick(s) after the servo saw the door; it stopped "
          f"the axes on the path from {s['trip_speed_mm_s']:.0f} mm/s in {s['brake_distance_mm']:.2f} mm; state "
          f"{MachineState(logic_block(sup)['state']).name}; closing the door, reset", flush=True)
    sup.set_sim(doors_open=0)
    sup.wait_until(lambda: sup.logic.request(Reset()).reason == "", 10.0, "a clean reset")
    sup.wait_until(lambda: logic_block(sup)["state"] == MachineState.READY, 10.0, "READY after the reset")
    ask(sup, CycleStart(cycles=1), "cycle start")
    press_button_when_asked(
        sup, lambda: sup.motion()["run_seq"] == runs + 3 and logic_block(sup)["phase"] == CyclePhase.NONE, 300.0,
        "the cycle after the reset")
    m, s = sup.motion(), sup.servo()
    took = (sup.hw()["tick"] - t0) * sup.config.timing.period_s
    print(
        f"demo: cycles ended ({RunResult(m['run_result']).name}) after {took:.2f} s machine time; max following error "
        f"{max(s['max_following_error_mm']) * 1000:.1f} um; underruns {s['underruns']}, overruns {s['overruns']}; "
        f"lowest FIFO fill {m['fifo_min_fill']}",
        flush=True,
    )
    if m["run_result"] != RunResult.DONE:
        errors.append(f"the last program run did not end: {RunResult(m['run_result']).name} {m['error']}")
    if s["fault"]:
        errors.append(f"servo fault {s['fault']}")
    if s["underruns"]:
        errors.append(f"{s['underruns']} FIFO underruns")
    if not errors:  # a run that did not end stopped the head where it was: nothing to settle, and these say why
        sup.wait_until(lambda: all(abs(p - 50.0) <= POSITION_TOLERANCE_MM for p in sup.servo()["actual_mm"]), 5.0,
                       "the table to settle at the program's end X50 Y50")
    return errors


def _upload(sup: Supervisor, program: Path) -> None:
    """Send the program the way an operator station does (command lock, upload over Zenoh), so that
    the operator screen gets its interpreted path for the contour; then hand the lock back."""
    session = open_client(connect_endpoints(sup.config.zenoh.listen))
    station = OperatorStation(session, sup.keys, "demo")
    try:
        for what, reply in (("take the command lock", lambda: station.take_lock()),
                            ("upload", lambda: station.upload(program.name, program.read_text())),
                            ("release the command lock", lambda: station.release_lock())):
            answer = reply()
            if not answer.ok:
                raise SupervisorError(f"{what} refused: {answer.reason}")
    finally:
        station.close()
        session.close()
    sup.wait_until(lambda: sup.motion()["program_name"] == program.name, 10.0, "the uploaded program to be loaded")


def _hmi(endpoint: str, config, *options: str) -> list[str]:  # noqa: ANN001 - a MachineConfig
    """The command line of `waterjet hmi` on this controller."""
    return [sys.executable, "-m", "cnc.cli", "hmi", "--connect", endpoint, "--machine", config.machine.name,
            "--prefix", config.zenoh.key_prefix, *options]


def _display() -> bool:
    """A screen to open the operator screen on (an explicitly offscreen Qt platform is none)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) and \
        os.environ.get("QT_QPA_PLATFORM", "") != "offscreen"


def _screen_headless(endpoint: str, config) -> list[str]:  # noqa: ANN001 - a MachineConfig
    """Render the operator screen once without a display, as `waterjet hmi --screenshot` does."""
    out = Path(tempfile.gettempdir()) / "waterjet-demo-hmi.png"
    try:
        res = subprocess.run(_hmi(endpoint, config, "--station", "demo-screen", "--screenshot", str(out)),
                             capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        return ["the operator screen did not render within 120 s"]
    if res.returncode != 0:
        return [f"the operator screen failed to render: {res.stderr.strip()[-500:]}"]
    print(f"demo: operator screen rendered headless to {out} ({res.stdout.strip().rsplit('(', 1)[-1]}", flush=True)
    return []


def _keep_running_with_screen(sup: Supervisor, screen: subprocess.Popen) -> None:
    """Leave the machine to the operator at the screen until its window is closed; a helper at the
    transport station presses its button whenever the transport procedure asks for it."""
    print("demo: the operator screen is yours: take the command lock to run cycles (the transport-station "
          "button is pressed for you); close the window to end the demo", flush=True)

    def done() -> bool:
        lo = logic_block(sup)
        if lo["procedure"] == "transport" and lo["procedure_state"] in ("running", "timed_out"):
            sup.plc_sim.press_button()
        return screen.poll() is not None

    sup.run(done)


def _history_holds(path: Path, code: int) -> bool:
    with AlarmHistory(path, readonly=True) as history:
        return any(e.code == code for e in history.after(0, 1000).entries)


def _check_history(path: Path) -> list[str]:
    """Every alarm in the history, in sequence without a gap, the door fault raised, cleared and reset."""
    with AlarmHistory(path, readonly=True) as history:
        entries = history.after(0, 1000).entries
    seqs = [e.seq for e in entries]
    print(f"demo: history: {len(entries)} entries, sequence {seqs[0] if seqs else '-'}..{seqs[-1] if seqs else '-'}", flush=True)
    errors = []
    if seqs != list(range(1, len(seqs) + 1)):
        errors.append(f"history sequence numbers have gaps: {seqs}")
    door = [e.action for e in entries if e.code == 2292]
    if door != ["raised", "cleared", "reset"]:
        errors.append(f"door alarm 2292 in the history: {door}, expected raised, cleared, reset")
    if not any(e.code == 3001 for e in entries):
        errors.append("no 'automatic cycle finished' message in the history")
    return errors
