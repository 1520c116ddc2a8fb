"""Supervisor: creates the data server, starts the controller processes and watches them.

It owns the shared-memory segments (created at start, unlinked at stop, nothing left in
/dev/shm), the controller's Zenoh router, which every process and HMI connects to, and, on
the simulated board with no PLC serial port configured, the PLC simulator on a pty pair.
Processes start in dependency order (servo waits for ticks, then the hardware server
ticks, then the planner, the PLC link, the control logic and the gateway) and are watched
by exit and by heartbeat, also while one of them is being restarted (a restart is started here
and finished by a later poll). When the servo dies the board is brought to rest by the hardware
server (its speed ramp, then the safe state); what may be restarted is restarted: the gateway,
the PLC link, the planner and the control logic freely (the logic rebuilds its active alarms
from the history), the servo into a latched fault that a reset clears; the hardware server owns
the board, so its loss stops the controller (by policy: a new controller started on the same
history recovers as after any fault). Losing the planner or the control logic in mid-motion is
the tick's to handle: the FIFO runs dry or the commander's heartbeat stops, and the servo stops
the axes under control itself.
The control logic is the machine's commander; started without it (`MOTION_ONLY`, for tests
of motion and for `waterjet simulate`) the supervisor's process commands the servo and asks
the planner itself, and without the planner too (`DIRECT_FEED`) it feeds the FIFO and
writes the `motion` block.
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing
import os
import secrets
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from ..control.loader import build as build_program
from ..bus.keys import Keys
from ..bus.access import Plan, open_machine_router, plan_access, run_dir, write_local_login
from ..config import MachineConfig, beside
from ..data.dataserver import BlockWriter, SharedArea, unique_name
from ..data.fifo import SetpointFifo
from ..hw.timers import VIRTUAL_SPIN_NS, TimerClient
from ..data.layout import Proc, ServoFault, ServoState, controller_layouts
from ..bus.messages import Drives, Reset, Stamp
from ..logic.client import LogicClient
from ..planner.client import PlannerClient
from .table import BY_NAME, START_ORDER, START_STAGES, process_context
from .child import HANG_DUMP_SIGNAL, Runtime
from ..data.trace import TraceRing

_ROUTERS = itertools.count(1)  # routers this process opened: each its own socket


def _private_socket() -> Path:
    """A new socket path for the private plane, in the controller account's run directory; the
    sockets of controllers that died without closing theirs (their process gone) are removed."""
    here = run_dir()
    for old in here.glob("bus-*-*.sock*"):
        pid = old.name.split("-")[1]
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            old.unlink(missing_ok=True)
    return here / f"bus-{os.getpid()}-{next(_ROUTERS)}.sock"


log = logging.getLogger(__name__)

FIFO_CAPACITY = 8192  # 8 s of setpoints at 1 kHz


def default_history_path(config: MachineConfig) -> str:
    """`[logic] history` beside the machine file, or the user's state directory when empty."""
    if config.logic.history:
        return str(beside(config, config.logic.history))
    state = Path(os.environ.get("XDG_STATE_HOME") or Path.home() / ".local" / "state")
    return str(state / "waterjet" / config.machine.name / "history.sqlite")


class SupervisorError(RuntimeError):
    """The controller could not start, or lost a process it cannot run without."""


MOTION_ONLY = ("servo", "hardware", "planner", "gateway")  # no soft-PLC: the supervisor's process commands (motion tests, simulate)
DIRECT_FEED = ("servo", "hardware", "gateway")  # no planner: the supervisor's process feeds the FIFO (servo tests)
TRACE_CAPACITY = 1 << 16  # ticks the trace ring holds between two drains
MAX_RESTARTS_PER_MINUTE = 5


#: how long a step of the virtual clock (`Supervisor.run_ticks`) polls for its ticks before it
#: waits at `wait_until`'s pace: a few ticks of a busy controller
_STEP_POLL_S = 0.005


@dataclass
class _Child:
    name: str
    process: Any
    started: float
    last_beat: int = -1
    last_beat_change: float = 0.0
    restarts: list[float] = field(default_factory=list)


@dataclass
class _Starting:
    """A process being restarted: started, not yet ready; later polls finish it."""

    name: str
    process: Any
    ready: Any
    deadline: float
    restarts: list[float]
    made_safe: bool


