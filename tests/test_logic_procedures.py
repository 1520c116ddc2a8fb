"""Guided procedures: steps ticked off in order, confirmations, timeouts, stop and end, and refusals."""

from __future__ import annotations

import dataclasses

import pytest

from cnc.config import MachineConfig, load_machine
from cnc.logic.conditions import ConditionError
from cnc.bus.service import CommandRefused
from cnc.logic.procedures import ProcedureRunner
from cnc.logic.signals import SignalReader

from .conftest import MACHINE_FILE

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

# The transport procedure of the shipped machine: the signals that complete each step.
TRANSPORT_STEPS = [
    ("Emergency stop released", ["din.estop_ok"]),
    ("Safety doors closed", ["din.doors_closed"]),
    ("Machine mains on", ["din.mains_on", "plc.mains_on"]),
    ("Pneumatic supply on", ["plc.pneumatic_supply_on"]),
    ("Pneumatic system ready", ["plc.pneumatic_ready"]),
    ("Supply ready", ["plc.supply_ready"]),
    ("Transport system ready", ["plc.transport_ready"]),
    ("Transport system drives ready", ["plc.transport_drives_ready"]),
    ("Safety barrier front ok", ["plc.barrier_front_ok"]),
    ("Safety barrier rear ok", ["plc.barrier_rear_ok"]),
    ("Button pressed", ["plc.button_pressed"]),
]
ALL_OFF = {name: False for _, names in TRANSPORT_STEPS for name in names}


@pytest.fixture(scope="module")
def cfg() -> MachineConfig:
    return load_machine(MACHINE_FILE)


class _NoArea:
    """SignalReader's shared area, unused here: only the names of the signals are wanted."""

    def reader(self, name: str) -> None:
        return None


def machine_signals(cfg: MachineConfig) -> set[str]:
    """The signal names the controller's logic publishes for this machine, as it checks conditions."""
    return SignalReader(cfg, _NoArea()).known()


class Alarms(list):
    """Records raise_alarm(alarm_id, detail) calls."""

    def __call__(self, alarm_id: str, detail: str) -> None:
        self.append((alarm_id, detail))


@pytest.fixture
def alarms() -> Alarms:
    return Alarms()


@pytest.fixture
def runner(cfg, alarms) -> ProcedureRunner:
    return ProcedureRunner(cfg.procedure, alarms, machine_signals(cfg), cfg.source)


def _replace_step(cfg: MachineConfig, proc_index: int, step_index: int, **changes) -> list:
    procs = list(cfg.procedure)
    steps = list(procs[proc_index].step)
    steps[step_index] = dataclasses.replace(steps[step_index], **changes)
    procs[proc_index] = dataclasses.replace(procs[proc_index], step=steps)
    return procs


def test_the_shipped_procedures_compile_against_the_machines_signals(runner, cfg):
    assert runner.ids == ("transport", "startup", "pump_warmup")
    assert [p.title for p in cfg.procedure] == ["TRANSPORT PHASE", "MACHINE START-UP", "PUMP WARM-UP"]
    assert len(cfg.procedure[0].step) == 11
    idle = runner.state()
    assert (idle.id, idle.state, idle.step, idle.steps, idle.seq) == ("", "idle", -1, [], 0)


def test_a_bad_condition_fails_at_construction_naming_file_procedure_step_and_column(cfg, alarms):
    procs = _replace_step(cfg, 0, 2, condition="din.mains_on and plc.mains_of")
    with pytest.raises(ConditionError) as info:
        ProcedureRunner(procs, alarms, machine_signals(cfg), cfg.source)
    msg = str(info.value)
    assert msg.startswith(f"{cfg.source}: [[procedure]] #1 (transport) step #3 condition: column 18: unknown signal 'plc.mains_of'")
    assert "did you mean 'plc.mains_on'" in msg and "din.*, plc.*" in msg and "pump_pressure" in msg


def test_a_step_with_neither_condition_nor_action_fails_at_construction(cfg, alarms):
    procs = _replace_step(cfg, 2, 0, action="")
    with pytest.raises(ConditionError, match=r"\[\[procedure\]\] #3 \(pump_warmup\) step #1: the step needs a condition"):
        ProcedureRunner(procs, alarms)


def test_walking_the_transport_procedure_ticks_off_each_step_in_order(runner, cfg, alarms):
    signals = dict(ALL_OFF)
    runner.start("transport")
    assert runner.running and runner.state().seq == 1
    seq = 1
    now = 0.0
    for index, (text, names) in enumerate(TRANSPORT_STEPS):
        now += 1.0
        assert runner.scan(signals, now) is False  # nothing met yet: nothing published
        st = runner.state()
        assert (st.id, st.title, st.state, st.step, st.seq) == ("transport", "TRANSPORT PHASE", "running", index, seq)
        assert st.steps[index].text == text and st.steps[index].state == "awaited"
        assert st.instruction == cfg.procedure[0].step[index].instruction != ""
        assert [s.state for s in st.steps] == ["done"] * index + ["awaited"] + ["pending"] * (10 - index)
        for name in names[:-1]:  # a step needing two signals waits for both
            signals[name] = True
            assert runner.scan(signals, now) is False and runner.state().step == index
        signals[names[-1]] = True
        assert runner.scan(signals, now) is True
        seq += 1
        assert runner.state().seq == seq
    st = runner.state()
    assert (st.state, st.step, st.instruction) == ("done", -1, "")
    assert [s.state for s in st.steps] == ["done"] * 11
    assert not runner.running and runner.done("transport")
    assert alarms == []


