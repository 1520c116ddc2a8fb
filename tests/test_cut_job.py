"""The cutting job over Zenoh, in the whole controller (PLC simulator on a pty, virtual clock): the lock
holder chooses material, thickness and quality for the loaded program; the planned cycle time is
made again with the model; what the library cannot answer is refused with the reason and changes
nothing; the choice is remembered per program and comes back when the program is loaded again; a
run's job record keeps the job and its planned time; nothing is changed during the cycle."""

from __future__ import annotations

from cnc.bus.keys import Keys
from cnc.bus.messages import (
    CalibrationLadder, CalibrationRecord, CycleStart, LoadProgram, MaterialList, SetCut, SetMode,
)
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.data.layout import PlannerState, RunResult
from cnc.gateway.jobs import JobHistory, jobs_path
from cnc.logic.states import CyclePhase, MachineState

from .conftest import NEAR_HOME, full_controller, logic, machine_config, press_button_when_asked, reset_and_home
from .test_cut_model import hide_library
from .test_logic_process import jet_open
from .test_zenoh_interface import get

PART = """(a part, no cutting job of its own)
G21 G90 G64 P0.05 F6000
G0 X100 Y100
M3
G1 X160
G1 Y140
G2 X150 Y150 R10
G1 X100
G1 Y100
M5
G0 X60 Y60
M2
"""


def planned(sup) -> float:
    sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 60.0, "the cycle time to be planned")
    return sup.motion()["planned_s"]


def test_the_cutting_job_is_chosen_over_zenoh_remembered_per_program_and_kept_in_the_job_record(tmp_path):
    library = hide_library(tmp_path / "materials")
    config = machine_config(**NEAR_HOME, **{"cutting.materials_dir": str(library)})
    with full_controller(config, tmp_path / "history.sqlite") as sup:
        programs = tmp_path / "programs"
        programs.mkdir(exist_ok=True)
        (programs / "part.ngc").write_text(PART)
        (programs / "other.ngc").write_text(PART.replace("(a part", "(another part"))
        keys = Keys(config.zenoh.key_prefix, config.machine.name)
        session = open_client([config.zenoh.listen[0]])
        op = OperatorStation(session, keys, "op")
        try:
            listing = get(session, keys.materials, MaterialList)
            assert listing.directory == str(library) and not listing.error
            (hide,) = listing.entries
            assert (hide.id, hide.thicknesses_mm, hide.corners) == ("hide", [2.0, 4.0], True)
            assert hide.speeds_mm_min[0] == [6000.0, 4800.0, 3600.0, 2400.0, 1200.0]
            (library / "broken.toml").write_text("[material]\nname = 1\n")
            listing = get(session, keys.materials, MaterialList)
            assert [e.id for e in listing.entries] == ["hide"] and "broken.toml" in listing.error, "named; the rest listed"

            assert "take it first" in op.request(SetCut("hide", 2.0, 3)).reason, "the lock, as for any command"
            assert op.take_lock().ok
            assert "no program is loaded" in op.request(SetCut("hide", 2.0, 3)).reason
            reset_and_home(sup, op.request)
            sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                           60.0, "homing")
            assert op.request(LoadProgram("part.ngc")).ok
            at_f = planned(sup)
            assert sup.motion()["cut"] == ""

            for wrong, why in ((SetCut("steel", 2.0, 3), "material 'steel' is not in the library"),
                               (SetCut("../materials/hide", 2.0, 3), "'../materials/hide' is not a material id"),
                               (SetCut("hide", 9.0, 3), "thickness 9 mm is outside its chart (2 to 4 mm)"),
                               (SetCut("hide", 2.0, 7), "quality 7 is not one of 1 to 5"),
                               (SetCut("hide", 2.0, 3, mode="fast"), "mode 'fast' is not one of: quality, feed")):
                reply = op.request(wrong)
                assert not reply.ok and why in reply.reason, reply
                assert sup.motion()["cut"] == "" and sup.motion()["planned_s"] == at_f, "a refusal changes nothing"

            reply = op.request(SetCut("hide", 2.0, 3))
            assert reply.ok and reply.reason == "hide 2 mm quality 3, by the operator", reply
            modelled = planned(sup)
            assert modelled > at_f * 1.3 and sup.motion()["cut"] == "hide 2 mm quality 3, by the operator"

            assert op.request(LoadProgram("other.ngc")).ok and sup.motion()["cut"] == "", "another program: its own"
            assert op.request(LoadProgram("part.ngc")).ok
            assert sup.motion()["cut"] == "hide 2 mm quality 3, by the operator", "remembered for part.ngc"
            assert planned(sup) == modelled

            assert op.request(SetMode("AUTO")).ok
            assert op.request(CycleStart(cycles=1)).ok
            press_button_when_asked(sup, lambda: jet_open(sup), 60.0, "the cut under way")
            reply = op.request(SetCut("hide", 2.0, 5))
            assert not reply.ok and "during the automatic cycle (CUTTING phase)" in reply.reason, reply
            sup.wait_until(lambda: logic(sup)["phase"] == CyclePhase.NONE and logic(sup)["state"] == MachineState.READY,
                           120.0, "the cycle to its end")
            assert sup.motion()["run_result"] == RunResult.DONE
            jobs = JobHistory(jobs_path(tmp_path / "history.sqlite"), readonly=True)
            sup.wait_until(lambda: jobs.page().entries, 10.0, "the job record")
            job = jobs.page().entries[0]
            assert job.cut == "hide 2 mm quality 3, by the operator" and job.planned_s == modelled
            assert abs(job.cycle_time_s - modelled) < 0.05 * modelled, (job.cycle_time_s, modelled)
            jobs.close()

            assert op.request(SetCut("")).reason == "part.ngc cuts at its programmed feed"
            assert planned(sup) == at_f
            assert op.request(LoadProgram("part.ngc")).ok and sup.motion()["cut"] == "", "and that is remembered too"
        finally:
            op.close()
            session.close()


