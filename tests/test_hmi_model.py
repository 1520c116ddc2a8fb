"""The HMI's model (alarm lifecycle, history filter, segments, lock, screen) and its Zenoh connection
to a real controller on the virtual clock (catch-up, live status, lock and commands, reconnection)."""

from __future__ import annotations

import time
from contextlib import contextmanager
from types import SimpleNamespace

import pytest

from cnc.bus.keys import Keys
from cnc.bus.messages import (
    ActiveAlarm, AlarmEvent, AlarmList, CycleStart, HistoryPage, LockRequest, LockState, Position, ProcedureState,
    ProcedureStep, ProgramInfo, ProgramPath, ProgramProgress, Reset, Status, UploadProgram, encode,
)
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.alarms.catalogue import AlarmAction, AlarmLevel
from cnc.alarms.history import AlarmHistory
from cnc.runtime.supervisor import Supervisor
from hmi.connection import Connection
from hmi.model import MachineModel, PlcState, Screen

from .conftest import NEAR_HOME, fast_plant, machine_config
from .test_zenoh_interface import PART


# -- hand-built messages -----------------------------------------------------------------------


def status(seq: int = 1, **fields) -> Status:
    base = dict(machine="wj", seq=seq, stamp_ns=seq * 1000, tick=seq, clock="virtual", servo_state="RUNNING",
                fault="NONE", fault_axis="", watchdog_tripped=False, safe_state=False, estop_ok=True,
                doors_closed=True, jet_on=False, axes=[], overruns=0, underruns=0, late_ticks=0,
                servo_missed_ticks=0, fifo_fill=0)
    return Status(**{**base, **fields})


def event(seq: int, action: str, code: int = 10, level: str = "error", detail: str = "x", text: str = "Following error",
          id: str = "following_error") -> AlarmEvent:
    return AlarmEvent(seq, seq * 1_000_000, code, id, level, action, text, detail)


def position(seq: int, segment: int) -> Position:
    return Position(seq, seq, seq, [1.0, 2.0], [1.0, 2.0], [0.0, 0.0], segment, 5, False)


def program(n_segments: int = 4, hash: str = "h1") -> ProgramInfo:
    zeros = [0.0] * n_segments
    path = ProgramPath([1] * n_segments, zeros, zeros, zeros, zeros, zeros, zeros, [False] * n_segments,
                       list(range(n_segments)))
    return ProgramInfo("part.ngc", hash, 100, 10, 12.0, text="G1 X1\n", path=path)


def progress(segment: int, result: str = "RUNNING", hash: str = "h1") -> ProgramProgress:
    return ProgramProgress("part.ngc", hash, 10, segment, 5, 0.0, 1.0, 0.5, 3.0, 12.0, 1, result)


class Recorder:
    """Counts the callbacks of each topic."""

    def __init__(self, model: MachineModel, *topics: str) -> None:
        self.calls = {t: 0 for t in topics}
        for t in topics:
            model.subscribe(t, lambda t=t: self.calls.__setitem__(t, self.calls[t] + 1))


# -- the model -------------------------------------------------------------------------------


def test_alarm_lifecycle_raised_acknowledged_cleared_latched_then_reset_leaves_the_list():
    model = MachineModel("panel")
    rec = Recorder(model, "alarms", "history")
    model.apply_alarm(event(1, "raised"))
    [alarm] = model.active_alarms
    assert alarm.code == 10 and alarm.active and not alarm.acknowledged and alarm.raised_seq == 1
    model.apply_alarm(event(2, "acknowledged"))
    assert model.active_alarms[0].acknowledged
    model.apply_alarm(event(3, "cleared"))
    [latched] = model.active_alarms
    assert not latched.active and latched.acknowledged, "a cleared error stays listed until reset"
    model.apply_alarm(event(4, "reset"))
    assert model.active_alarms == []
    assert rec.calls == {"alarms": 4, "history": 4}
    model.apply_alarm(event(4, "reset"))  # a repeat changes nothing and calls nobody
    assert rec.calls == {"alarms": 4, "history": 4}
    assert [e.seq for e in model.history_view()] == [4, 3, 2, 1] and model.last_seq == 4


