"""Control parameters: the registry from the machine file, online changes over Zenoh applied by the
servo at a tick boundary, refusals (range, lock, state), and saving into the machine file."""

from __future__ import annotations

import shutil

import pytest

from cnc.bus.keys import Keys
from cnc.bus.messages import CycleStart, SetMode
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.config import ConfigError, load_machine
from cnc.data.layout import PlannerState
from cnc.logic.states import MachineState
from cnc.params import ParamError, find, registry, save, values_of
from cnc.runtime.supervisor import Supervisor

from .conftest import MACHINE_FILE, NEAR_HOME, MID_TRAVEL, free_port, full_controller, logic, press_button_when_asked, reset_and_home
from .test_zenoh_interface import PART


def test_the_registry_takes_name_description_unit_and_range_from_the_machine_file_options():
    config = load_machine(MACHINE_FILE)
    specs = registry(config)
    kp = find(specs, "axis.y.kp_1_s")
    assert (kp.unit, kp.lo, kp.hi, kp.owner, kp.when) == ("1/s", 0.0, 10000.0, "servo", "always")
    assert "proportional gain" in kp.description
    tol = find(specs, "gcode.default_tolerance_mm")
    assert tol.owner == "planner" and tol.when == "idle" and tol.effect == "the next program loaded"
    assert [s.index for s in specs] == list(range(len(specs)))
    with pytest.raises(ParamError, match="out of range: allowed 0 to 10000 1/s"):
        kp.check(10001.0, "IDLE")
    with pytest.raises(ParamError, match="not a finite number"):
        kp.check(float("nan"), "IDLE")
    with pytest.raises(ParamError, match="not changeable while the planner is RUNNING"):
        tol.check(0.1, "RUNNING")
    tol.check(0.1, "HELD")
    with pytest.raises(ParamError, match="no control parameter 'axis.z.kp_1_s'"):
        find(specs, "axis.z.kp_1_s")


def test_saving_changes_only_the_values_and_keeps_the_files_layout_and_comments(tmp_path):
    machine = tmp_path / "machine.toml"
    shutil.copy(MACHINE_FILE, machine)
    before = machine.read_text()
    written = save(machine, {(("axis", "x"), "kp_1_s"): 125.5, (("planner",), "jog_velocity_mm_s"): 42.0,
                             (("jet",), "off_delay_s"): 0.025})
    assert written == ["axis.x.kp_1_s", "planner.jog_velocity_mm_s", "jet.off_delay_s"]
    config = load_machine(machine)
    assert config.axis["x"].kp_1_s == 125.5 and config.axis["y"].kp_1_s == load_machine(MACHINE_FILE).axis["y"].kp_1_s
    assert config.planner.jog_velocity_mm_s == 42.0 and config.jet.off_delay_s == 0.025
    after = machine.read_text()
    changed = [(a, b) for a, b in zip(before.splitlines(), after.splitlines()) if a != b]
    assert all("kp_1_s" in a or "off_delay_s" in a or "jog_velocity" in a for a, _ in changed), changed
    assert (tmp_path / "machine.toml.bak").read_text() == before
    assert sum(line.startswith("#") for line in after.splitlines()) == sum(line.startswith("#") for line in before.splitlines())
    with pytest.raises(ConfigError, match=r"\[axis.x\] kp_1_s"):
        save(machine, {(("axis", "x"), "kp_1_s"): -1.0})
    assert load_machine(machine).axis["x"].kp_1_s == 125.5, "a refused save leaves the file as it was"