def test_a_material_is_calibrated_over_zenoh_ladder_first_then_what_the_operator_judged(tmp_path):
    """The guided calibration: the ladder made for an uncalibrated material, checked, stored and loaded
    at its programmed feeds; what the cut showed recorded into the material's file; the material can
    then be chosen for a job. What cannot be is refused with the reason, and nothing is written."""
    library = hide_library(tmp_path / "materials")
    (library / "felt.toml").write_text('[material]\nname = "Felt"\nkind = "water"\nsource = "calibrate it"\n'
                                        '[quality]\ncorner_mm = [0.4, 0.3, 0.2, 0.1, 0.05]\n')
    config = machine_config(**NEAR_HOME, **{"cutting.materials_dir": str(library)})
    with full_controller(config, tmp_path / "history.sqlite") as sup:
        keys = Keys(config.zenoh.key_prefix, config.machine.name)
        session = open_client([config.zenoh.listen[0]])
        op = OperatorStation(session, keys, "op")
        try:
            assert op.take_lock().ok
            for wrong, why in ((CalibrationLadder("wool", 3.0, 600.0, 6000.0), "material 'wool' is not in the library"),
                               (CalibrationLadder("felt", 3.0, 6000.0, 600.0), "must rise from above 0"),
                               (CalibrationLadder("felt", 3.0, 600.0, 90000.0), "beyond this machine's"),
                               (CalibrationLadder("felt", 3.0, 600.0, 6000.0, rungs=1), "rungs 1 must be 2 to 40")):
                reply = op.request(wrong)
                assert not reply.ok and why in reply.reason, reply
            assert not (tmp_path / "programs").exists() or not list((tmp_path / "programs").glob("ladder-*"))

            reply = op.request(CalibrationLadder("felt", 3.0, 600.0, 6000.0, rungs=5, pierce_s=0.5))
            assert reply.ok and reply.reason.startswith("ladder-felt-3mm.ngc loaded: 5 rungs at 600, 1067, 1897, 3374, 6000"), reply
            assert sup.motion()["program_name"] == "ladder-felt-3mm.ngc" and sup.motion()["cut"] == ""
            text = (tmp_path / "programs" / "ladder-felt-3mm.ngc").read_text()
            assert text.count("(MSG,rung") == 5 and "F6000.0" in text

            bad = op.request(CalibrationRecord("felt", 3.0, 3374.0, [3374.0, 1897.0, 2400.0, 1067.0, 600.0], 0.5, 0.2))
            assert not bad.ok and "quality 3: 2400 is faster than quality 2's 1897" in bad.reason, bad
            assert "[[chart]]" not in (library / "felt.toml").read_text(), "nothing written"
            reply = op.request(CalibrationRecord("felt", 3.0, 3374.0, [3374.0, 2500.0, 1897.0, 1067.0, 600.0], 0.5, 0.2,
                                                 lag_mm=[0.9, 0.6, 0.45, 0.25, 0.1]))
            assert reply.ok and reply.reason == "felt: 3 mm recorded; its chart covers 3 mm", reply
            felt = {e.id: e for e in get(session, keys.materials, MaterialList).entries}["felt"]
            assert felt.thicknesses_mm == [3.0] and felt.corners and felt.speeds_mm_min[0][1] == 2500.0
            assert "calibrated 3 mm by local at station op" in felt.source

            (tmp_path / "programs" / "part.ngc").write_text(PART)
            assert op.request(LoadProgram("part.ngc")).ok
            reply = op.request(SetCut("felt", 3.0, 2))
            assert reply.ok and reply.reason == "felt 3 mm quality 2, by the operator", reply
        finally:
            op.close()
            session.close()