def test_the_same_alarm_on_two_axes_is_two_alarms_and_info_messages_never_enter_the_list():
    model = MachineModel("panel")
    model.apply_alarm(event(1, "raised", detail="axis x"))
    model.apply_alarm(event(2, "raised", detail="axis y"))
    model.apply_alarm(event(3, "raised", code=37, level="info", id="wrong_mode", text="Wrong operation mode"))
    assert [a.detail for a in model.active_alarms] == ["axis x", "axis y"]
    model.apply_alarm(event(4, "cleared", detail="axis y"))
    model.apply_alarm(event(5, "reset", detail="axis y"))
    assert [a.detail for a in model.active_alarms] == ["axis x"]
    prompt = ActiveAlarm(40, "press_button", "info", "Press the button", "", "logic", 6, 6, True, False)
    model.apply_active(AlarmList([model.active_alarms[0], prompt], last_seq=6))
    assert [a.code for a in model.active_alarms] == [10, 40]
    model.apply_alarm(AlarmEvent(7, 7, 40, "press_button", "info", "cleared", "Press the button"))
    assert [a.code for a in model.active_alarms] == [10], "an info prompt leaves the list when cleared"


def test_history_view_filters_by_text_level_and_code_newest_first():
    model = MachineModel("panel")
    model.apply_history(HistoryPage([
        event(1, "raised", detail="axis X 2.5 mm"),
        event(2, "raised", code=37, level="info", id="wrong_mode", text="Wrong operation mode", detail="cycle start"),
        event(3, "raised", code=50, level="warning", id="pump_pressure", text="Pump pressure low", detail="1200 bar"),
    ], last_seq=3, more=False))
    model.apply_alarm(event(3, "raised", code=50, level="warning"))  # already in the history: not twice
    assert [e.seq for e in model.history_view()] == [3, 2, 1]
    assert [e.seq for e in model.history_view(text="AXIS x")] == [1]
    assert [e.seq for e in model.history_view(text="cycle")] == [2], "the detail is searched"
    assert [e.seq for e in model.history_view(levels=["warning", "error"])] == [3, 1]
    assert [e.seq for e in model.history_view(codes=[37, 50], text="bar")] == [3]
    assert model.history_view(text="nothing like this") == []


def test_a_code_filter_takes_alarm_codes_and_names_a_word_that_is_not_one():
    """What the history window's code box sends: codes within the machine file's range only (a
    long row of digits once went to the controller's history as it was)."""
    from hmi.alarms import parse_codes

    assert parse_codes("5, 37 2292") == [5, 37, 2292] and parse_codes(" , ") is None
    assert parse_codes("999999") == [999999]
    for word in ("12a", "1" * 40, "0", "1000000", "\u0663", "-5"):
        with pytest.raises(ValueError, match=f"code filter: {word!r} is not an alarm code \\(1 to 999999\\)"):
            parse_codes(f"37 {word}")


def test_segment_states_follow_the_position_and_the_status_program():
    model = MachineModel("panel")
    assert model.segment_states() == -1
    model.apply_program(program(4))
    model.apply_status(status(1, program=progress(-1, "NONE")))
    assert model.segment_states() == -1, "before the first segment nothing is cut"
    model.apply_status(status(2, program=progress(1)))
    assert model.segment_states() == 1, "the status's segment while no position came"
    model.apply_position(position(1, 2))
    assert model.segment_states() == 2, "the 50 Hz position wins"
    model.apply_position(position(2, -1))
    model.apply_status(status(3, program=progress(-1, "DONE")))
    assert model.segment_states() == 4, "a finished run: every segment is cut"
    assert model.program.segments == 4 and model.program.name == "part.ngc" and model.program.text == "G1 X1\n"
    assert not model.program_outdated
    model.apply_status(status(4, program=progress(0, hash="h2")))
    assert model.program_outdated, "the controller loaded another program"


def test_the_screen_has_caught_up_once_status_position_history_and_program_are_in():
    """What `waterjet hmi --screenshot` waits for before it renders (not a fixed delay)."""
    model = MachineModel("panel")
    assert not model.caught_up
    model.set_reachable(True)
    model.apply_status(status(1, alarm_seq=2, program=progress(0)))
    assert not model.caught_up, "no position yet"
    model.apply_position(position(1, 0))
    assert not model.caught_up, "the history is behind the status's newest entry"
    model.apply_history(HistoryPage([event(1, "raised"), event(2, "cleared")], 2, False))
    assert not model.caught_up, "the program the status names is not in"
    model.apply_program(program(4))
    assert model.caught_up
    model.apply_status(status(2, alarm_seq=3, program=progress(1)))
    assert not model.caught_up, "a newer entry the history does not hold"
    model.apply_alarm(event(3, "raised"))
    assert model.caught_up
    model.set_reachable(False)
    assert not model.caught_up, "an unreachable controller is never caught up with"


