"""Supervisor: watches its processes, restarts what may be restarted, and leaves no shared memory behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cnc.runtime.rt import VIRTUAL_NICE, WALL_TIME_NICE
from cnc.runtime.supervisor import MOTION_ONLY, Supervisor

from . import lanes
from .conftest import MACHINE_FILE, REPO, enable_and_hold, free_port, machine_config

SHM = Path("/dev/shm")


def _ours() -> set[str]:
    return {p.name for p in SHM.glob("wjcnc_waterjet_*")}


def test_stop_frees_every_shared_memory_segment_and_the_plc_simulator(machine, tmp_path):
    before = _ours()
    sup = Supervisor(machine, clock="virtual", history_path=tmp_path / "h.sqlite").start()
    names = {sup.area.shm.name, sup.fifo.shm.name, sup.trace.shm.name}
    assert names <= _ours()
    sim, link = sup.plc_sim.process, sup.plc_sim_link
    assert os.path.realpath(link).startswith("/dev/pts/"), "the PLC link opens the simulator's pty"
    sup.stop()
    assert not names & _ours() and _ours() <= before
    assert not sim.is_alive() and not os.path.exists(link)


def test_on_the_virtual_clock_the_lockstep_processes_step_aside_for_those_with_wall_clock_deadlines(machine, tmp_path):
    """The hardware server, servo, planner and logic hand ticks to each other as fast as the CPUs
    allow (machine time waits for a busy host); the PLC link and its simulator, the gateway and the
    stations answer within wall-clock timeouts. At equal shares with them, three demos at once on
    2 CPUs all lost their PLC links (docs/benchmarks.md); the logger stays lowest. The PLC link
    steps up where the host lets it: at nice 0 beside fifty observers and a test's other work its
    input image once went a second without a refresh (`rt.step_up_for_wall_time`)."""
    base = os.getpriority(os.PRIO_PROCESS, 0)
    with Supervisor(machine, clock="virtual", history_path=tmp_path / "h.sqlite") as sup:
        nice = {name: os.getpriority(os.PRIO_PROCESS, child.process.pid) - base for name, child in sup.children.items()}
        nice["plc simulator"] = os.getpriority(os.PRIO_PROCESS, sup.plc_sim.process.pid) - base
    assert VIRTUAL_NICE > 0
    simulator, link = nice.pop("plc simulator"), nice.pop("plc_link")
    assert simulator in (-10, 0), "the simulator stands for a PLC with a CPU of its own: first where the host lets it"
    assert WALL_TIME_NICE < 0 and link == (WALL_TIME_NICE if simulator else 0) and simulator <= link
    assert nice == {"hardware": VIRTUAL_NICE, "servo": VIRTUAL_NICE, "planner": VIRTUAL_NICE, "logic": VIRTUAL_NICE,
                    "gateway": 0, "logger": 10}, nice


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_waterjet_up_stops_in_order_on_signal_and_leaves_no_shared_memory(sig, tmp_path):
    before, everything = _ours(), set(os.listdir(SHM))
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "cnc.cli", "up", "--machine", str(MACHINE_FILE), "--clock", "virtual",
         "--listen", f"tcp/127.0.0.1:{port}"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "XDG_STATE_HOME": str(tmp_path)},  # the alarm history goes here
    )
    try:
        line = proc.stdout.readline()
        assert "running on the virtual clock" in line, line + proc.stderr.read()
        created = _ours() - before
        assert len(created) == 3, created  # the data area, the setpoint FIFO and the trace ring
        proc.send_signal(sig)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not created & _ours(), f"left in /dev/shm: {created & _ours()}"
    now = {n for n in os.listdir(SHM) if not lanes.other_lanes_segment(n)}  # the computes lane's come and go meanwhile
    assert now <= everything, "nothing else either (Zenoh's own segments: its shared memory is off)"
    assert "stopping" in proc.stderr.read()
    assert (tmp_path / "waterjet" / "waterjet" / "history.sqlite").exists(), "the control logic kept its history"


def test_killing_the_supervisor_ends_every_controller_process_and_the_plc_simulator(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "cnc.cli", "up", "--machine", str(MACHINE_FILE), "--clock", "virtual",
         "--listen", f"tcp/127.0.0.1:{free_port()}"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        env={**os.environ, "XDG_STATE_HOME": str(tmp_path)},
    )
    try:
        assert "running on the virtual clock" in proc.stdout.readline()
        children = _descendants(proc.pid)  # its processes, the resource tracker, and what they started
        assert len(children) >= 8, children  # hardware, servo, gateway, planner, logic, PLC link, simulator...
        proc.kill()  # no chance to stop anything in order
        proc.wait(10)
        deadline = time.monotonic() + 60.0
        while (alive := [p for p in children if os.path.exists(f"/proc/{p}") and _state(p) != "Z"]) \
                and time.monotonic() < deadline:
            time.sleep(0.1)
        assert alive == [], "orphaned controller processes"
    finally:
        if proc.poll() is None:
            proc.kill()


def _descendants(pid: int) -> list[int]:
    found, todo = [], [pid]
    while todo:
        kids = [int(p) for p in subprocess.run(["pgrep", "-P", str(todo.pop())], capture_output=True,
                                               text=True).stdout.split()]
        found += kids
        todo += kids
    return found


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


def test_waterjet_up_refuses_a_bad_machine_file_naming_the_key(tmp_path):
    before = _ours()
    bad = tmp_path / "bad.toml"
    bad.write_text(MACHINE_FILE.read_text().replace("following_error_limit_mm = 0.5", "following_error_limit_mm = -1", 1))
    res = subprocess.run(
        [sys.executable, "-m", "cnc.cli", "up", "--machine", str(bad)], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 2
    assert f"{bad}: [axis.x] following_error_limit_mm: -1.0 is out of range: allowed 0.001 to 100 mm" in res.stderr
    assert _ours() <= before, "nothing was started"


def test_a_dead_gateway_is_restarted_and_status_resumes(virtual_controller):
    sup = virtual_controller
    old = sup.children["gateway"].process.pid
    os.kill(old, signal.SIGKILL)
    sup.wait_until(lambda: "gateway" in sup.children and sup.children["gateway"].process.pid != old, 30.0, "a new gateway")
    assert any("gateway process exited with code -9" in e for e in sup.events)
    beat = sup._beats[3]
    sup.wait_until(lambda: sup._beats[3] > beat + 2, 10.0, "the new gateway's heartbeat")
    assert sup.failed is None


def test_a_hung_process_is_found_by_its_heartbeat_and_replaced_but_a_paused_clock_is_no_hang():
    config = machine_config(**{"supervisor.heartbeat_timeout_s": 0.5})
    with Supervisor(config, clock="virtual", processes=MOTION_ONLY) as sup:
        sup.pause_virtual_clock()  # the servo and the hardware server beat once a tick: now they do not
        deadline = time.monotonic() + 1.5
        while time.monotonic() < deadline:
            sup.poll()
            time.sleep(0.01)
        sup.resume_virtual_clock()
        assert not sup.events and sup.failed is None, sup.events
        old = sup.children["gateway"].process.pid
        os.kill(old, signal.SIGSTOP)
        sup.wait_until(lambda: "gateway" in sup.children and sup.children["gateway"].process.pid != old, 30.0, "a new gateway")
        assert any("gateway process heartbeat stopped" in e for e in sup.events)


def test_losing_the_hardware_server_is_fatal_and_leaves_the_servo_safe(virtual_controller):
    sup = virtual_controller
    enable_and_hold(sup)
    os.kill(sup.children["hardware"].process.pid, signal.SIGKILL)
    deadline = time.monotonic() + 60
    while sup.failed is None and time.monotonic() < deadline:
        sup.poll()
        time.sleep(0.01)
    assert sup.failed and "hardware process exited with code -9" in sup.failed
    assert sup.control.get("safe_state") == 1


def test_while_one_process_is_restarted_the_others_are_still_watched(virtual_controller):
    """A restart takes its start-up time (a Zenoh session, the process's own set-up): meanwhile the
    supervisor goes on polling, so a second process lost then is noticed then, not after the first
    is back. The new gateway is held stopped (SIGSTOP) until then, so that its start-up lasts as
    long as the test needs, however fast the host."""
    sup = virtual_controller
    first, second = sup.children["gateway"].process.pid, sup.children["planner"].process.pid
    os.kill(first, signal.SIGKILL)
    sup.wait_until(lambda: "gateway" in sup.starting, 10.0, "the gateway's restart under way")
    replacement = sup.starting["gateway"].process.pid
    os.kill(replacement, signal.SIGSTOP)
    try:
        os.kill(second, signal.SIGKILL)
        sup.wait_until(lambda: any("planner process exited" in e for e in sup.events), 10.0, "the planner's loss noticed")
        assert "gateway" in sup.starting, "the second loss was noticed while the first restart was still under way"
    finally:
        os.kill(replacement, signal.SIGCONT)
    sup.wait_until(lambda: all(n in sup.children for n in ("gateway", "planner")) and not sup.starting, 60.0, "both back")
    assert sup.children["gateway"].process.pid != first and sup.children["planner"].process.pid != second
    assert sup.failed is None


def test_a_terminated_hardware_server_leaves_the_board_safe_first(virtual_controller):
    """SIGTERM (the supervisor's end, a system shutdown): the board goes to its safe state before
    anything else; its last image says so."""
    from cnc.data.fifo import SetpointFlag
    from cnc.hw.board import DigitalOut

    sup = virtual_controller
    held = enable_and_hold(sup)
    sup.fifo.push_one(held, (0.0, 0.0), SetpointFlag.JET_ON, epoch=sup.servo()["motion_epoch"])
    sup.wait_until(lambda: sup.hw()["digital_out"] & DigitalOut.JET_VALVE, 5.0, "the jet open")
    os.kill(sup.children["hardware"].process.pid, signal.SIGTERM)
    sup.children["hardware"].process.join(10.0)
    hw = sup.hw()
    assert hw["safe_state"] == 1 and not hw["digital_out"] & DigitalOut.JET_VALVE, "the last image: safe, jet closed"


def test_killing_the_fork_server_ends_the_processes_it_forked_the_board_left_safe(virtual_controller):
    """The processes are forked by the fork server (`table.process_context`), their parent. Were it
    killed, the supervisor would see them all gone (their exit statuses come through it): they must
    be gone indeed, not left running without it, the hardware server's board safe first."""
    from cnc.data.fifo import SetpointFlag
    from cnc.hw.board import DigitalOut

    sup = virtual_controller
    held = enable_and_hold(sup)
    sup.fifo.push_one(held, (0.0, 0.0), SetpointFlag.JET_ON, epoch=sup.servo()["motion_epoch"])
    sup.wait_until(lambda: sup.hw()["digital_out"] & DigitalOut.JET_VALVE, 5.0, "the jet open")
    pids = [child.process.pid for child in sup.children.values()]
    servers = [p for p in _descendants(os.getpid()) if "multiprocessing.forkserver" in _cmdline(p) and p not in pids]
    forked = [p for p in pids if _parent(p) in servers]
    assert len(servers) == 1 and sorted(forked) == sorted(pids), (servers, forked, pids)
    os.kill(servers[0], signal.SIGKILL)
    deadline = time.monotonic() + 60.0
    while [p for p in pids if _state(p) not in ("Z", "gone")] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert [p for p in pids if _state(p) not in ("Z", "gone")] == [], "processes left running without their parent"
    hw = sup.hw()
    assert hw["safe_state"] == 1 and not hw["digital_out"] & DigitalOut.JET_VALVE, "the last image: safe, jet closed"


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _parent(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError, IndexError):
        return -1


def test_the_process_table_names_every_process_once_and_every_entry_point_resolves():
    from cnc.data.layout import Proc
    from cnc.runtime.table import BY_NAME, PROCESSES, START_STAGES, realtime_priority

    assert sorted(p.slot for p in PROCESSES) == sorted(s for s in Proc if s != Proc.SUPERVISOR)
    assert [n for stage in START_STAGES for n in stage] == [p.name for p in sorted(PROCESSES, key=lambda p: p.stage)]
    assert START_STAGES[0] == ("servo",) and "hardware" in START_STAGES[1], "the servo waits for the first tick"
    for spec in PROCESSES:
        assert callable(spec.main()), spec.entry
        assert spec.restart in ("always", "faulted", "never")
    config = machine_config()
    priorities = [realtime_priority(config, p.name) for p in PROCESSES if p.rt_rank is not None]
    assert realtime_priority(config, "hardware") == max(priorities) > realtime_priority(config, "servo")
    assert BY_NAME["hardware"].restart == "never" and BY_NAME["servo"].restart == "faulted"


def test_every_zenoh_session_the_project_opens_has_shared_memory_off():
    """Zenoh's shared-memory transport would leave a segment per process in /dev/shm (1.3 MB
    each); our payloads are small and our fast data has its own shared memory."""
    import json

    from cnc.bus.session import zenoh_config

    for mode in ("client", "peer", "router"):
        assert json.loads(zenoh_config(mode).get_json("transport/shared_memory/enabled")) is False
