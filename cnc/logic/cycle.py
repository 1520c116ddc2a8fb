"""The automatic cycle of the paper's machine: transport phase, cutting phase, unload, repeated.

The sequencer is a step function called every scan with the scan's snapshot; it never waits.
Each phase sets the PLC outputs it needs and waits for the PLC's answer, with a timeout that
raises an alarm and aborts the cycle safely (the caller's `fault`). Timeouts run on the wall
clock (the PLC lives in wall time) and stand still while the cycle is held.

- PROCEDURE: the transport procedure (machine file, `[cycle] transport_procedure`) walks the
  operator through the preconditions, once per cycle start.
- TRANSPORT: `feed_material` until `material_in_place`, then `gripper_close` until
  `gripper_closed`.
- PRESSURE: `pump_on` and `pump_pressure_set` to the pierce pressure (or the cutting pressure
  when the machine does not pierce low) until the pressure is within `[pump] tolerance_bar`.
- CUTTING: `cnc_cutting`, and the planner runs the loaded program. With
  `pierce_at_low_pressure` the pressure set point follows the jet: low while the jet is off and
  during its on delay and pierce dwell, then the cutting pressure.
- UNLOAD: `unload` (gripper opens, pieces to the output section) until `unload_done`.

A start inside the program (continuing an interrupted cut, a part, a line: `RestartAt`) finds
the material in place: it begins at PRESSURE, and its first CUTTING runs from there.
"""

from __future__ import annotations

from typing import Protocol

from ..bus.messages import Hold, Reply, RestartAt, Resume, Start, Stop
from ..config import MachineConfig
from ..data.layout import PlannerState, RunResult
from .signals import PlcOutputs, Snapshot
from .states import CyclePhase


class CycleHost(Protocol):
    """What the sequencer needs from the control logic."""

    config: MachineConfig
    outputs: PlcOutputs

    def plc(self, snap: Snapshot, var_id: str) -> float: ...
    def pressure_reached(self, bar: float) -> bool: ...
    def send_planner(self, command, on_reply=None) -> None: ...
    def void_motion(self) -> None: ...
    def fault(self, alarm_id: str, detail: str) -> None: ...
    def notice(self, alarm_id: str, detail: str) -> None: ...
    def start_procedure(self, procedure_id: str) -> str: ...
    def procedure_outcome(self, procedure_id: str) -> str: ...
    def stop_procedure(self, why: str) -> None: ...


