"""No stale motion: a motion asked for before a stop or a fault never moves the machine after it;
stop and hold reach whatever the planner runs; a continuous jog is a dead-man's."""

from __future__ import annotations

import threading
import time

import pytest

from cnc.bus.messages import GoTo, Hold, Home, Jog, JogRefresh, LoadProgram, RestartAt, Stamp, Start, Stop
from cnc.data.layout import PlannerState, RunResult, ServoState
from cnc.planner.client import PlannerClient
from cnc.runtime.supervisor import MOTION_ONLY, Supervisor

from .conftest import enable_and_hold, home, machine_config, wait_planner_idle

NEAR_HOME = {"sim.axes.x.start_position_mm": 30.0, "sim.axes.y.start_position_mm": 30.0}


def slow_to_prepare(blocks: int = 100_000) -> str:
    """A program whose interpretation takes seconds (`blocks` parameter assignments, each through
    the general path: about 2 s per 100k) and whose first move is an R arc from wherever the head
    stands, so that a start after the head moved must interpret it again (its shape is no pure
    shift of the start: `planner/rebase.py`). Its motion is short."""
    return "\n".join(["G21 G90 G64 P0.05", "G2 X200 Y200 R900 F6000", "#1 = 0", *(["#1 = [#1 + 1]"] * blocks),
                      "M3", "G1 X220 Y200", "M5", "G0 X60 Y60", "M2", ""])


@pytest.fixture(scope="module")
def homed():
    with Supervisor(machine_config(**NEAR_HOME), clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        home(sup)
        yield sup


def test_a_motion_command_issued_before_a_stop_is_refused_and_nothing_moves(homed):
    sup = homed
    before = sup.stamp()
    sup.stop_motion()  # the commander decides a stop: everything issued before it is void
    here = list(sup.servo()["commanded_mm"])
    for command in (Jog("x", 20.0, stamp=before), GoTo({"x": 300.0}, stamp=before),
                    Home(["x"], stamp=before), JogRefresh(stamp=before)):
        reply = sup.planner.request(command)
        assert not reply.ok and "issued before the last stop" in reply.reason, (command, reply.reason)
    assert sup.fifo.fill() == 0 and sup.servo()["commanded_mm"] == here and sup.motion()["state"] == PlannerState.IDLE
    assert sup.planner.request(GoTo({"x": 40.0})).ok, "one issued now moves"
    wait_planner_idle(sup)


def test_only_the_commanders_token_moves_the_machine(homed):
    sup = homed
    outsider = PlannerClient(sup.router, sup.keys)  # no stamp: not the commander
    reply = outsider.request(GoTo({"x": 300.0}))
    assert not reply.ok and "not from the machine's commander" in reply.reason
    forged = Stamp(sup.stamp().token + 1, sup.stamp().epoch)
    reply = outsider.request(Jog("x", 20.0, stamp=forged))
    assert not reply.ok and "not from the machine's commander" in reply.reason
    assert outsider.request(Stop()).reason.endswith("nothing moves"), "a stop needs no stamp: anyone may stop"


def test_a_start_waiting_behind_a_long_replan_is_cancelled_by_a_stop(homed, tmp_path):
    """The head moved since the program was loaded, and the program is no pure shift of its start:
    the start interprets it again from where the head is (seconds, for this one). A stop that comes
    meanwhile is answered at once and the start never runs."""
    sup = homed
    path = tmp_path / "slow.ngc"
    path.write_text(slow_to_prepare())
    assert sup.planner.request(LoadProgram(str(path))).ok
    assert sup.planner.request(GoTo({"x": 45.0, "y": 45.0})).ok  # the head moves away: the start must plan again
    wait_planner_idle(sup)
    runs = sup.motion()["run_seq"]
    answers: dict[str, object] = {}
    starter = threading.Thread(target=lambda: answers.update(start=sup.planner.request(Start())))
    starter.start()
    time.sleep(0.2)  # the planner is in the start's interpretation (it takes seconds)
    t0 = time.monotonic()
    answers["stop"] = sup.planner.request(Stop())
    stop_s = time.monotonic() - t0
    starter.join(60.0)
    assert answers["stop"].ok and "cancelled" in answers["stop"].reason, answers["stop"]
    assert not answers["start"].ok and "cancelled by a stop" in answers["start"].reason, answers["start"]
    assert stop_s < 2.0, f"the stop waited {stop_s:.2f} s behind the planning"
    m = sup.motion()
    assert m["run_seq"] == runs and m["state"] == PlannerState.IDLE and sup.fifo.fill() == 0, "the start never ran"


def test_hold_stops_a_homing_and_a_jog_whatever_the_planner_runs(homed):
    sup = homed
    assert sup.planner.request(Home(["x"])).ok
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.HOMING and sup.servo()["state"] == ServoState.TRACKING,
                   10.0, "homing under way")
    reply = sup.planner.request(Hold())
    assert reply.ok and "homing stopped" in reply.reason
    m = wait_planner_idle(sup)
    assert "homing stopped by a hold" in m["error"]
    sup.wait_motion_done()
    home(sup, ["x"])  # and it homes again: a homed axis may be homed again
    assert sup.planner.request(Jog("y", 20.0)).ok
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.JOGGING, 10.0, "jogging")
    assert sup.planner.request(Hold()).ok
    wait_planner_idle(sup)


