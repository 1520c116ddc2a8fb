"""Fault injection during a cut (issue 9): every fault of `cnc.faultinject.catalogue()` is put on
the simulated machine while it cuts; the jet closes and the axes stand still within the fault's
bounds in ticks, the right alarm is in the history, the supervisor restarts what it may, and the
machine is reset and cuts again. One controller for the module, on the virtual clock: each
recovery starts the next cut. The table of reactions is printed at the end of the run."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnc.alarms import AlarmHistory
from cnc.faultinject import (
    CUT_PROGRAM, SCENARIO_OVERRIDES, Fault, catalogue, cutting_now, inject_during_cut, ready_to_cut, recover, start_cut,
)
from cnc.supervisor import Supervisor

from .conftest import FAULT_REACTIONS, NEAR_HOME, fast_plant, machine_config

FAULTS = catalogue()
RESTARTABLE = [f for f in FAULTS if f.process != "hardware"]
HARDWARE = next(f for f in FAULTS if f.process == "hardware")


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("faults")
    (path / "cut.ngc").write_text(CUT_PROGRAM)
    return path


@pytest.fixture(scope="module")
def config():
    return machine_config(**{**NEAR_HOME, **SCENARIO_OVERRIDES})


@pytest.fixture(scope="module")
def cutting(config, workdir):
    """The controller with the PLC simulator, cutting the long frame."""
    with Supervisor(config, clock="virtual", history_path=workdir / "history.sqlite", plc_sim_times=fast_plant()) as sup:
        ready_to_cut(sup, workdir / "cut.ngc")
        start_cut(sup)
        yield sup


@pytest.mark.parametrize("fault", RESTARTABLE, ids=[f.name for f in RESTARTABLE])
def test_a_fault_during_a_cut_closes_the_jet_stops_the_axes_raises_its_alarm_and_the_machine_cuts_again(
        cutting, workdir, fault: Fault):
    sup = cutting
    if not cutting_now(sup):  # the cut the last recovery started ended (a fault of this host?): start another
        recover(sup, fault, workdir / "cut.ngc")
    reaction = inject_during_cut(sup, fault)
    FAULT_REACTIONS.append((reaction, fault))
    assert 0 <= reaction.jet_off_ticks <= fault.jet_ticks, f"jet closed after {reaction.jet_off_ticks} ticks"
    assert reaction.stopped_ticks <= fault.stop_ticks, f"axes still after {reaction.stopped_ticks} ticks"
    assert reaction.state.startswith(("FAULT", "ESTOP")), reaction.state
    if fault.process:
        assert reaction.restarted == f"{fault.process} restarted"
    if fault.process == "planner":  # its program went with it: the status must not offer a cycle start
        assert sup.motion()["program_name"] == "" and sup.motion()["program_hash"] == ""
    assert sup.failed is None
    recover(sup, fault, workdir / "cut.ngc")  # reset, and the program is started again: the jet is on, the head moves


def test_the_history_kept_every_entry_of_the_faults_in_sequence(cutting):
    with AlarmHistory(cutting.history_path, readonly=True) as history:
        page = history.after(0, 1000)
    seqs = [e.seq for e in page.entries]
    assert seqs == list(range(1, len(seqs) + 1)), "no entry lost across the restarts"
    lost = [e.detail for e in page.entries if e.code == 1098 and e.action == "raised"]
    for name in ("gateway", "logger", "plc_link", "planner", "logic", "servo"):
        assert any(d.startswith(f"{name} process exited with code -9; restarted") for d in lost), (name, lost)


def test_killing_the_hardware_server_ends_the_controller_and_a_new_one_resets_and_cuts(cutting, config, workdir):
    """The board's owner may not be restarted under a running servo: the supervisor gives up, the
    history says why, and a controller started again on the same history cuts again."""
    if not cutting_now(cutting):
        recover(cutting, HARDWARE, workdir / "cut.ngc")
    reaction = inject_during_cut(cutting, HARDWARE)
    FAULT_REACTIONS.append((reaction, HARDWARE))
    assert cutting.failed and "hardware process exited with code -9" in cutting.failed
    assert reaction.alarm == "1098 Controller process lost"
    cutting.stop()
    with Supervisor(config, clock="virtual", history_path=workdir / "history.sqlite", plc_sim_times=fast_plant()) as sup:
        with AlarmHistory(sup.history_path, readonly=True) as history:
            details = [e.detail for e in history.after(0, 1000).entries if e.code == 1098]
        assert any(d.startswith("hardware process exited with code -9; not restarted") for d in details)
        ready_to_cut(sup, workdir / "cut.ngc")
        start_cut(sup)