def test_an_engineer_tunes_the_gains_online_while_the_program_runs_and_saves_them(tmp_path):
    machine = tmp_path / "machine.toml"
    shutil.copy(MACHINE_FILE, machine)
    config = load_machine(machine, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **MID_TRAVEL, **NEAR_HOME})
    keys = Keys(config.zenoh.key_prefix, config.machine.name)
    with full_controller(config, tmp_path / "history.sqlite") as sup:
        session = open_client([config.zenoh.listen[0]])
        station = OperatorStation(session, keys, "tuner")
        try:
            listed = station.params()
            assert [p.name for p in listed.params] == [s.name for s in registry(config)] and listed.seq == 0
            assert [p.value for p in listed.params] == values_of(config, registry(config))
            [unknown] = list(session.get(keys.param("axis.z.kp_1_s"), timeout=5.0))
            assert unknown.ok is None and "no control parameter 'axis.z.kp_1_s'" in unknown.err.payload.to_string()
            refused = station.set_param("axis.x.kp_1_s", 150.0)
            assert not refused.ok and refused.reason.startswith("param axis.x.kp_1_s: ") and "lock" in refused.reason
            assert station.take_lock().ok
            out = station.set_param("axis.x.kp_1_s", 20000.0)
            assert not out.ok and "out of range: allowed 0 to 10000 1/s" in out.reason
            assert not station.set_param("axis.x.no_such_gain", 1.0).ok

            reset_and_home(sup, station.request)
            sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY, 60.0, "homing")
            assert station.upload("part.ngc", PART).ok and station.request(SetMode("AUTO")).ok
            assert station.request(CycleStart(1)).ok
            press_button_when_asked(sup, lambda: sup.motion()["state"] == PlannerState.RUNNING, 60.0, "the cut")
            done = station.set_param("axis.x.kp_1_s", 150.0)
            assert done.ok and "applied by the servo at tick" in done.reason, done.reason
            tick = int(done.reason.split("at tick ")[1].split(";")[0])
            servo = sup.servo()
            assert servo["params_change"] == 1 and servo["params_tick"] == tick
            busy = station.set_param("planner.arc_normal_share", 0.4)
            assert not busy.ok and "not changeable while the planner is RUNNING" in busy.reason
            assert station.set_param("axis.y.following_error_limit_mm", 0.4).ok
            press_button_when_asked(sup, lambda: logic(sup)["cycles_done"] == 1, 60.0, "the cycle's end")
            assert sup.servo()["fault"] == 0, "retuned mid-cut without a trip"
            idle = station.set_param("planner.arc_normal_share", 0.4)
            assert idle.ok and "applied by the planner" in idle.reason and sup.motion()["params_change"] == 3

            now = {p.name: p for p in station.params().params}
            assert now["axis.x.kp_1_s"].value == 150.0 and now["axis.x.kp_1_s"].file_value == config.axis["x"].kp_1_s
            saved = station.save_params()
            assert saved.ok and "saved 3 parameter(s)" in saved.reason, saved.reason
            on_disk = load_machine(machine)
            assert on_disk.axis["x"].kp_1_s == 150.0 and on_disk.axis["y"].following_error_limit_mm == 0.4
            assert on_disk.planner.arc_normal_share == 0.4
            assert {p.name: p.file_value for p in station.params().params}["axis.x.kp_1_s"] == 150.0
        finally:
            station.close()
            session.close()


def test_a_change_for_a_process_that_is_not_running_waits_for_its_start_and_a_running_one_applies_it(tmp_path):
    """Whether the owner runs is read from its heartbeat slot's pid, not asked of Zenoh."""
    config = load_machine(MACHINE_FILE, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"], **NEAR_HOME})
    keys = Keys(config.zenoh.key_prefix, config.machine.name)
    without_planner = ("hardware", "servo", "gateway")
    with Supervisor(config, clock="virtual", processes=without_planner, history_path=tmp_path / "h.sqlite"):
        session = open_client([config.zenoh.listen[0]])
        station = OperatorStation(session, keys, "tuner")
        try:
            assert station.take_lock().ok
            waiting = station.set_param("planner.arc_normal_share", 0.4)
            assert waiting.ok and "the planner is not running: it applies it when it starts" in waiting.reason, waiting
            applied = station.set_param("axis.x.kp_1_s", 150.0)
            assert applied.ok and "applied by the servo at tick" in applied.reason, applied
        finally:
            station.close()
            session.close()