def test_read_only_unless_this_station_holds_the_lock():
    model = MachineModel("panel")
    rec = Recorder(model, "lock")
    assert model.read_only and model.lock_holder == ""
    model.apply_lock(LockState("other", 1, ["other", "panel"], 1))
    assert model.read_only and model.lock_holder == "other" and model.stations == ["other", "panel"]
    model.apply_lock(LockState("panel", 2, ["other", "panel"], 2))
    assert not model.read_only and model.holds_lock
    model.apply_status(status(1, operator="panel"))  # agrees: no callback
    assert rec.calls["lock"] == 2
    model.apply_status(status(2, operator=""))  # the status says the lock went (a lost lock message)
    assert model.read_only and rec.calls["lock"] == 3


def test_screen_follows_the_machine_state_and_callbacks_run_only_on_change():
    model = MachineModel("panel")
    rec = Recorder(model, "screen", "status", "connection")
    assert model.screen is Screen.OFFLINE
    model.set_reachable(True)
    model.apply_status(status(1))
    assert model.screen is Screen.MANUAL
    model.apply_status(status(2))  # only the sequence and stamps moved
    assert rec.calls["status"] == 1
    model.apply_status(status(3, mode="AUTO"))
    assert model.screen is Screen.AUTO
    running = ProcedureState("transport", "Transport", "running", 0, [ProcedureStep("Press", "awaited")], "Press", 1)
    model.apply_procedure(running)
    assert model.screen is Screen.PROCEDURE
    model.apply_status(status(4, mode="AUTO", machine_state="ESTOP"))
    assert model.screen is Screen.FAULT, "a fault comes before the procedure"
    model.set_reachable(False)
    assert model.screen is Screen.OFFLINE
    assert rec.calls == {"screen": 5, "status": 3, "connection": 2}  # manual, auto, procedure, fault, offline


def test_travel_limits_come_from_the_machine_configuration_and_a_failing_view_does_not_stop_the_others():
    config = SimpleNamespace(axis={"x": SimpleNamespace(travel_min_mm=0.0, travel_max_mm=3000.0),
                                   "y": SimpleNamespace(travel_min_mm=-10.0, travel_max_mm=1500.0)})
    model = MachineModel("panel", config)
    assert model.travel_mm == {"x": (0.0, 3000.0), "y": (-10.0, 1500.0)}
    assert machine_config().axis["x"].travel_max_mm > 0 and MachineModel("p", machine_config()).travel_mm
    seen = []
    model.subscribe("position", lambda: 1 / 0)
    unsubscribe = model.subscribe("position", lambda: seen.append(model.position.segment))
    model.apply_position(position(1, 3))
    unsubscribe()
    model.apply_position(position(2, 4))
    assert seen == [3]
    with pytest.raises(ValueError, match="not one of"):
        model.subscribe("weather", lambda: None)


# -- the connection to a real controller ---------------------------------------------------------