class Supervisor:
    """One controller instance. Use as a context manager, or `start()` ... `stop()`."""

    def __init__(
        self,
        config: MachineConfig,
        clock: str = "realtime",
        processes: tuple[str, ...] = START_ORDER,
        log_level: int = logging.INFO,
        history_path: str | os.PathLike | None = None,
        plc_sim_times: Any = None,
    ) -> None:
        if clock not in ("realtime", "virtual"):
            raise ValueError(f"clock {clock!r} is not one of: realtime, virtual")
        unknown = [p for p in processes if p not in BY_NAME]
        if unknown:
            raise ValueError(f"unknown controller process {unknown[0]!r} (known: {', '.join(BY_NAME)})")
        self.config, self.clock, self.log_level = config, clock, log_level
        self.process_names = tuple(p for p in START_ORDER if p in processes)
        self.history_path = str(history_path) if history_path is not None else default_history_path(config)
        self.plc_sim = None  # the PLC simulator, when this controller started one
        self._sim_pending: Callable[[], None] | None = None  # waits for the simulator spawned at start
        self.plc_sim_link = ""  # the device name the PLC link opens: a symlink to the simulator's pty
        self._plc_dir: tempfile.TemporaryDirectory | None = None
        self.plc_sim_times = plc_sim_times  # its plant's times (plc_link.sim_model.PlantTimes; None: realistic)
        self.keys = Keys(config.zenoh.key_prefix, config.machine.name)
        self.ctx = process_context()
        self.children: dict[str, _Child] = {}
        self.starting: dict[str, _Starting] = {}  # restarts under way
        self._release_safe = False  # give the safe state back once the hardware server has acted on it
        self.events: list[str] = []  # what the supervisor noticed, for the log and for tests
        self.failed: str | None = None
        self.area: SharedArea | None = None
        self.fifo: SetpointFifo | None = None
        self.trace: TraceRing | None = None
        self.router = None
        self.runtime: Runtime | None = None  # what every process is handed, once started
        self._sim_inputs_close: Callable[[], None] | None = None
        self.access: Plan | None = None
        self._socket: Path | None = None
        self._local_login: Path | None = None
        self._token = None
        self._watchdog_seen = False

    # -- lifecycle -----------------------------------------------------------------------
    def __enter__(self) -> "Supervisor":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> "Supervisor":
        cfg = self.config
        n = len(cfg.axis_names)
        self.area = SharedArea.create(unique_name(cfg.machine.name, "data"), controller_layouts(n))
        self.fifo = SetpointFifo.create(unique_name(cfg.machine.name, "fifo"), FIFO_CAPACITY, n)
        # each record carries the control program's log variables too: the ring is sized from its registrations
        extra = sum(spec.size for spec in build_program(cfg).log_variables)
        self.trace = TraceRing.create(unique_name(cfg.machine.name, "trace"), TRACE_CAPACITY, n, extra)
        # the commander's block: the control logic's when it runs, else this process's
        self.command: BlockWriter | None = None if "logic" in self.process_names else self.area.writer("command")
        if self.command is not None:
            self.command.set("token", secrets.randbits(63))
            self.command.publish()
        self.control: BlockWriter = self.area.writer("supervisor")
        self.control.set("members", sum(1 << BY_NAME[name].slot for name in self.process_names) | 1 << Proc.SUPERVISOR)
        self.control.publish()
        # without a planner process the supervisor feeds the FIFO, and so writes `motion`
        self.motion_writer: BlockWriter | None = None if "planner" in self.process_names else self.area.writer("motion")
        self.sim: BlockWriter = self.area.writer("sim")
        self.sim.set("friction_scale", [1.0] * n)
        self.sim.publish()
        hb = self.area.blocks["heartbeat"].array[0]
        self._beats = hb["beat"]
        hb["pid"][Proc.SUPERVISOR] = os.getpid()
        try:
            # the private plane's socket, the network endpoints and the access rules (cnc.bus.access)
            self._socket = _private_socket()
            self.access = plan_access(cfg, self._socket)
            self.router = open_machine_router(cfg, self.access)
            self._local_login = write_local_login(self.access)
            self._token = self.router.liveliness().declare_token(self.keys.alive("supervisor"))
            if cfg.board.kind == "sim":  # the simulated machine's inputs, for the gateway's cmd/sim
                from ..sim.inputs import serve

                self._sim_inputs_close = serve(self, self.router)
            plc_port, self._sim_pending = self._plc_port()
            clients = {}
            spin = VIRTUAL_SPIN_NS if self.clock == "virtual" else 0
            if "servo" in self.process_names:
                clients["servo"] = TimerClient.new(self.ctx, "servo", 1, spin)
            if "planner" in self.process_names:
                clients["planner"] = TimerClient.new(self.ctx, "planner", cfg.planner.divisor, spin)
            if "logic" in self.process_names:
                clients["logic"] = TimerClient.new(self.ctx, "logic", cfg.timing.logic_divisor, spin)
            if "logger" in self.process_names:
                clients["logger"] = TimerClient.new(self.ctx, "logger", cfg.logger.wake_divisor, spin)
                self.set_tracing(True)  # the logger drains the trace ring: the servo writes it every tick
            self.runtime = Runtime(
                config=cfg,
                clock=self.clock,
                data_name=self.area.shm.name,
                fifo_name=self.fifo.shm.name,
                zenoh_connect=[self.access.private],  # the private plane
                trace_name=self.trace.shm.name,
                timer_clients=clients,
                log_level=self.log_level,
                plc_port=plc_port,
                history_path=self.history_path,
                zenoh_credentials=self.access.controller,
                supervisor_pid=os.getpid(),
            )
            self.planner = PlannerClient(self.router, self.keys, stamp=self.stamp if self.command is not None else None)
            self.logic = LogicClient(self.router, self.keys)
            for stage in START_STAGES:  # each stage's processes start together, once the stage before is ready
                if "plc_link" in stage and self._sim_pending is not None:
                    finish, self._sim_pending = self._sim_pending, None
                    finish()  # the link opens the simulator's pty: it must serve by now (raises why not)
                self._spawn(*[name for name in stage if name in self.process_names])
            if "gateway" in self.process_names:
                self._until_announced("gateway")
        except BaseException:
            self.stop()
            raise
        log.info("controller %s up (%s clock): %s", cfg.machine.name, self.clock, ", ".join(self.process_names))
        return self

    def _until_announced(self, name: str, timeout_s: float = 10.0) -> None:
        """Wait until the router holds process `name`'s liveliness token. The gateway declares it
        after its doors, on the same link: once the router has it, a station's first query finds
        them (a query that comes before the declarations gets no answer at all)."""
        deadline = time.monotonic() + timeout_s
        while not any(r.ok is not None for r in self.router.liveliness().get(self.keys.alive(name), timeout=1.0)):
            if time.monotonic() > deadline:
                raise SupervisorError(f"{name} process started but its doors were not announced within {timeout_s:g} s")
            time.sleep(0.005)

    def _launch(self, name: str) -> tuple[Any, Any]:
        ready = self.ctx.Event()
        proc = self.ctx.Process(target=BY_NAME[name].main(), args=(self.runtime, ready), name=f"wj-{name}")
        proc.start()
        return proc, ready

    def _spawn(self, *names: str) -> None:
        """Start these processes together and wait until each reports ready (forked from the fork
        server with their modules imported, `table.process_context`: what is left of a start-up is
        attaching the shared memory and opening a session, and the stages follow each other)."""
        started = [(name, *self._launch(name)) for name in names]
        deadline = time.monotonic() + self.config.supervisor.start_timeout_s
        for name, proc, ready in started:
            while not ready.wait(0.05):
                if not proc.is_alive():
                    raise SupervisorError(f"{name} process exited during start-up (exit code {proc.exitcode})")
                if time.monotonic() > deadline:
                    proc.kill()
                    raise SupervisorError(f"{name} process did not report ready within {self.config.supervisor.start_timeout_s:g} s")
            old = self.children.get(name)
            child = _Child(name, proc, time.monotonic(), restarts=old.restarts if old else [])
            child.last_beat_change = time.monotonic()
            self.children[name] = child

    def _plc_port(self) -> tuple[str, Callable[[], None] | None]:
        """The PLC link's serial device: the machine file's, or a PLC simulator's on a pty pair
        that this controller starts (sim board, `[plc] port` empty). The simulator is spawned
        here and starts while the first stages do (its start-up is imports, like theirs); the
        function returned waits until it serves."""
        cfg = self.config
        if "plc_link" not in self.process_names or cfg.plc.port or not cfg.plc.var:
            return cfg.plc.port, None
        if cfg.board.kind != "sim":
            raise SupervisorError("[plc] port is empty: a real board needs the PLC's serial device")
        # the link opens a stable name, like socat's link=: a restarted simulator gets a new pty
        self._plc_dir = tempfile.TemporaryDirectory(prefix=f"wj-{cfg.machine.name}-plc-")
        self.plc_sim_link = os.path.join(self._plc_dir.name, "tty")
        return self.plc_sim_link, self.restart_plc_sim(wait=False)

    def restart_plc_sim(self, wait: bool = True) -> Callable[[], None] | None:
        """(Re)start the PLC simulator on a fresh pty pair and point the link's device name at it.
        Stopping it closes its pty: to the PLC link that is a cut cable. With `wait` False the
        simulator is spawned and what finishes its start is returned (start-up goes on meanwhile)."""
        from plc_link.sim_server import launch_simulator_process

        if self.plc_sim is not None:
            self.plc_sim.stop()
            self.plc_sim = None
        serving = launch_simulator_process(self.config, self.ctx, times=self.plc_sim_times)

        def finish() -> None:
            self.plc_sim = serving()
            fresh = self.plc_sim_link + ".new"
            os.symlink(self.plc_sim.device, fresh)
            os.replace(fresh, self.plc_sim_link)
        if not wait:
            return finish
        finish()
        return None

    def stop(self) -> None:
        """Safe state, then stop the processes in reverse start order and free the shared memory."""
        if self.area is not None and self.children:
            # the commander goes first, so that the safe state of a shutdown is not taken for a fault
            self._stop_child("logic")
            self.control.set("safe_state", 1)
            self.control.publish()
            self._wait_ticks(3, timeout_s=0.5)
            for stage in reversed(START_STAGES):  # a stage's processes stop together, the servo's last
                self._stop_child(*[name for name in stage if name in self.children])
        for name, child in list(self.children.items()):
            child.process.kill()
            child.process.join(2.0)
        self.children.clear()
        for pending in self.starting.values():
            pending.process.kill()
            pending.process.join(2.0)
        self.starting.clear()
        if self._sim_pending is not None:  # start-up failed before the simulator was waited for
            try:
                self._sim_pending()
            except (RuntimeError, OSError):
                pass  # it did not come up: nothing to stop but its process, which start_... killed
            self._sim_pending = None
        if self.plc_sim is not None:
            self.plc_sim.stop()
            self.plc_sim = None
        if self._plc_dir is not None:
            self._plc_dir.cleanup()
            self._plc_dir = None
        if self._sim_inputs_close is not None:
            self._sim_inputs_close()
            self._sim_inputs_close = None
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        if self.router is not None:
            self.router.close()
            self.router = None
        for path in (self._socket, self._local_login):
            if path is not None:
                path.unlink(missing_ok=True)
                path.with_name(path.name + ".lock").unlink(missing_ok=True)  # Zenoh's, beside its socket
        self._socket = self._local_login = None
        if self.fifo is not None:
            self.fifo.close()
            self.fifo = None
        if self.trace is not None:
            self.trace.close()
            self.trace = None
        if self.area is not None:
            self._beats = None  # drop the numpy view so the segment can be unmapped
            self.area.close()
            self.area = None

    def _stop_child(self, *names: str) -> None:
        """Ask these processes to stop, together, then wait for each (terminated, then killed, when late)."""
        children = [(name, self.children.pop(name)) for name in names if name in self.children]
        for name, _ in children:
            self.control.set("shutdown", self.control.get("shutdown") | 1 << BY_NAME[name].slot)
        if children:
            self.control.publish()
        if any(name == "servo" for name, _ in children) and self.runtime is not None:
            # it stops last, with no ticks left to wake it: woken now, it reads the word at once
            # (`procs.run_servo`) instead of after its 0.25 s wait for a tick
            self.runtime.timer_clients["servo"].wake.release()
        for name, child in children:
            child.process.join(5.0)
            if child.process.is_alive():
                log.warning("%s did not stop in time: terminating", name)
                child.process.terminate()
                child.process.join(2.0)
            if child.process.is_alive():
                child.process.kill()
                child.process.join(2.0)

    # -- watching ------------------------------------------------------------------------
    def poll(self) -> None:
        """Check exits, heartbeats, restarts under way and the watchdog once; act on what is found."""
        now = time.monotonic()
        self._beats[Proc.SUPERVISOR] += 1
        self._finish_restarts(now)
        self._release_safe_state()
        # a paused virtual clock stops the processes that beat once a tick: that is no hang
        paused = self.clock == "virtual" and bool(self.area.reader("hw").read_dict()["paused"])
        for name, child in list(self.children.items()):
            if not child.process.is_alive():
                self._on_death(name, f"exited with code {child.process.exitcode}")
                continue
            beat = int(self._beats[BY_NAME[name].slot])
            if beat != child.last_beat or paused:
                child.last_beat, child.last_beat_change = beat, now
            elif now - child.last_beat_change > self.config.supervisor.heartbeat_timeout_s:
                _dump_stacks(name, child.process)
                child.process.kill()
                child.process.join(2.0)
                self._on_death(name, f"heartbeat stopped for {now - child.last_beat_change:.1f} s (killed)")
        tripped = bool(self.hw()["watchdog_tripped"])
        if tripped and not self._watchdog_seen:
            self._note(f"drive watchdog tripped at tick {self.hw()['watchdog_trip_tick']}: drives disabled, jet closed")
        self._watchdog_seen = tripped

    def _on_death(self, name: str, why: str) -> None:
        policy = BY_NAME[name]
        self._note(f"{name} process {why}")
        # without the servo (or the board) the hardware server brings the axes to rest itself, then
        # holds the board safe; the planner's and the logic's losses the servo handles in the tick
        made_safe = policy.slot in (Proc.SERVO, Proc.HARDWARE)
        if made_safe:
            self.control.set("safe_state", 1)
            self.control.publish()
        child = self.children.pop(name)
        now = time.monotonic()
        recent = [t for t in child.restarts if now - t < 60.0]
        restart = policy.restart != "never" and len(recent) < MAX_RESTARTS_PER_MINUTE
        # the control logic latches the loss and stops a cut (a restarted logic reports its own)
        self.control.set("lost_proc", int(policy.slot))
        self.control.set("lost_why", why[:120])
        self.control.set("lost_restarted", int(restart))
        self.control.set("lost_seq", self.control.get("lost_seq") + 1)
        self.control.publish()
        if not restart:
            self.failed = f"{name} process {why}; the controller cannot run without it"
            self._note(self.failed)
            return
        process, ready = self._launch(name)
        self.starting[name] = _Starting(name, process, ready, now + self.config.supervisor.start_timeout_s,
                                        recent + [now], made_safe)

    def _release_safe_state(self) -> None:
        """The safe state asked for at a servo's loss is given back once the hardware server has acted
        on it (its ramp under way, or the board safe): a servo restarted faster than the hardware
        server's next tick would otherwise leave the axes to coast under a drives-off servo."""
        if self._release_safe and self.control.get("safe_state"):
            hw = self.hw()
            if hw["braking"] or hw["safe_state"]:
                self._release_safe = False
                self.control.set("safe_state", 0)
                self.control.publish()

    def _finish_restarts(self, now: float) -> None:
        """Restarts under way: the ready ones join the watched processes; the others may still start."""
        for name, pending in list(self.starting.items()):
            if pending.ready.is_set():
                del self.starting[name]
                child = _Child(name, pending.process, now, restarts=pending.restarts)
                child.last_beat_change = now
                self.children[name] = child
                self._note(f"{name} process restarted"
                           + (" into a latched fault: reset to continue" if BY_NAME[name].restart == "faulted" else ""))
                if pending.made_safe:  # back: the latched servo fault and its alarm now wait for the operator's reset
                    self._release_safe = True
            elif not pending.process.is_alive() or now > pending.deadline:
                del self.starting[name]
                pending.process.kill()
                self.failed = (f"{name} could not be restarted: it "
                               + ("exited during start-up" if not pending.process.is_alive() else "did not report ready in time"))
                self._note(self.failed)

    def _note(self, text: str) -> None:
        log.error("supervisor: %s", text) if "restarted" not in text else log.warning("supervisor: %s", text)
        self.events.append(text)

    def run(self, should_stop: Callable[[], bool], period_s: float = 0.05) -> int:
        """Watch until `should_stop()` or a fatal loss; returns the process exit status."""
        while not should_stop():
            self.poll()
            if self.failed:
                return 1
            time.sleep(period_s)
        return 0

    # -- commander -----------------------------------------------------------------------
    def enable(self, on: bool = True) -> None:
        """Ask the servo to close the loop (drives on) or open it (drives off): through the control
        logic when it runs (it may refuse: the reason is raised)."""
        if self.command is None:
            reply = self.logic.request(Drives(on))
            if not reply.ok:
                raise SupervisorError(reply.reason)
            return
        if not on:
            self.command.set("epoch", self.command.get("epoch") + 1)  # motion asked for before is void
        self.command.set("servo_enable", int(on))
        self.command.publish()

    def reset(self) -> None:
        """Clear latched faults: servo faults, the drive watchdog, a supervisor-forced safe state
        (those that tripped before now: a trip after the reset stays latched)."""
        self._release_safe = False
        self.control.set("safe_state", 0)
        self.control.publish()
        if self.command is None:
            self.logic.request(Reset())
            return
        self.command.set("reset_tick", self.hw()["tick"])
        self.command.set("reset_trip_seq", self.servo()["trip_seq"])
        self.command.set("reset_seq", self.command.get("reset_seq") + 1)
        self.command.publish()

    def stamp(self) -> Stamp:
        """The commander's stamp for a motion command (this process commands: no control logic)."""
        if self.command is None:
            raise RuntimeError("the control logic commands this controller: motion goes through it")
        return Stamp(self.command.get("token"), self.command.get("epoch"))

    def stop_motion(self) -> None:
        """A stop as the commander decides it: motion commands issued before are void from now."""
        if self.command is None:
            raise RuntimeError("the control logic commands this controller")
        self.command.set("epoch", self.command.get("epoch") + 1)
        self.command.publish()

    def set_position_reference(self, axis: int, counts: int, position_mm: float) -> int:
        """Encoder count `counts` of `axis` is machine position `position_mm` (without a planner
        process only: otherwise homing through the planner sets it); returns the request's number."""
        if self.motion_writer is None:
            raise RuntimeError("the planner process owns the position references: home through it")
        if not 0 <= axis < len(self.config.axis_names):
            raise ValueError(f"axis {axis} is not one of 0..{len(self.config.axis_names) - 1}")
        m = self.motion_writer
        counts_l, mm_l = list(m.get("position_ref_counts")), list(m.get("position_ref_mm"))
        counts_l[axis], mm_l[axis] = int(counts), float(position_mm)
        m.set("position_ref_counts", counts_l)
        m.set("position_ref_mm", mm_l)
        pending = self.servo()["position_ref_seq"] != m.get("position_ref_seq")
        m.set("position_ref_mask", (m.get("position_ref_mask") if pending else 0) | 1 << axis)  # keep an unapplied one
        seq = m.get("position_ref_seq") + 1
        m.set("position_ref_seq", seq)
        m.publish()
        return seq

    def set_tracing(self, on: bool) -> None:
        """Have the servo write every tick into the trace ring (`self.trace`)."""
        self.control.set("trace_enable", int(on))
        self.control.publish()

    def set_safe_state(self, on: bool = True) -> None:
        self.control.set("safe_state", int(on))
        self.control.publish()

    def pause_virtual_clock(self) -> int:
        """Virtual clock: stop time after the current tick; returns the tick it stops at."""
        self._require_virtual()
        self.control.set("virtual_run_until", max(self.hw()["tick"], 1))
        self.control.publish()
        self.wait_until(lambda: self.hw()["paused"], 5.0, "the virtual clock to pause")
        return self.hw()["tick"]

    def run_ticks(self, n: int, timeout_s: float = 60.0) -> int:
        """Virtual clock: advance exactly `n` ticks from a pause and stop again; returns the tick reached.

        Tests step the clock a tick at a time to see a reaction in the tick it happens (thousands of
        steps to a pierce): the wait polls its few ticks closely, then backs off to `wait_until`'s
        pace, and still supervises the processes while it waits."""
        self._require_virtual()
        reader = self.area.reader("hw")
        i_tick, i_paused = reader.layout.index["tick"], reader.layout.index["paused"]
        target = reader.read()[0][i_tick] + n
        self.control.set("virtual_run_until", target)
        self.control.publish()

        def reached() -> bool:
            hw = reader.read()[0]
            return bool(hw[i_paused]) and hw[i_tick] == target
        end = time.monotonic() + _STEP_POLL_S
        while time.monotonic() < end:
            if reached():
                return target
            os.sched_yield()
        self.wait_until(reached, timeout_s, f"tick {target}")
        return target

    def resume_virtual_clock(self) -> None:
        self.control.set("virtual_run_until", 0)
        self.control.publish()

    def _require_virtual(self) -> None:
        if self.clock != "virtual":
            raise RuntimeError(f"only the virtual clock can be paused and stepped (this controller runs {self.clock})")

    def stall_servo(self, ticks: int) -> None:
        """Make the servo sit out its next `ticks` ticks (`cnc.data.injection.ServoStall`): each
        is an overrun; `[timing] watchdog_missed_ticks` of them in a row trip the drive watchdog."""
        self.set_sim(servo_stall_ticks=ticks, servo_stall_seq=int(self.sim.get("servo_stall_seq")) + 1)

    def set_sim(self, **values: Any) -> None:
        """Change the simulated environment: estop_pressed, doors_open, mains_off, drive_fault_mask, friction_scale,
        planner_stall (the planner produces nothing: the FIFO runs dry), limit_switch_mask, inject_bug
        ("<process>/<verb>,...": those request handlers raise, `cnc.data.injection`)."""
        for key, value in values.items():
            if key not in self.sim.layout.index:
                raise ValueError(f"unknown simulated input {key!r} (known: {', '.join(self.sim.layout.index)})")
            self.sim.set(key, value)
        self.sim.publish()

    # -- reading -------------------------------------------------------------------------
    def hw(self) -> dict[str, Any]:
        return self.area.reader("hw").read_dict()

    def servo(self) -> dict[str, Any]:
        return self.area.reader("servo").read_dict()

    def motion(self) -> dict[str, Any]:
        """The planner's state and progress (the `motion` block)."""
        return self.area.reader("motion").read_dict()

    def timing(self, which: str) -> dict[str, Any]:
        """Copy of a timing histogram block (`hw_timing` or `servo_timing`)."""
        arr = self.area.blocks[which].array[0]
        return {"count": int(arr["count"]), "max_ns": int(arr["max_ns"]), "hist": arr["hist"].copy()}

    # Every wait_until's limit is multiplied by this: the tests set it higher (tests/conftest.py),
    # so that a busy two-core host never misses a limit; a wait that succeeds returns at once anyway.
    wait_margin = 1.0

    def wait_until(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        """Poll (and keep supervising) until `predicate()`; raise TimeoutError naming `what` after
        `timeout_s` x `wait_margin`."""
        limit_s = timeout_s * self.wait_margin
        deadline = time.monotonic() + limit_s
        while not predicate():
            self.poll()
            if self.failed:
                raise SupervisorError(self.failed)
            if time.monotonic() > deadline:
                raise TimeoutError(f"timed out after {limit_s:g} s waiting for {what}")
            time.sleep(0.002)

    def _wait_ticks(self, n: int, timeout_s: float) -> None:
        reader = self.area.reader("hw")
        start = reader.read_dict()["tick"]
        deadline = time.monotonic() + timeout_s
        while reader.read_dict()["tick"] < start + n and time.monotonic() < deadline:
            time.sleep(0.001)

    def wait_motion_done(self, timeout_s: float = 60.0) -> None:
        """Until the FIFO is empty and the servo holds (or has faulted)."""
        self.wait_until(
            lambda: self.fifo.fill() == 0 and self.servo()["state"] in (ServoState.HOLDING, ServoState.FAULT),
            timeout_s,
            "the motion to finish",
        )

    def servo_fault(self) -> ServoFault:
        return ServoFault(self.servo()["fault"])


def _dump_stacks(name: str, process: multiprocessing.Process) -> None:
    """Have a hung process write where each of its threads stands (stderr) before it is killed."""
    log.error("supervisor: %s stopped its heartbeat; its threads' stacks follow", name)
    try:
        os.kill(process.pid, HANG_DUMP_SIGNAL)
    except (OSError, TypeError):
        return
    time.sleep(0.1)  # the dump is written by the signal handler, at once