def test_a_continuous_jog_not_refreshed_stops_by_itself_and_a_refreshed_one_runs_on(homed):
    """The dead-man, on the virtual clock, where ticks run faster than the wall: a jog refreshed every
    100 ms of wall time runs on (the limit is waited for on both clocks), one not refreshed stops
    within jog_deadman_ms of wall time, having run at least that long in machine time."""
    sup = homed
    deadman_ms = sup.config.planner.jog_deadman_ms
    assert sup.planner.request(Jog("x", 10.0)).ok
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.JOGGING, 10.0, "jogging")
    ticks0 = sup.hw()["tick"]
    for _ in range(8):  # 0.8 s of refreshes: the jog goes on
        time.sleep(0.1)
        assert sup.planner.request(JogRefresh()).ok
        assert sup.motion()["state"] == PlannerState.JOGGING
    ran = sup.hw()["tick"] - ticks0
    assert ran * sup.config.timing.period_s > 3 * deadman_ms / 1000.0, "it ran well past one dead-man period"
    last = time.monotonic()
    tick_last = sup.hw()["tick"]
    m = wait_planner_idle(sup, 10.0)
    assert "dead-man" in m["event"]
    assert time.monotonic() - last >= deadman_ms / 1000.0 * 0.9
    assert (sup.hw()["tick"] - tick_last) * sup.config.timing.period_s >= deadman_ms / 1000.0
    assert sup.servo()["state"] == ServoState.HOLDING


def test_a_program_that_parks_on_the_travel_ends_runs_and_the_machine_goes_on(homed, tmp_path):
    """G0 X0 Y0 on a machine whose travel starts at 0: no soft-limit trip; the next program loads and
    starts from there; homing the homed axes again works."""
    sup = homed
    park = tmp_path / "park.ngc"
    park.write_text("G21 G90\nG0 X37.3 Y12.1\nG1 X0.7 Y0.3 F3000\nG0 X0 Y0\nM2\n")
    assert sup.planner.request(LoadProgram(str(park))).ok
    assert sup.planner.request(Start()).ok
    m = wait_planner_idle(sup)
    s = sup.servo()
    assert m["run_result"] == RunResult.DONE and s["fault"] == 0 and s["state"] == ServoState.HOLDING
    assert s["commanded_mm"] == pytest.approx([0.0, 0.0], abs=1e-9) and min(s["commanded_mm"]) >= 0.0
    again = tmp_path / "again.ngc"
    again.write_text("G21 G90\nG1 X10 Y10 F3000\nM2\n")
    reply = sup.planner.request(LoadProgram(str(again)))
    assert reply.ok, reply.reason
    assert sup.planner.request(Start()).ok
    assert wait_planner_idle(sup)["run_result"] == RunResult.DONE
    home(sup)
    assert sup.servo()["homed_mask"] == 0b11 and sup.servo()["fault"] == 0


