"""The simulated machine's inputs over Zenoh and from a shell: `<root>/sim` lists them, `cmd/sim`
changes one behind the command lock like every command, each change is an info entry in the
alarm history (before what it causes), and `waterjet sim` does the same from a shell."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from cnc.alarms import AlarmHistory
from cnc.bus.keys import Keys
from cnc.bus.messages import CycleStart, SimInput, SimInputs, decode
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.data.layout import LinkState
from cnc.logic.states import CyclePhase
from cnc.siminputs import INPUTS, SimInputError, check

from .conftest import MACHINE_FILE, REPO, logic
from .test_logic_process import Events, ready_in_auto


@pytest.fixture
def station(plc_controller):
    sup = plc_controller
    session = open_client([sup.config.zenoh.listen[0]])
    op = OperatorStation(session, Keys(sup.config.zenoh.key_prefix, sup.config.machine.name), "bench")
    yield op
    session.close()


def listing(op: OperatorStation) -> dict[str, float]:
    [reply] = list(op.session.get(op.keys.sim, timeout=10.0))
    return {i.name: i.value for i in decode(reply.ok.payload.to_bytes(), SimInputs).inputs}


def history(sup) -> list:
    with AlarmHistory(sup.history_path, readonly=True) as h:
        return h.after(0, 1000).entries


def test_every_input_is_listed_with_its_value_and_changed_behind_the_lock(plc_controller, station):
    sup, op = plc_controller, station
    events = Events(sup)
    assert listing(op) == {spec.name: (1.0 if spec.name == "friction" else 0.0) for spec in INPUTS}
    refused = op.request(SimInput("doors_open", 1))
    assert not refused.ok and "lock" in refused.reason and sup.sim.get("doors_open") == 0, "no lock, no change"
    assert op.take_lock().ok
    reply = op.request(SimInput("doors_open", 1))
    assert reply.ok and reply.reason == "doors_open 0 -> 1"
    sup.wait_until(lambda: 2292 in events.codes(), 10.0, "the door alarm")
    assert listing(op)["doors_open"] == 1.0 and sup.sim.get("doors_open") == 1
    entries = history(sup)
    note = next(k for k, e in enumerate(entries) if e.code == 3004)
    door = next(k for k, e in enumerate(entries) if e.code == 2292)
    assert entries[note].detail == "simulator: doors_open set to 1 by local at station bench" and note < door, \
        "the change is in the history before what it caused"
    assert op.request(SimInput("doors_open", 0)).ok
    sup.wait_until(lambda: 2292 in events.codes("cleared"), 10.0, "the door closed")
    events.close()


@pytest.mark.parametrize("name, value, why", [
    ("door", 1, "no simulated input 'door' (inputs: transport_button, doors_open"),
    ("doors_open", 0.5, "doors_open is a switch: 0 or 1, not 0.5"),
    ("friction", 101, "friction: 101 is outside 0 to 100 x"),
    ("estop", -1, "estop: -1 is outside 0 to 1"),
])
def test_a_change_it_cannot_make_is_refused_naming_why_and_nothing_changes(plc_controller, station, name, value, why):
    sup, op = plc_controller, station
    assert op.take_lock().ok
    before = listing(op)
    reply = op.request(SimInput(name, value))
    assert not reply.ok and why in reply.reason
    assert listing(op) == before and not any(e.code == 3004 for e in history(sup))


def test_each_input_reaches_the_board_or_the_plc_and_the_alarm_it_causes(plc_controller, station):
    sup, op = plc_controller, station
    events = Events(sup)
    assert op.take_lock().ok
    for name, alarm in (("estop", 1001), ("mains_off", 1002)):
        assert op.request(SimInput(name, 1)).ok
        sup.wait_until(lambda: alarm in events.codes(), 10.0, f"{name}'s alarm")
        assert op.request(SimInput(name, 0)).ok
        sup.wait_until(lambda: alarm in events.codes("cleared"), 10.0, f"{name} undone")
    for name, signal in (("barrier_front", "barrier_front_ok"), ("barrier_rear", "barrier_rear_ok"),
                         ("pump_fault", "pump_fault")):
        assert op.request(SimInput(name, 1)).ok
        expected = 0.0 if signal.endswith("_ok") else 1.0
        sup.wait_until(lambda: sup.plc_sim.inputs()[signal] == expected, 10.0, f"the PLC's {signal} after {name} 1")
        assert op.request(SimInput(name, 0)).ok
        sup.wait_until(lambda: sup.plc_sim.inputs()[signal] == 1.0 - expected, 10.0, f"the PLC's {signal} after {name} 0")
    assert op.request(SimInput("friction", 40)).ok
    assert list(sup.sim.get("friction_scale")) == [40.0] * len(sup.config.axis_names)
    assert op.request(SimInput("friction", 1)).ok
    assert op.request(SimInput("plc_link_cut", 1)).ok
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] != LinkState.OK, 20.0, "the link lost")
    assert op.request(SimInput("plc_link_cut", 0)).ok
    sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 30.0, "the link back")
    notes = [e.detail for e in history(sup) if e.code == 3004]
    assert len(notes) == 2 * 2 + 3 * 2 + 2 + 2 and all(n.startswith("simulator: ") for n in notes)
    events.close()


def test_the_automatic_cycle_runs_to_the_end_with_the_transport_button_pressed_over_zenoh(plc_controller, station,
                                                                                         tmp_path):
    """No supervisor hook: a station follows the published procedure and, when its step asks for
    the transport station's button, presses it with cmd/sim."""
    sup, op = plc_controller, station
    events = Events(sup)
    ready_in_auto(sup, tmp_path)
    assert op.take_lock().ok
    assert op.request(CycleStart(cycles=1)).ok
    pressed_at: set[int] = set()  # the procedure changes (seq) a press answered
    phases = set()

    def step() -> bool:
        phases.add(CyclePhase(logic(sup)["phase"]))
        with events.lock:
            now = events.procedures[-1] if events.procedures else None
        if now is not None and now.state == "running" and now.instruction.startswith("Press the button") \
                and now.seq not in pressed_at:
            pressed_at.add(now.seq)
            assert op.request(SimInput("transport_button", 1)).ok
        lo = logic(sup)
        return lo["cycles_done"] == 1 and lo["phase"] == CyclePhase.NONE

    sup.wait_until(step, 120.0, "the cycle to the end")
    assert pressed_at and {CyclePhase.TRANSPORT, CyclePhase.CUTTING} <= phases
    assert any(e.detail.startswith("simulator: transport_button set to 1") for e in history(sup))
    events.close()