def wait_for(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(0.05)


def start_controller(config, tmp_path) -> Supervisor:
    sup = Supervisor(config, clock="virtual", history_path=tmp_path / "history.sqlite", plc_sim_times=fast_plant())
    sup.start()
    return sup


@pytest.fixture
def controller(plc_controller):
    return plc_controller


def keys_of(config) -> Keys:
    return Keys(config.zenoh.key_prefix, config.machine.name)


@contextmanager
def other_station(endpoints: list[str], keys: Keys, wrong_mode_messages: int):
    """Another station that takes the lock and asks for a cycle start in MANUAL `wrong_mode_messages`
    times (each refused, message 37 in the history)."""
    session = open_client(endpoints)
    station = OperatorStation(session, keys, "other")
    try:
        assert station.take_lock().ok
        for _ in range(wrong_mode_messages):
            assert not station.request(CycleStart()).ok
        yield station
    finally:
        station.close()
        session.close()


def test_the_connection_catches_up_takes_the_lock_commands_and_follows_the_program(controller):
    sup = controller
    keys, endpoints = keys_of(sup.config), [sup.config.zenoh.listen[0]]
    model = MachineModel("panel")  # no machine file on the operator's host: the travel comes with the status
    with other_station(endpoints, keys, 3) as other, Connection(model, endpoints, keys, "panel") as conn:
        wait_for(lambda: len(model.history_view(codes=[37])) == 3, 10.0, "the messages from before the connection")
        wait_for(lambda: model.reachable and model.position is not None, 5.0, "status and position")
        assert model.status.plc_link == "OK" and model.screen is Screen.MANUAL and model.error == ""
        x = sup.config.axis["x"]
        assert model.travel_mm["x"] == (x.travel_min_mm, x.travel_max_mm)
        assert model.lock_holder == "other" and model.read_only
        assert model.travel_mm["x"] == (sup.config.axis["x"].travel_min_mm, sup.config.axis["x"].travel_max_mm)
        refused = conn.command(Reset())
        assert not refused.ok and "read-only: station 'other' holds the command lock" in refused.reason
        assert other.request(CycleStart()).ok is False
        wait_for(lambda: len(model.history_view(codes=[37])) == 4, 5.0, "a live message")
        assert [e.seq for e in model.history_view()] == list(range(model.last_seq, 0, -1)), "no entry missed"
        assert other.release_lock().ok
        assert conn.command(LockRequest(take=True)).ok
        wait_for(lambda: model.holds_lock and not model.read_only, 5.0, "the lock in the model")
        assert conn.command(Reset()).ok
        assert conn.command(UploadProgram("part.ngc", PART)).ok
        wait_for(lambda: model.program is not None and model.program.name == "part.ngc", 5.0, "the program")
        assert model.program.segments == 6 and model.program.text == PART and model.segment_states() <= 0
    assert not model.reachable


def test_a_schema_version_mismatch_sets_a_clear_error_and_the_subscription_survives(controller):
    sup = controller
    keys, endpoints = keys_of(sup.config), [sup.config.zenoh.listen[0]]
    model = MachineModel("panel")
    with Connection(model, endpoints, keys, "panel"):
        wait_for(lambda: model.reachable, 5.0, "the first status")
        publisher = open_client(sup.runtime.zenoh_connect, sup.runtime.zenoh_credentials)  # the controller's side
        future = encode(ProcedureState("p", "P", "running", 0, [], "", 1)).replace(b'"version":1', b'"version":2')
        publisher.put(keys.procedure, future)
        wait_for(lambda: "schema version 2" in model.error, 5.0, "the error text")
        assert "ProcedureState" in model.error and model.procedure is None
        publisher.put(keys.procedure, encode(ProcedureState("p", "P", "running", 0, [], "", 2)))
        wait_for(lambda: model.procedure is not None, 5.0, "the next readable procedure")
        assert model.error == "", "a readable message on that key clears the error"
        publisher.close()


def test_unreachable_when_the_controller_stops_and_reachable_when_a_new_one_comes_up(tmp_path):
    config = machine_config(**NEAR_HOME)
    keys, endpoints = keys_of(config), [config.zenoh.listen[0]]
    model = MachineModel("panel")
    changes: list[bool] = []
    model.subscribe("connection", lambda: changes.append(model.reachable))
    sup = start_controller(config, tmp_path)
    try:
        with Connection(model, endpoints, keys, "panel"):
            wait_for(lambda: model.reachable, 10.0, "the first controller")
            assert changes == [True], "reachable once, and it stays so while the status flows"
            sup.stop()
            wait_for(lambda: not model.reachable, 5.0, "the loss")
            assert model.screen is Screen.OFFLINE
            with AlarmHistory(tmp_path / "history.sqlite") as history:  # written while no controller runs:
                history.append(stamp_ns=time.time_ns(), code=9999, id="offline_entry",  # no event will ever carry it
                               level=AlarmLevel.WARNING, action=AlarmAction.RAISED, text="Written offline")
            sup = start_controller(config, tmp_path)  # the same endpoint and history file
            wait_for(lambda: model.reachable and model.status is not None, 20.0, "the new controller")
            assert changes == [True, False, True]
            assert model.screen is Screen.MANUAL
            wait_for(lambda: model.history_view(codes=[9999]), 5.0, "the catch-up after the reconnect")
            assert [e.seq for e in model.history_view()] == list(range(model.last_seq, 0, -1)), "no entry missed"
            wait_for(lambda: 9999 in [a.code for a in model.active_alarms], 5.0, "the active list read again")
    finally:
        sup.stop()


def test_a_long_history_is_read_from_its_newest_entries_and_searched_whole_on_the_controller(controller, monkeypatch):
    import hmi.connection

    sup = controller
    keys, endpoints = keys_of(sup.config), [sup.config.zenoh.listen[0]]
    with other_station(endpoints, keys, 5):
        pass
    monkeypatch.setattr(hmi.connection, "HISTORY_KEPT", 3)
    model = MachineModel("panel")
    with Connection(model, endpoints, keys, "panel") as conn:
        wait_for(lambda: model.reachable and model.last_seq >= 5, 10.0, "the catch-up")
        newest = model.status.alarm_seq
        assert [e.seq for e in model.history_view()] == [newest, newest - 1, newest - 2], "only the newest kept are read"
        found = conn.search_history(text="mode", codes=[37])
        assert len(found.entries) == 5 and all(e.code == 37 for e in found.entries)
        assert [e.seq for e in found.entries] == sorted((e.seq for e in found.entries), reverse=True), "newest first"
        assert conn.search_history(levels=["fatal"]).entries == []


def test_plc_state_faults_and_reset_needed_are_derived_from_the_status_and_the_alarms():
    model = MachineModel("panel")
    assert model.plc_state() is PlcState.STOPPED and model.faults() == [] and not model.needs_reset()
    running = {"plc_running": 1.0, "transport_step": 0.0, "safety_circuit_ok": 1.0}
    model.apply_status(status(1, plc_link="OK", plc_inputs=running))
    assert model.plc_state() is PlcState.STARTED
    model.apply_status(status(2, plc_link="OK", plc_inputs={**running, "transport_step": 3.0}))
    assert model.plc_state() is PlcState.RUNNING
    model.apply_status(status(3, plc_link="OK", plc_inputs=running, cycle_phase="CUTTING"))
    assert model.plc_state() is PlcState.RUNNING
    model.apply_status(status(4, plc_link="LOST", plc_inputs={}, estop_ok=False, doors_closed=False,
                              fault="FOLLOWING_ERROR", fault_axis="x", machine_state="ESTOP"))
    assert model.plc_state() is PlcState.STOPPED and model.needs_reset()
    assert model.faults() == ["Emergency stop pressed (or the safety circuit is open)", "Safety door open",
                              "Servo fault FOLLOWING_ERROR on axis X", "PLC link LOST"]
    model.apply_status(status(5, plc_link="OK", plc_inputs={**running, "plc_alarm": 12.0, "pump_fault": 1.0,
                                                             "safety_circuit_ok": 0.0}))
    assert model.faults() == ["PLC alarm 12", "High-pressure pump fault", "Safety circuit open (PLC)"]
    model.apply_status(status(6, plc_link="OK", plc_inputs=running))
    assert not model.needs_reset()
    model.apply_alarm(event(1, "raised", detail="axis x"))
    assert model.faults() == ["10 Following error: axis x"] and model.needs_reset()
    model.apply_alarm(event(2, "cleared", detail="axis x"))
    assert model.faults() == [] and model.needs_reset(), "cleared but latched: no fault, the reset still owed"
    model.apply_alarm(event(3, "reset", detail="axis x"))
    assert not model.needs_reset()


def test_the_plc_link_lamp_tells_failed_exchanges_and_dropped_answers_since_start():
    from hmi.model import plc_link_text

    assert plc_link_text(status(plc_link="OK", plc_exchanges=500)) == "OK"
    assert plc_link_text(status(plc_link="OK", plc_exchanges=498, plc_failed=2, plc_dropped=1)) == (
        "OK (2 of 500 exchanges failed, 1 late answer dropped since start)")
    assert plc_link_text(status(plc_link="LOST", plc_exchanges=10, plc_failed=3)) == "LOST (3 of 13 exchanges failed since start)"


def test_a_done_procedure_keeps_the_screen_until_ended_unless_the_automatic_cycle_started_it():
    model = MachineModel("panel")
    model.set_reachable(True)
    steps = [ProcedureStep("Press", "done")]
    model.apply_status(status(1, mode="AUTO", procedure="transport", cycle_phase="TRANSPORT"))
    model.apply_procedure(ProcedureState("transport", "Transport", "done", -1, steps, "", 1, by_cycle=True))
    assert model.screen is Screen.AUTO, "the cycle goes on by itself"
    model.apply_procedure(ProcedureState("transport", "Transport", "stopped", -1, steps, "", 2, by_cycle=True))
    assert model.screen is Screen.PROCEDURE, "a stopped one waits for the operator to end it"
    model.apply_status(status(2, mode="MANUAL", procedure="pump_warmup"))
    model.apply_procedure(ProcedureState("pump_warmup", "Pump", "done", -1, steps, "", 3))
    assert model.screen is Screen.PROCEDURE, "the operator's own procedure stays until ended"
    model.apply_status(status(3, mode="MANUAL", procedure=""))
    model.apply_procedure(ProcedureState("", "", "idle", -1, [], "", 4))
    assert model.screen is Screen.MANUAL
