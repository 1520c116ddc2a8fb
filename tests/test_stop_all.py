"""Stop all: any operator station, with or without the command lock, closes the jet, stops the axes
on their braking distance and switches the drives off; the alarm names the station, and nothing
starts again before a reset. (Its jet-off tick and stop distance at full and slow speed are in
the fault-injection matrix: `cnc.sim.faultinject`, "stop all (software)".)"""

from __future__ import annotations

from cnc.alarms import AlarmHistory
from cnc.bus.keys import Keys
from cnc.bus.messages import CycleStart, Reset, StopAll
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.data.layout import PlannerState, ServoState
from cnc.logic.states import MachineState

from .conftest import logic
from .test_logic_process import Events, command, cutting_in_auto, jet_open


def test_a_station_without_the_lock_stops_everything_and_only_a_reset_goes_on(plc_controller, tmp_path):
    sup = plc_controller
    events = Events(sup)
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    sessions = [open_client([sup.config.zenoh.listen[0]]) for _ in range(2)]
    holder, other = (OperatorStation(s, keys, name) for s, name in zip(sessions, ("panel", "bench-2")))
    assert holder.take_lock().ok
    cutting_in_auto(sup, tmp_path, start=lambda: holder.request(CycleStart(cycles=1)))
    jet = lambda: jet_open(sup)  # noqa: E731
    reply = other.request(StopAll(station="forged"))
    assert reply.ok and "reset to go on" in reply.reason, reply.reason
    sup.wait_until(lambda: not jet() and sup.motion()["state"] == PlannerState.IDLE
                   and sup.servo()["state"] not in (ServoState.STOPPING, ServoState.TRACKING), 30.0, "the stop")
    sup.wait_until(lambda: sup.servo()["drive_enable_mask"] == 0, 10.0, "the drives off at rest")
    assert logic(sup)["state"] == MachineState.FAULT
    sup.wait_until(lambda: 1097 in events.codes(), 10.0, "the stop-all alarm")
    with AlarmHistory(sup.history_path, readonly=True) as history:
        [raised] = [e for e in history.after(0, 1000).entries if e.code == 1097 and e.action == "raised"]
    assert raised.detail == "stop all from station bench-2 (local)", "the gateway names the station, not the message"
    refused = holder.request(CycleStart(cycles=1))
    assert not refused.ok, "nothing starts before a reset"
    assert holder.request(Reset()).ok
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.servo()["state"] == ServoState.HOLDING
                   and sup.servo()["drive_enable_mask"] != 0, 20.0, "drives on and READY after the reset")
    for op, s in zip((holder, other), sessions):
        op.close()
        s.close()
    events.close()


def test_stop_all_at_rest_switches_the_drives_off_and_is_latched(plc_controller):
    sup = plc_controller
    command(sup, Reset())
    sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 10.0, "the drives on")
    assert command(sup, StopAll(station="station test (local)")).startswith("everything stopped")
    sup.wait_until(lambda: sup.servo()["drive_enable_mask"] == 0, 10.0, "the drives off")
    # the logic's block says "blocking" once the alarm is in the history (its recorder's thread)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.FAULT and logic(sup)["blocking"], 10.0, "latched")