def test_steps_already_met_complete_together_in_one_scan(runner):
    signals = dict(ALL_OFF)
    for _, names in TRANSPORT_STEPS[:6]:
        signals.update(dict.fromkeys(names, True))
    runner.start("transport")
    assert runner.scan(signals, 0.0) is True
    st = runner.state()
    assert st.step == 6 and st.seq == 2  # six steps, one published change
    assert st.steps[6].text == "Transport system ready" and st.instruction.startswith("Wait for the transport system")
    assert runner.scan({k: True for k in ALL_OFF}, 0.1) is True
    assert runner.state().state == "done" and runner.state().seq == 3


def test_pump_warmup_waits_for_the_operators_confirmations(runner):
    runner.start("pump_warmup")
    ready = {"plc.pump_running": True, "pump_pressure": 3800.0}
    assert runner.scan(ready, 0.0) is False  # a confirm step does not complete on signals
    st = runner.state()
    assert st.step == 0 and st.steps[0].action == "confirm"
    assert st.instruction == "Move the head over the catcher tank and confirm"
    runner.confirm()
    assert runner.state().step == 1 and runner.state().seq == 2
    assert runner.scan(ready, 0.1) is True  # pump running and both pressures: three steps in one scan
    st = runner.state()
    assert st.step == 4 and st.steps[4].text == "Jet test" and st.state == "running"
    runner.confirm()
    assert runner.state().state == "done" and runner.done("pump_warmup")


def test_pressure_steps_follow_the_pressure_as_it_rises(runner):
    runner.start("pump_warmup")
    runner.confirm()
    for pressure, awaited in ((0.0, 1), (500.0, 2), (1000.0, 3), (3600.0, 3), (3650.0, 4)):
        runner.scan({"plc.pump_running": pressure > 0, "pump_pressure": pressure}, pressure / 1000.0)
        assert runner.state().step == awaited, pressure


def test_a_timeout_raises_the_steps_alarm_once_and_the_step_can_still_complete(cfg, alarms):
    procs = _replace_step(cfg, 0, 0, timeout_alarm="press_button", timeout_s=30.0)
    runner = ProcedureRunner(procs, alarms, machine_signals(cfg), cfg.source)
    runner.start("transport")
    assert runner.scan(ALL_OFF, 100.0) is False  # the step's clock starts at the first scan
    assert runner.scan(ALL_OFF, 129.9) is False and alarms == []
    assert runner.scan(ALL_OFF, 130.0) is True
    assert alarms == [(
        "press_button",
        "procedure 'transport' (TRANSPORT PHASE) step 1/11 (Emergency stop released) not completed after 30 s: "
        "Release every emergency stop button",
    )]
    st = runner.state()
    assert (st.state, st.step, st.steps[0].state, st.seq) == ("timed_out", 0, "timed_out", 2)
    assert runner.running
    assert runner.scan(ALL_OFF, 500.0) is False and len(alarms) == 1  # raised once
    assert runner.scan({**ALL_OFF, "din.estop_ok": True}, 501.0) is True
    st = runner.state()
    assert (st.state, st.step, st.steps[0].state, st.steps[1].state) == ("running", 1, "done", "awaited")
    # the next step's clock starts when it becomes awaited: 120 s from 501 s
    assert runner.scan({**ALL_OFF, "din.estop_ok": True}, 620.9) is False
    assert runner.scan({**ALL_OFF, "din.estop_ok": True}, 621.0) is True
    assert alarms[-1][0] == "procedure_timeout" and "step 2/11 (Safety doors closed)" in alarms[-1][1]


def test_a_step_without_timeout_waits_forever_without_alarm(runner, alarms):
    runner.start("pump_warmup")
    runner.scan({}, 0.0)
    assert runner.scan({}, 1e6) is False and alarms == []


def test_stop_raises_procedure_stop_and_end_closes_the_window(runner, alarms):
    runner.start("transport")
    runner.scan({**ALL_OFF, "din.estop_ok": True}, 0.0)
    runner.stop()
    st = runner.state()
    assert (st.state, st.step, st.seq) == ("stopped", -1, 3)
    assert [s.state for s in st.steps[:3]] == ["done", "pending", "pending"]
    assert alarms == [(
        "procedure_stop", "procedure 'transport' (TRANSPORT PHASE) step 2/11 (Safety doors closed) stopped by the operator",
    )]
    assert not runner.running and not runner.done("transport")
    assert runner.scan({k: True for k in ALL_OFF}, 1.0) is False  # a stopped procedure does not advance
    runner.end()
    st = runner.state()
    assert (st.id, st.state, st.step, st.steps, st.instruction, st.seq) == ("", "idle", -1, [], "", 4)