def test_waterjet_sim_lists_and_changes_the_inputs_from_a_shell(plc_controller):
    sup = plc_controller
    events = Events(sup)
    base = [sys.executable, "-m", "cnc.cli", "sim", "--machine", str(MACHINE_FILE), "--connect", sup.config.zenoh.listen[0]]
    listed = subprocess.run(base, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert listed.returncode == 0, listed.stderr
    assert [line.split()[0] for line in listed.stdout.splitlines()] == [spec.name for spec in INPUTS]
    changed = subprocess.run([*base, "doors_open", "on"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert changed.returncode == 0 and "doors_open 0 -> 1" in changed.stdout, changed.stderr
    sup.wait_until(lambda: 2292 in events.codes(), 10.0, "the door alarm")
    bad = subprocess.run([*base, "doors_open", "half"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "value 'half' is not a number" in bad.stderr
    refused = subprocess.run([*base, "friction", "500"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert refused.returncode == 1 and "friction: 500 is outside 0 to 100 x" in refused.stderr
    events.close()


def test_only_a_simulated_machine_has_simulator_inputs():
    from cnc.config import load_machine
    from cnc.siminputs import simulated_only

    config = load_machine(MACHINE_FILE)
    simulated_only(config)  # the shipped machine is the simulated one
    real = dataclasses.replace(config, board=dataclasses.replace(config.board, kind="pci-io"))
    with pytest.raises(SimInputError, match="board is 'pci-io', not the simulated one: it has no simulator inputs"):
        simulated_only(real)


def test_the_checks_name_the_input_and_its_range():
    assert check("friction", 50.0).unit == "x"
    with pytest.raises(SimInputError, match="transport_button: 2 is outside 0 to 1"):
        check("transport_button", 2.0)
    with pytest.raises(SimInputError, match="transport_button is a button: 0 or 1, not 0.5"):
        check("transport_button", 0.5)