class AutoCycle:
    """One automatic run of `target` cycles (0: until stopped); `phase` NONE when not running."""

    def __init__(self, host: CycleHost) -> None:
        self.host = host
        self.config = host.config
        self.phase = CyclePhase.NONE
        self.target = 0
        self.done = 0
        self.held = False
        self.stopping = False  # stop asked: finish the stop, then NONE
        self.stopped = False  # the last run was stopped by the operator
        self.sub = ""  # step within the phase
        self.deadline = 0.0
        self.held_at = 0.0
        self.run_seq = -1  # the planner's run_seq before our start
        self.start_reply: Reply | None = None
        self.jet_since: float | None = None
        self.restart: RestartAt | None = None  # the first cut of this start begins inside the program

    @property
    def active(self) -> bool:
        return self.phase != CyclePhase.NONE

    # -- operator ---------------------------------------------------------------------------
    def start(self, cycles: int, now: float, restart: RestartAt | None = None) -> None:
        """Start `cycles` cycles (0: until stopped); with `restart`, the first begins inside the
        program with the material already in place (no procedure, no transport: the pump, then the
        cut from there, then the unload as always)."""
        self.target, self.done, self.held, self.stopping, self.stopped = cycles, 0, False, False, False
        self.restart = restart
        if restart is not None:
            self._enter_pressure(now)
            return
        proc = self.config.cycle.transport_procedure
        if proc and any(p.id == proc for p in self.config.procedure):
            self._enter(CyclePhase.PROCEDURE, "walk", now, 0.0)
            refusal = self.host.start_procedure(proc)
            if refusal:
                self.host.fault("internal_error", f"the transport procedure could not start: {refusal}")
        else:
            self._enter_transport(now)

    def hold(self, now: float) -> None:
        if self.held or not self.active:
            return
        self.held, self.held_at = True, now
        if self.phase == CyclePhase.CUTTING and self.sub == "start":
            # the start is still on its way (a long re-plan): it must not run after the hold; the hold
            # cancels it if the planner is preparing it, and resume asks again
            self.host.void_motion()
            self.host.send_planner(Hold())
        elif self.phase == CyclePhase.CUTTING:
            self.host.send_planner(Hold(), self._on_planner)

    def resume(self, now: float) -> None:
        if not self.held:
            return
        self.held = False
        self.deadline += now - self.held_at  # timeouts stand still while held
        if self.phase == CyclePhase.CUTTING and self.sub in ("start", "restart"):
            self.sub, self.start_reply = "start", None
            self.host.send_planner(Start(restart=self.restart), self._on_start)
        elif self.phase == CyclePhase.CUTTING:
            self.host.send_planner(Resume(), self._on_planner)

    def stop(self) -> None:
        """Operator stop: a controlled end. Cutting decelerates on the path and ends the program."""
        if not self.active:
            return
        self.stopping, self.held = True, False
        if self.phase == CyclePhase.CUTTING:
            self.host.send_planner(Stop())
        else:
            self._end_procedure("stopped: the cycle was stopped")
            self._finish(stopped=True)

    def abort(self) -> None:
        """A fault: the caller has closed the jet and stopped the motion; leave the PLC safe."""
        self._end_procedure("stopped: the cycle stopped at a fault")
        self._transport_outputs_off()
        self.host.outputs.set("cnc_cutting", 0)
        self.phase, self.sub, self.held, self.stopping = CyclePhase.NONE, "", False, False

    # -- every scan -------------------------------------------------------------------------
    def step(self, snap: Snapshot, now: float) -> None:
        if not self.active:
            return
        if self.phase == CyclePhase.CUTTING:
            self._cutting(snap, now)  # runs while held too: the planner's end must be seen
            return
        if self.held:
            return
        if now > self.deadline > 0.0:
            self._timed_out()
            return
        getattr(self, f"_{self.phase.name.lower()}")(snap, now)

    def _end_procedure(self, why: str) -> None:
        """The cycle ends in its procedure phase: the procedure it opened ends with it (else it would
        go on asking for the button of a cycle no longer running, and hold the next start back)."""
        if self.phase == CyclePhase.PROCEDURE:
            self.host.stop_procedure(why)

    def _procedure(self, snap: Snapshot, now: float) -> None:
        outcome = self.host.procedure_outcome(self.config.cycle.transport_procedure)
        if outcome == "done":
            self._enter_transport(now)
        elif outcome in ("stopped", "idle"):
            self._finish(stopped=True)

    def _transport(self, snap: Snapshot, now: float) -> None:
        out = self.host.outputs
        if self.sub == "feed":
            out.set("feed_material", 1)
            if self.host.plc(snap, "material_in_place"):
                out.set("feed_material", 0)
                self.sub = "grip"
        if self.sub == "grip":
            out.set("gripper_close", 1)
            if self.host.plc(snap, "gripper_closed"):
                self._enter_pressure(now)

    def _pressure(self, snap: Snapshot, now: float) -> None:
        pump = self.config.pump
        target = pump.pierce_pressure_bar if pump.pierce_at_low_pressure else pump.cut_pressure_bar
        self._set_pump(target)
        if self.host.pressure_reached(target):
            self._enter(CyclePhase.CUTTING, "start", now, 0.0)
            self.host.outputs.set("cnc_cutting", 1)
            self.run_seq, self.start_reply, self.jet_since = snap.motion["run_seq"], None, None
            self.host.send_planner(Start(restart=self.restart), self._on_start)

    def _on_planner(self, reply: Reply) -> None:
        """The planner refused a hold or a resume: it is not doing what the cycle believes."""
        if not reply.ok:
            self.host.fault("program_error", reply.reason)

    def _on_start(self, reply: Reply) -> None:
        self.start_reply = reply

    def _cutting(self, snap: Snapshot, now: float) -> None:
        if self.sub == "restart":
            return  # held before the start ran: resume starts it
        if self.sub == "start":
            if self.start_reply is None:
                return
            if not self.start_reply.ok:
                if self.stopping:
                    self._finish(stopped=True)  # stopped before it ran
                elif self.held:
                    self.sub = "restart"
                else:
                    self.host.fault("program_error", self.start_reply.reason)
                return
            self.sub = "run"
            self.restart = None  # it runs: the next cycle cuts the whole program
        self._follow_jet(snap, now)
        m = snap.motion
        if m["run_seq"] > self.run_seq and m["state"] == PlannerState.IDLE:
            result = RunResult(m["run_result"])
            self.host.outputs.set("cnc_cutting", 0)
            if result == RunResult.DONE and not self.stopping:
                self._enter(CyclePhase.UNLOAD, "unload", now, self.config.cycle.unload_timeout_s)
            elif result == RunResult.FAULT:
                self.host.fault("program_error", m["error"] or "the program run failed")
            else:
                self._finish(stopped=True)

    def _follow_jet(self, snap: Snapshot, now: float) -> None:
        """Pierce at low pressure: the cutting pressure once the jet has been open for its on delay and pierce dwell."""
        pump, jet = self.config.pump, self.config.jet
        if not pump.pierce_at_low_pressure:
            self._set_pump(pump.cut_pressure_bar)
            return
        if not snap.jet_on:
            self.jet_since = None
            self._set_pump(pump.pierce_pressure_bar)
        elif self.jet_since is None:
            self.jet_since = now
        elif now - self.jet_since >= jet.on_delay_s + self._pierce_s(snap):
            self._set_pump(pump.cut_pressure_bar)

    def _pierce_s(self, snap: Snapshot) -> float:
        """The pierce dwell of the run in force, as the planner times it: the cutting job's chart
        pierce time, else the machine file's (a cut runs only on a planner that has said which)."""
        return float(snap.motion["pierce_s"])

    def _unload(self, snap: Snapshot, now: float) -> None:
        out = self.host.outputs
        out.set("gripper_close", 0)
        out.set("unload", 1)
        if self.host.plc(snap, "unload_done"):
            out.set("unload", 0)
            self.done += 1
            if self.stopping or (self.target and self.done >= self.target):
                self._finish(stopped=self.stopping)
                if not self.stopping:
                    self.host.notice("cycle_done", f"{self.done} cycle{'s' if self.done != 1 else ''} cut")
            else:
                self._enter_transport(now)

    # -- helpers ----------------------------------------------------------------------------
    def _enter(self, phase: CyclePhase, sub: str, now: float, timeout_s: float) -> None:
        self.phase, self.sub = phase, sub
        self.deadline = now + timeout_s if timeout_s > 0 else 0.0

    def _enter_transport(self, now: float) -> None:
        self._enter(CyclePhase.TRANSPORT, "feed", now, self.config.cycle.transport_timeout_s)

    def _enter_pressure(self, now: float) -> None:
        self.host.outputs.set("pump_on", 1)
        self._enter(CyclePhase.PRESSURE, "ramp", now, self.config.pump.ramp_timeout_s)

    def _set_pump(self, bar: float) -> None:
        self.host.outputs.set("pump_on", 1)
        self.host.outputs.set("pump_pressure_set", bar)

    def _timed_out(self) -> None:
        if self.phase == CyclePhase.PRESSURE:
            self.host.fault("pump_pressure_fault", f"the pump did not reach {self.host.outputs.get('pump_pressure_set'):.0f} bar "
                            f"within {self.config.pump.ramp_timeout_s:g} s")
        else:
            limit = self.config.cycle.transport_timeout_s if self.phase == CyclePhase.TRANSPORT else self.config.cycle.unload_timeout_s
            what = {"feed": "feed the material", "grip": "close the gripper", "unload": "unload"}.get(self.sub, self.sub)
            self.host.fault("transport_timeout", f"the transport system did not {what} within {limit:g} s")

    def _transport_outputs_off(self) -> None:
        for var in ("feed_material", "unload"):
            self.host.outputs.set(var, 0)

    def _finish(self, stopped: bool) -> None:
        self._transport_outputs_off()
        self.host.outputs.set("cnc_cutting", 0)
        self.phase, self.sub, self.held, self.stopping, self.stopped = CyclePhase.NONE, "", False, False, stopped
