"""Simulated external PLC: its program (transport sequence, pump control, CNC watchdog) and plant.

A time-stepped model in terms of the variable ids of the machine file's `[plc]` map; the
simulator's Modbus server (`sim_server`) exposes it at the map's addresses. Inputs are what
the PLC publishes to the CNC, outputs what the CNC wrote, both as engineering values. The
plant is deliberately simple but shaped like the real one: commands take their travel time,
the pump pressure ramps at a limited rate, and the PLC stops the transport (alarm) when the
CNC's heartbeat stalls or a safety condition drops during a motion.

Thread safety: the server thread steps the model and applies writes while tests, the demo
or the fault-injection channel call `inject`, `press_button` and the readers; one lock
serialises them.
"""

from __future__ import annotations

import enum
import math
import threading
from dataclasses import dataclass

from cnc.config import PlcConfig

INPUT_IDS = (
    "plc_running", "mains_on", "safety_circuit_ok", "pneumatic_supply_on", "pneumatic_ready",
    "supply_ready", "transport_ready", "transport_drives_ready", "barrier_front_ok",
    "barrier_rear_ok", "button_pressed", "material_in_place", "gripper_closed", "unload_done",
    "pump_running", "pump_fault", "pump_pressure", "transport_step", "plc_alarm", "plc_heartbeat",
)
OUTPUT_IDS = (
    "feed_material", "gripper_close", "unload", "pump_on", "plc_reset", "cnc_cutting",
    "pump_pressure_set", "cnc_heartbeat",
)

FAULTS = (
    "estop",  # e-stop pressed: safety circuit open
    "doors",  # a guard door open: safety circuit open
    "barrier_front",  # front light barrier interrupted
    "barrier_rear",  # rear light barrier interrupted
    "mains_off",  # mains contactor off: everything loses power
    "pneumatic_off",  # compressed-air supply valve closed
    "pump_fault",  # the pump reports a fault and stops
    "pump_pressure_drop",  # pressure collapses while the pump runs (leak, worn orifice)
    "transport_drives_fault",  # transport drives report a fault
    "supply_empty",  # no material left on the input table
    "plc_stop",  # PLC switched to STOP: the program no longer runs
    "link_dead",  # the PLC's serial port stops answering
)


class ModelError(ValueError):
    """The machine file's map does not fit the simulated PLC program."""


class PlcAlarm(enum.IntEnum):
    """The simulated PLC's own alarm numbers (input register plc_alarm). Numbers are stable."""

    NONE = 0
    CNC_WATCHDOG = 1  # the CNC's heartbeat stalled during a transport motion
    TRANSPORT_STOPPED = 2  # safety, barrier, drives or air lost during a transport motion
    PUMP_FAULT = 3


class TransportStep(enum.IntEnum):
    """transport_step as the simulated PLC program reports it. Numbers are stable."""

    IDLE = 0
    FEEDING = 10
    MATERIAL_IN_PLACE = 11
    GRIPPER_CLOSING = 20
    GRIPPER_CLOSED = 21
    GRIPPER_OPENING = 22
    UNLOAD_OPENING = 30  # unload: gripper opens first
    UNLOADING = 31  # pieces travel to the output section
    UNLOAD_DONE = 32
    STOPPED = 90  # a motion was stopped by a fault; plc_reset clears it


@dataclass(frozen=True)
class PlantTimes:
    """Travel and reaction times of the simulated plant (realistic defaults; tests shorten them)."""

    feed_s: float = 3.0  # input table moves the material onto the cutting table
    gripper_s: float = 0.5  # gripper closes or opens
    unload_s: float = 3.0  # cut pieces travel to the output section
    pneumatic_s: float = 0.3  # air pressure builds after the supply valve opens
    button_s: float = 0.3  # a push-button press is held this long
    watchdog_s: float = 1.0  # CNC heartbeat stall that stops a moving transport
    ramp_bar_s: float = 1500.0  # pump pressure rate limit while building up
    decay_tau_s: float = 0.3  # pressure decay time constant with the pump off (bleed valve)
    drop_bar: float = 50.0  # pressure the line falls to under pump_pressure_drop