def test_a_restart_being_prepared_answers_a_stop_at_once_and_never_runs(tmp_path):
    """A restart from inside the program makes its steps (and, when short, its timing) before it
    moves: on a slow machine more than a second for three parts. It does so on the helper, as a
    load does: a stop that comes meanwhile is answered before the start is, and the start is
    cancelled; nothing moves. The same restart, unhindered, then runs."""
    from .test_planner_overlap import _random_cam_parts
    from .test_recovery_cycle import SLOW_PLANNER, _moved_into_travel

    text, _ = _random_cam_parts(56, jet=True)
    path = tmp_path / "parts.ngc"
    path.write_text(_moved_into_travel(text))
    line = next(i for i, row in enumerate(text.splitlines(), 1) if row.startswith("M3")) + 1  # the first cut
    with Supervisor(machine_config(**NEAR_HOME, **SLOW_PLANNER), clock="virtual", processes=MOTION_ONLY) as sup:
        enable_and_hold(sup)
        home(sup)
        reply = sup.planner.request(LoadProgram(str(path)))
        assert reply.ok, reply.reason
        runs = sup.motion()["run_seq"]
        answers: list[tuple[str, object]] = []
        start = Start(restart=RestartAt("line", number=line))
        starter = threading.Thread(target=lambda: answers.append(("start", sup.planner.request(start))))
        starter.start()
        stops = []
        while starter.is_alive() and not any("cancelled" in r.reason for r in stops):
            stops.append(sup.planner.request(Stop()))  # "nothing to stop" until the start is being prepared
            answers.append(("stop", stops[-1]))
        starter.join(60.0)
        cancelled = [i for i, (what, r) in enumerate(answers) if what == "stop" and "cancelled" in r.reason]
        assert cancelled, f"no stop was answered while the restart was prepared: {answers}"
        assert cancelled[0] < [what for what, _ in answers].index("start"), "the stop waited behind the start"
        reply = dict(answers)["start"]
        assert not reply.ok and "cancelled by a stop" in reply.reason, reply
        m = sup.motion()
        assert m["run_seq"] == runs and m["state"] == PlannerState.IDLE and sup.fifo.fill() == 0, "the start never ran"
        reply = sup.planner.request(Start(restart=RestartAt("line", number=line)))
        assert reply.ok, reply.reason
        assert f"line {line}" in sup.motion()["event"], sup.motion()["event"]
        assert sup.planner.request(Stop()).ok
        assert wait_planner_idle(sup)["run_seq"] == runs + 1


def test_a_restart_placed_at_a_start_the_machine_cannot_have_is_refused_naming_start_mm(homed, tmp_path):
    """`RestartAt.start_mm` (where the interrupted run started) must give every axis a finite
    value: anything else is refused, naming the field and the axes, and nothing moves."""
    from cnc.bus.messages import CheckRestart

    sup = homed
    path = tmp_path / "rel.ngc"
    path.write_text("G21 G91 G64 P0.05\nG0 X10 Y10\nM3\nG1 X20 F1200\nM5\nM2\n")
    assert sup.planner.request(LoadProgram(str(path))).ok
    runs = sup.motion()["run_seq"]
    for bad in ((40.0,), (40.0, float("nan")), (40.0, 60.0, 0.0)):
        for command in (Start(restart=RestartAt("line", number=3, start_mm=bad)),
                        CheckRestart(RestartAt("line", number=3, start_mm=bad))):
            reply = sup.planner.request(command)
            assert not reply.ok and "start_mm" in reply.reason, (bad, reply)  # NaN: not JSON, refused by the decoder
            assert "one per axis (X, Y)" in reply.reason or "Expected `float`" in reply.reason, (bad, reply)
    reply = sup.planner.request(CheckRestart(RestartAt("line", number=4, start_mm=(40.0, 60.0))))
    assert reply.ok and "run from line 4" in reply.reason, reply
    m = sup.motion()
    assert m["run_seq"] == runs and m["state"] == PlannerState.IDLE and sup.fifo.fill() == 0