def test_end_closes_a_finished_procedure_and_another_may_start(runner):
    runner.start("startup")
    runner.scan({"din.estop_ok": True, "din.mains_on": True, "plc.plc_running": True, "plc_link": True,
                 "drives_on": True, "homed": True}, 0.0)
    assert runner.state().state == "done" and runner.done("startup")
    runner.end()
    assert runner.state().state == "idle"
    runner.start("pump_warmup")
    assert runner.state().id == "pump_warmup" and not runner.state().by_cycle
    assert runner.done("startup")  # the last run of startup still counts as completed


def test_a_procedure_the_automatic_cycle_starts_says_so_to_the_screen(runner):
    runner.start("transport", by_cycle=True)
    assert runner.state().by_cycle, "its window does not keep the screen once done: the cycle goes on"


def test_starting_again_forgets_that_the_last_run_completed(runner):
    runner.start("pump_warmup")
    for _ in range(2):
        runner.confirm()
        runner.scan({"plc.pump_running": True, "pump_pressure": 4000.0}, 0.0)
    assert runner.done("pump_warmup")
    runner.start("pump_warmup")  # the window may be reopened straight from done
    assert not runner.done("pump_warmup") and runner.state().step == 0


def test_unknown_procedure_is_refused_listing_the_known_ones(runner):
    with pytest.raises(CommandRefused, match=r"unknown procedure 'transprt'; known: transport, startup, pump_warmup"):
        runner.start("transprt")
    assert runner.state().seq == 0


def test_start_while_another_runs_is_refused(runner):
    runner.start("transport")
    with pytest.raises(CommandRefused, match=r"cannot start procedure 'startup': procedure 'transport' .* is running"):
        runner.start("startup")
    with pytest.raises(CommandRefused, match=r"procedure 'transport' \(TRANSPORT PHASE\) is already running"):
        runner.start("transport")
    assert runner.state().id == "transport" and runner.state().seq == 1


def test_confirm_on_a_condition_step_is_refused(runner):
    runner.start("transport")
    with pytest.raises(CommandRefused, match=r"step 1 \(Emergency stop released\) .* completes by its condition 'din.estop_ok'"):
        runner.confirm()
    assert runner.state().step == 0 and runner.state().seq == 1


def test_end_while_running_is_refused(runner):
    runner.start("transport")
    with pytest.raises(CommandRefused, match="cannot end procedure 'transport' while it runs; stop it first"):
        runner.end()
    assert runner.running


def test_commands_with_no_procedure_are_refused(runner):
    for command, reason in ((runner.confirm, "nothing to confirm"), (runner.stop, "nothing to stop"),
                            (runner.end, "no procedure window to end")):
        with pytest.raises(CommandRefused, match=reason):
            command()
    assert runner.state().seq == 0


def test_done_steps_stay_done_and_still_holds_lists_those_no_longer_met(runner):
    runner.start("transport")
    all_on = {k: True for k in ALL_OFF}
    runner.scan(all_on, 0.0)
    assert runner.still_holds(all_on) == []
    dropped = {**all_on, "din.doors_closed": False, "plc.mains_on": False}
    assert runner.scan(dropped, 1.0) is False
    assert [s.state for s in runner.state().steps] == ["done"] * 11  # the list records what was checked
    assert runner.still_holds(dropped) == [(1, "Safety doors closed"), (2, "Machine mains on")]
    runner.end()
    assert runner.still_holds(dropped) == []  # no window
    assert runner.still_holds(dropped, "transport") == [(1, "Safety doors closed"), (2, "Machine mains on")]


def test_still_holds_ignores_steps_not_yet_done_and_confirm_steps(runner):
    runner.start("pump_warmup")
    runner.confirm()
    runner.scan({"plc.pump_running": True, "pump_pressure": 1100.0}, 0.0)
    assert runner.state().step == 3
    assert runner.still_holds({"plc.pump_running": True, "pump_pressure": 900.0}) == [(2, "Low pressure reached")]
    assert runner.still_holds({}) == [(1, "Pump running"), (2, "Low pressure reached")]  # missing signals do not hold


def test_state_is_republished_only_on_change(runner):
    runner.start("transport")
    first = runner.state()
    assert runner.scan(ALL_OFF, 0.0) is False
    assert runner.state() is first  # unchanged: the same message, same seq
    runner.scan({**ALL_OFF, "din.estop_ok": True}, 0.1)
    assert runner.state() is not first and runner.state().seq == first.seq + 1