class PlcModel:
    """The simulated PLC program and plant; `step(now_s)` advances it to `now_s`."""

    def __init__(self, config: PlcConfig, times: PlantTimes | None = None, now_s: float = 0.0) -> None:
        self.times = times or PlantTimes()
        _check_map(config)
        self._lock = threading.Lock()
        self._faults = {name: False for name in FAULTS}
        self._out = {name: 0.0 for name in OUTPUT_IDS}
        self._in = {name: 0.0 for name in INPUT_IDS}
        self._now = now_s
        self._air_since: float | None = None
        self._button_until = -math.inf
        self._heartbeat_changed = now_s
        self._reset_was = False
        self._pressure = 0.0
        self._material = False
        self._gripper = False
        self._unloaded = False
        self._motion: TransportStep | None = None
        self._motion_left = 0.0
        self._alarm = PlcAlarm.NONE
        self._scans = 0
        self._update_inputs()

    # -- the CNC's and the operator's side --------------------------------------------------

    def set_output(self, var_id: str, value: float) -> None:
        """The CNC wrote `value` to output `var_id` (engineering value); unknown ids are ignored
        (a map may carry outputs this program does not use)."""
        with self._lock:
            if var_id not in self._out:
                return
            if var_id == "cnc_heartbeat" and value != self._out[var_id]:
                self._heartbeat_changed = self._now
            self._out[var_id] = float(value)

    def inject(self, name: str, on: bool) -> None:
        """Switch a simulated fault on or off (names in FAULTS)."""
        if name not in self._faults:
            raise ValueError(f"unknown PLC simulator fault {name!r}; known: {', '.join(FAULTS)}")
        with self._lock:
            self._faults[name] = bool(on)

    def press_button(self) -> None:
        """The operator presses the transport-station push button (held for button_s)."""
        with self._lock:
            self._button_until = self._now + self.times.button_s

    @property
    def link_dead(self) -> bool:
        return self._faults["link_dead"]

    def inputs(self) -> dict[str, float]:
        """What the PLC publishes now (engineering values), by variable id."""
        with self._lock:
            return dict(self._in)

    def outputs(self) -> dict[str, float]:
        """What the CNC last wrote, by variable id."""
        with self._lock:
            return dict(self._out)

    def input(self, var_id: str) -> float:
        with self._lock:
            return self._in[var_id]

    # -- the scan ---------------------------------------------------------------------------

    def step(self, now_s: float) -> None:
        """One PLC scan at time `now_s` (monotonic seconds)."""
        with self._lock:
            dt = max(0.0, now_s - self._now)
            self._now = now_s
            self._scan(dt)

    def _scan(self, dt: float) -> None:
        f, out = self._faults, self._out
        running = not f["plc_stop"] and not f["mains_off"]
        mains = not f["mains_off"]
        air = mains and not f["pneumatic_off"]
        if air and self._air_since is None:
            self._air_since = self._now
        elif not air:
            self._air_since = None
        if running:
            self._scans += 1
            reset = out["plc_reset"] != 0.0
            if reset and not self._reset_was:
                self._acknowledge()
            self._reset_was = reset
            self._transport(dt)
            self._pump_control()
        else:
            self._stop_motion(None)
        self._pump_plant(dt, running)
        self._update_inputs()

    def _conditions(self) -> dict[str, bool]:
        f = self._faults
        mains = not f["mains_off"]
        safety = mains and not f["estop"] and not f["doors"]
        air_ready = self._air_since is not None and self._now - self._air_since >= self.times.pneumatic_s
        drives = safety and not f["transport_drives_fault"]
        return {
            "mains_on": mains,
            "safety_circuit_ok": safety,
            "pneumatic_supply_on": mains and not f["pneumatic_off"],
            "pneumatic_ready": air_ready,
            "transport_drives_ready": drives,
            "barrier_front_ok": not f["barrier_front"],
            "barrier_rear_ok": not f["barrier_rear"],
        }

    def _transport_ok(self, c: dict[str, bool]) -> bool:
        return (
            not self._faults["plc_stop"] and c["transport_drives_ready"] and c["pneumatic_ready"]
            and c["barrier_front_ok"] and c["barrier_rear_ok"] and self._alarm == PlcAlarm.NONE
        )

    def _transport(self, dt: float) -> None:
        """The transport sequence: one motion at a time, each taking its travel time."""
        out = self._out
        ok = self._transport_ok(self._conditions())
        if self._motion is not None:
            if not ok:
                self._stop_motion(PlcAlarm.TRANSPORT_STOPPED)
                return
            if self._now - self._heartbeat_changed > self.times.watchdog_s:
                self._stop_motion(PlcAlarm.CNC_WATCHDOG)
                return
            if not self._still_commanded():
                self._motion = None  # the CNC withdrew the command: stop where it is
                return
            self._motion_left -= dt
            if self._motion_left <= 0.0:
                self._finish(self._motion)
            return
        if out["unload"] == 0.0:
            self._unloaded = False
        if not ok or out["cnc_cutting"] != 0.0:
            return  # the transport must not move while the CNC cuts
        t = self.times
        if out["unload"] != 0.0 and self._material and not self._unloaded:
            self._start(TransportStep.UNLOAD_OPENING if self._gripper else TransportStep.UNLOADING,
                        t.gripper_s if self._gripper else t.unload_s)
        elif out["feed_material"] != 0.0 and not self._material and not self._gripper and not self._faults["supply_empty"]:
            self._start(TransportStep.FEEDING, t.feed_s)
        elif out["gripper_close"] != 0.0 and self._material and not self._gripper and out["unload"] == 0.0:
            self._start(TransportStep.GRIPPER_CLOSING, t.gripper_s)
        elif out["gripper_close"] == 0.0 and self._gripper and out["unload"] == 0.0:
            self._start(TransportStep.GRIPPER_OPENING, t.gripper_s)

    def _still_commanded(self) -> bool:
        out, m = self._out, self._motion
        if m in (TransportStep.UNLOAD_OPENING, TransportStep.UNLOADING):
            return out["unload"] != 0.0
        if m == TransportStep.FEEDING:
            return out["feed_material"] != 0.0
        if m == TransportStep.GRIPPER_CLOSING:
            return out["gripper_close"] != 0.0
        return out["gripper_close"] == 0.0  # GRIPPER_OPENING

    def _start(self, step: TransportStep, duration_s: float) -> None:
        self._motion, self._motion_left = step, duration_s

    def _finish(self, step: TransportStep) -> None:
        self._motion = None
        if step == TransportStep.FEEDING:
            self._material = True
        elif step == TransportStep.GRIPPER_CLOSING:
            self._gripper = True
        elif step == TransportStep.GRIPPER_OPENING:
            self._gripper = False
        elif step == TransportStep.UNLOAD_OPENING:
            self._gripper = False
            self._start(TransportStep.UNLOADING, self.times.unload_s)
        elif step == TransportStep.UNLOADING:
            self._material = False
            self._unloaded = True

    def _stop_motion(self, alarm: PlcAlarm | None) -> None:
        if self._motion is not None and alarm is not None and self._alarm == PlcAlarm.NONE:
            self._alarm = alarm
        self._motion = None

    def _acknowledge(self) -> None:
        """plc_reset rising edge: clear the alarm when its cause is gone."""
        if self._alarm == PlcAlarm.PUMP_FAULT and self._faults["pump_fault"]:
            return
        self._alarm = PlcAlarm.NONE

    def _pump_control(self) -> None:
        if self._faults["pump_fault"] and self._alarm == PlcAlarm.NONE:
            self._alarm = PlcAlarm.PUMP_FAULT

    def _pump_running(self, running: bool) -> bool:
        f = self._faults
        safety = not f["mains_off"] and not f["estop"] and not f["doors"]
        return running and safety and self._out["pump_on"] != 0.0 and not f["pump_fault"]

    def _pump_plant(self, dt: float, running: bool) -> None:
        """Pressure: rate-limited towards the set point while running, first-order decay off."""
        t = self.times
        if self._pump_running(running):
            target = max(0.0, self._out["pump_pressure_set"])
            if self._faults["pump_pressure_drop"]:
                target = min(target, t.drop_bar)
            step = t.ramp_bar_s * dt
            self._pressure += max(-step, min(step, target - self._pressure))
        else:
            self._pressure *= math.exp(-dt / t.decay_tau_s) if t.decay_tau_s > 0 else 0.0
            if self._pressure < 0.05:
                self._pressure = 0.0

    def _update_inputs(self) -> None:
        c = self._conditions()
        f, i = self._faults, self._in
        running = not f["plc_stop"] and not f["mains_off"]
        for name, value in c.items():
            i[name] = 1.0 if value else 0.0
        i["plc_running"] = 1.0 if running else 0.0
        i["supply_ready"] = 1.0 if c["mains_on"] and not f["supply_empty"] else 0.0
        i["transport_ready"] = 1.0 if running and self._transport_ok(c) else 0.0
        i["button_pressed"] = 1.0 if self._now < self._button_until else 0.0
        i["material_in_place"] = 1.0 if self._material else 0.0
        i["gripper_closed"] = 1.0 if self._gripper else 0.0
        i["unload_done"] = 1.0 if self._unloaded else 0.0
        i["pump_running"] = 1.0 if self._pump_running(running) else 0.0
        i["pump_fault"] = 1.0 if f["pump_fault"] else 0.0
        i["pump_pressure"] = round(self._pressure, 1)
        i["transport_step"] = float(self._step_number())
        i["plc_alarm"] = float(int(self._alarm))
        i["plc_heartbeat"] = float(self._scans & 0xFFFF)

    def _step_number(self) -> int:
        if self._motion is not None:
            return int(self._motion)
        if self._alarm in (PlcAlarm.CNC_WATCHDOG, PlcAlarm.TRANSPORT_STOPPED):
            return int(TransportStep.STOPPED)
        if self._unloaded:
            return int(TransportStep.UNLOAD_DONE)
        if self._gripper:
            return int(TransportStep.GRIPPER_CLOSED)
        if self._material:
            return int(TransportStep.MATERIAL_IN_PLACE)
        return int(TransportStep.IDLE)


def _check_map(config: PlcConfig) -> None:
    """Every id the program uses must be in the map, in the right direction."""
    inputs = {v.id for v in config.inputs()}
    outputs = {v.id for v in config.outputs()}
    for var_id in INPUT_IDS:
        if var_id not in inputs:
            where = "is written (coil/holding_register)" if var_id in outputs else "is missing"
            raise ModelError(
                f"PLC simulator: [[plc.var]] {var_id!r} {where}; the simulated PLC publishes it "
                "as a discrete_input or input_register"
            )
    for var_id in OUTPUT_IDS:
        if var_id not in outputs:
            where = "is read (discrete_input/input_register)" if var_id in inputs else "is missing"
            raise ModelError(
                f"PLC simulator: [[plc.var]] {var_id!r} {where}; the simulated PLC reads it "
                "as a coil or holding_register"
            )
