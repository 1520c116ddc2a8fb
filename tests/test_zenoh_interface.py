"""The controller's Zenoh interface seen from operator stations and observers in other sessions:
the command lock, every command's refusals, program upload, history and job queries, the
position stream, and what happens when the operator station is lost during a cut."""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

from cnc.bus.keys import Keys
from cnc.bus.messages import (
    AlarmEvent, AlarmList, CycleStart, HistoryPage, Hold, Home, JobPage, LockState, Position, ProcedureCatalogue, ProgramInfo, Reset,
    SetMode, Status, decode,
)
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.data.layout import LinkState, PlannerState, RunResult
from cnc.logic.states import CyclePhase, MachineState
from cnc.runtime.supervisor import Supervisor

from .conftest import NEAR_HOME, fast_plant, full_controller, logic, machine_config, press_button_when_asked, reset_and_home

PART = """(square part)
G21 G90 G64 P0.05 F6000
G0 X100 Y100
M3
G1 X140
G1 Y140
G1 X100
G1 Y100
M5
G0 X60 Y60
M2
"""


@pytest.fixture
def controller(request, tmp_path):
    """`plc_controller`; for a test marked `quick_runaway`, one whose interpreter gives up on a
    runaway program after 3 s (its endless upload then ends before the controller is stopped)."""
    quick = {"gcode.interpret_timeout_s": 3.0} if request.node.get_closest_marker("quick_runaway") else {}
    with full_controller(machine_config(**NEAR_HOME, **quick), tmp_path / "history.sqlite") as sup:
        yield sup


@pytest.fixture
def keys(controller) -> Keys:
    return Keys(controller.config.zenoh.key_prefix, controller.config.machine.name)


@pytest.fixture
def session(controller):
    s = open_client([controller.config.zenoh.listen[0]])
    yield s
    s.close()


def get(session, key: str, kind, timeout: float = 10.0):
    replies = list(session.get(key, timeout=timeout))
    assert replies and replies[0].ok is not None, replies[0].err.payload.to_string() if replies else f"no answer on {key}"
    return decode(replies[0].ok.payload.to_bytes(), kind)


def test_only_the_station_holding_the_lock_commands_and_observers_are_refused(controller, session, keys):
    sup = controller
    alice, bob = OperatorStation(session, keys, "alice"), OperatorStation(session, keys, "bob")
    sup.wait_until(lambda: get(session, keys.lock, LockState).stations == ["alice", "bob"], 5.0, "both stations seen")
    assert "nobody holds the command lock; take it first" in alice.request(Reset()).reason
    assert alice.take_lock().ok
    assert "station 'alice' holds the command lock" in bob.take_lock().reason
    assert "read-only: station 'alice' holds the command lock" in bob.request(Reset()).reason
    assert alice.request(Reset()).ok
    observer = list(session.get(keys.cmd("reset"), payload=b"{}", timeout=5.0))
    assert "no station id" in decode(observer[0].ok.payload.to_bytes(), type(alice.request(Reset()))).reason
    assert "does not hold" in bob.release_lock().reason
    assert alice.release_lock().ok and bob.take_lock().ok
    assert get(session, keys.lock, LockState).holder == "bob"
    alice.close()
    bob.close()
    sup.wait_until(lambda: get(session, keys.lock, LockState).holder == "", 10.0, "the lock released with bob's token")
    carol = OperatorStation(session, keys, "carol")
    sup.wait_until(lambda: get(session, keys.lock, LockState).stations == ["carol"], 5.0, "carol seen")
    carol.token.undeclare()  # a station that does not announce itself
    sup.wait_until(lambda: get(session, keys.lock, LockState).stations == [], 5.0, "carol's token gone")
    refused = carol.take_lock()
    assert not refused.ok and "has no liveliness token" in refused.reason and "declare it" in refused.reason, refused
    carol.pong.undeclare()


@pytest.mark.quick_runaway
def test_malformed_and_refused_commands_get_a_reason_and_never_crash_or_block_the_gateway(controller, session, keys):
    op = OperatorStation(session, keys, "op")
    assert op.take_lock().ok
    for verb, payload, expected in [
        ("start", b'{"cycles": "many", "version": 1}', "malformed command"),
        ("start", b"not json", "malformed command"),
        ("start", b"{}", "message schema version None is not the supported version 1"),
        ("mode", b'{"mode": 3, "version": 1}', "malformed command"),
        ("jog", b'{"axis": "x", "version": 99}', "schema version 99"),
        ("mode", b'{"mode": "TURBO", "version": 1}', "mode 'TURBO' is not one of: MANUAL, AUTO"),
        ("start", b'{"version": 1}', "wrong operation mode: cycle start needs AUTO"),
        ("pump", b'{"on": true, "pressure_bar": 99999, "version": 1}', "out of range"),
        ("jog", b'{"axis": "q", "version": 1}', "jog"),
    ]:
        replies = list(session.get(keys.cmd(verb), payload=payload, attachment=op.attachment, timeout=10.0))
        reply = decode(replies[0].ok.payload.to_bytes(), type(op.request(Reset())))
        assert not reply.ok and expected in reply.reason, (verb, payload, reply.reason)
    assert controller.children["gateway"].process.is_alive() and controller.failed is None
    # uploads have their own worker: the lock, reset and hold are answered while one interprets
    slow = threading.Thread(target=lambda: op.upload("loop.ngc", "o1 while [1]\nG0 X1\no1 endwhile\nM2\n"), daemon=True)
    slow.start()
    time.sleep(0.5)  # the gateway is interpreting it now
    started = time.monotonic()
    assert op.request(Reset()).ok
    assert "nothing to hold" in op.request(Hold()).reason
    assert time.monotonic() - started < 5.0, "answered beside the endless upload, not after it"
    assert slow.is_alive(), "the endless program is still being interpreted (its own time limit ends it)"
    slow.join(30.0)  # refused as a runaway after its 3 s: the gateway is free to stop
    op.close()


def test_a_program_is_uploaded_checked_and_loaded_or_refused_with_line_and_column(controller, session, keys):
    sup = controller
    op = OperatorStation(session, keys, "op")
    assert op.take_lock().ok
    bad = op.upload("bad.ngc", "G21 G90\nG1 X10 Y10 F100\nG2 X20 Y10 R2\n")
    assert not bad.ok and bad.errors and bad.errors[0].line == 3, bad
    assert "bad.ngc:3:" in bad.reason
    binary = op.upload("blob.ngc", "G0 X1\n\x00\x01binary")
    assert not binary.ok and binary.errors[0].line == 2 and binary.errors[0].column == 1 and "not text" in binary.reason
    assert "plain file name" in op.upload("../etc/passwd", "G0 X1").reason
    big = "G0 X1\n" * (sup.config.gcode.max_program_bytes // 6 + 1)
    assert "this machine accepts at most" in op.upload("big.ngc", big).reason
    assert sup.motion()["program_name"] == "", "nothing was loaded"
    good = op.upload("part.ngc", PART)
    assert good.ok, good.reason
    info = get(session, keys.program, ProgramInfo)
    assert info.name == "part.ngc" and info.text == PART and info.lines == PART.count("\n") and info.planned_s > 0
    assert info.path is None, "the path only when asked for"
    path = get(session, f"{keys.program}?path=1;text=0", ProgramInfo).path
    assert path.kind == [0, 1, 1, 1, 1, 0] and path.end_x[:2] == [100.0, 140.0] and path.line[1] == 5
    op.close()


def test_position_stream_and_status_carry_what_the_operator_sees(controller, session, keys):
    sup = controller
    positions, statuses = [], []
    got = threading.Event()

    def on_position(sample):
        positions.append(decode(sample.payload.to_bytes(), Position))
        if len(positions) >= 20 and statuses:
            got.set()

    subs = [session.declare_subscriber(keys.position, on_position),
            session.declare_subscriber(keys.status, lambda s: statuses.append(decode(s.payload.to_bytes(), Status)))]
    op = OperatorStation(session, keys, "panel-1")
    assert op.take_lock().ok
    assert got.wait(10.0)
    st = statuses[-1]
    assert len(positions[-1].position_mm) == 2 and positions[-1].seq > positions[0].seq
    sup.wait_until(lambda: statuses[-1].network_alive and statuses[-1].operator == "panel-1", 5.0, "the operator in the status")
    st = statuses[-1]
    assert st.plc_link == "OK" and st.mode == "MANUAL" and st.stations == ["panel-1"]
    assert st.plc_inputs["mains_on"] == 1.0 and st.plc_inputs["pneumatic_ready"] == 1.0 and "transport_ready" in st.plc_inputs
    stamps = [p.stamp_ns for p in positions[-20:]]
    rate = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) / 1e9)
    assert 0.5 * sup.config.gateway.position_rate_hz < rate < 1.5 * sup.config.gateway.position_rate_hz
    catalogue = get(session, keys.procedures, ProcedureCatalogue)
    assert [p.id for p in catalogue.procedures] == [p.id for p in sup.config.procedure]
    transport = catalogue.procedures[0]
    assert transport.title == "TRANSPORT PHASE" and transport.steps[-1] == "Button pressed"
    for s in subs:
        s.undeclare()
    op.close()


def test_history_queries_filter_and_page_and_every_run_is_a_job(controller, session, keys, tmp_path):
    sup = controller
    op = OperatorStation(session, keys, "op")
    assert op.take_lock().ok
    for _ in range(3):
        op.request(CycleStart())  # refused in MANUAL: message 37 each time
    reset_and_home(sup, op.request)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                   60.0, "homing")
    assert op.upload("part.ngc", PART).ok and op.request(SetMode("AUTO")).ok and op.request(CycleStart(1)).ok
    press_button_when_asked(sup, lambda: logic(sup)["cycles_done"] == 1 and logic(sup)["phase"] == CyclePhase.NONE,
                            60.0, "one automatic cycle")
    wrong = get(session, f"{keys.alarms_history}?code=37", HistoryPage)
    assert [e.code for e in wrong.entries] == [37, 37, 37] and not wrong.more
    page1 = get(session, f"{keys.alarms_history}?level=info;limit=2", HistoryPage)
    assert len(page1.entries) == 2 and page1.more and page1.entries[0].seq > page1.entries[1].seq
    page2 = get(session, f"{keys.alarms_history}?level=info;limit=2;before_seq={page1.entries[-1].seq}", HistoryPage)
    assert page2.entries[0].seq < page1.entries[-1].seq
    text = get(session, f"{keys.alarms_history}?text=CYCLE", HistoryPage)
    assert text.entries and all("cycle" in (e.text + e.detail).lower() for e in text.entries)
    errors = list(session.get(f"{keys.alarms_history}?limit=lots", timeout=5.0))
    assert errors[0].err is not None and "not an integer" in errors[0].err.payload.to_string()
    sup.wait_until(lambda: get(session, keys.jobs_history, JobPage).entries, 5.0, "the job record")
    job = get(session, keys.jobs_history, JobPage).entries[0]
    assert job.program == "part.ngc" and job.result == RunResult.DONE.name and job.cycle_time_s > 0
    assert 0 < job.planned_s <= job.cycle_time_s, "the planned cycle time kept with the run (the run adds the FIFO's lead)"
    assert job.hash == get(session, keys.program, ProgramInfo).hash and job.end_ns >= job.start_ns
    op.close()


def test_a_history_read_with_a_number_past_64_bits_or_a_bad_code_is_refused_naming_it_not_an_internal_error(
        controller, session, keys):
    """A code typed on the history window as a long row of digits reached SQLite, whose OverflowError
    was taken for a bug in the gateway (a fatal internal_error alarm)."""
    huge = "1" * 40
    for key, named in ((f"{keys.alarms_history}?code={huge}", f"code='{huge}' is out of range"),
                       (f"{keys.alarms_history}?code=37,x1", "code='37,x1' (item 'x1') is not an integer"),
                       (f"{keys.alarms_history}?offset={huge}", f"offset='{huge}' is out of range"),
                       (f"{keys.alarms_history}?after=-{huge}", f"after='-{huge}' is out of range"),
                       (f"{keys.jobs_history}?offset={huge}", f"offset='{huge}' is out of range")):
        replies = list(session.get(key, timeout=10.0))
        assert replies and replies[0].err is not None, key
        assert named in replies[0].err.payload.to_string(), replies[0].err.payload.to_string()
    assert get(session, f"{keys.alarms_history}?code={2 ** 63 - 1}", HistoryPage).entries == [], "the largest is a code"
    assert not [e for e in get(session, f"{keys.alarms_history}?after=0", HistoryPage).entries if e.id == "internal_error"]


def test_losing_the_operator_station_during_a_cut_holds_the_feed(controller, keys):
    sup = controller
    hmi = open_client([sup.config.zenoh.listen[0]])
    op = OperatorStation(hmi, keys, "panel")
    assert op.take_lock().ok
    reset_and_home(sup, op.request)
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                   60.0, "homing")
    long_cut = PART.replace("G1 X140\nG1 Y140\nG1 X100\nG1 Y100", "G1 X900\nG1 Y900\nG1 X100\nG1 Y100")
    assert op.upload("long.ngc", long_cut).ok and op.request(SetMode("AUTO")).ok and op.request(CycleStart(1)).ok
    press_button_when_asked(sup, lambda: logic(sup)["phase"] == CyclePhase.CUTTING
                            and sup.motion()["state"] == PlannerState.RUNNING, 60.0, "the cut")
    hmi.close()  # the station's host goes away: its liveliness token with it
    sup.wait_until(lambda: logic(sup)["state"] == MachineState.HOLD and sup.motion()["state"] == PlannerState.HELD,
                   20.0, "the feed hold")
    assert sup.area.reader("logic").read_dict()["phase"] == CyclePhase.CUTTING


def test_a_subscriber_that_reconnects_catches_up_on_every_alarm_it_missed(controller, keys):
    sup = controller
    endpoint = [sup.config.zenoh.listen[0]]
    op_session = open_client(endpoint)
    op = OperatorStation(op_session, keys, "op")
    assert op.take_lock().ok
    seen: list[int] = []
    first = open_client(endpoint)
    sub = first.declare_subscriber(keys.event_alarm, lambda s: seen.append(decode(s.payload.to_bytes(), AlarmEvent).seq))
    op.request(CycleStart())
    sup.wait_until(lambda: len(seen) >= 1, 5.0, "the first alarm live")
    sub.undeclare()
    first.close()  # the observer's host drops off the network
    for _ in range(4):
        op.request(CycleStart())  # messages it does not see
    again = open_client(endpoint)
    live: list[int] = []
    sub = again.declare_subscriber(keys.event_alarm, lambda s: live.append(decode(s.payload.to_bytes(), AlarmEvent).seq))
    page = get(again, f"{keys.alarms_history}?after={max(seen)}", HistoryPage)
    op.request(CycleStart())
    sup.wait_until(lambda: live, 5.0, "a live alarm after the reconnect")
    got = sorted(set(seen) | {e.seq for e in page.entries} | set(live))
    assert got == list(range(1, max(got) + 1)), "no sequence number missed"
    assert len(page.entries) >= 4
    st = get(again, keys.alarms_active, AlarmList)
    assert st.last_seq >= max(got) - 1
    sub.undeclare()
    again.close()
    op.close()
    op_session.close()


def test_with_access_control_only_authenticated_operators_command_the_running_controller(tmp_path):
    from cnc.bus.session import zenoh_config
    from cnc.bus.users import Account, write_users

    users = tmp_path / "machine.users"
    write_users(users, {"op1": Account("op1", "operator", "op-secret"), "obs1": Account("obs1", "observer", "obs-secret")})
    config = machine_config(**NEAR_HOME, **{"zenoh.access.users_file": str(users)})
    keys = Keys(config.zenoh.key_prefix, config.machine.name)
    endpoint = [config.zenoh.listen[0]]
    with Supervisor(config, clock="virtual", history_path=tmp_path / "h.sqlite", plc_sim_times=fast_plant()) as sup:
        sup.wait_until(lambda: sup.area.reader("plc").read_dict()["state"] == LinkState.OK, 20.0, "the PLC link")
        with pytest.raises(Exception):
            zenoh.open(zenoh_config("client", connect=endpoint))  # no credentials: refused at the door
        with pytest.raises(Exception):
            open_client(endpoint, ("op1", "wrong"))
        observer = open_client(endpoint, ("obs1", "obs-secret"))
        operator = open_client(endpoint, ("op1", "op-secret"))
        statuses = []
        sub = observer.declare_subscriber(keys.status, lambda s: statuses.append(s))
        sup.wait_until(lambda: statuses, 10.0, "status at the observer")
        watcher = OperatorStation(observer, keys, "watcher", timeout_s=2.0, user="obs1")
        refused = watcher.take_lock()
        assert not refused.ok and "no answer" in refused.reason, "an observer's command never reaches the gateway"
        op = OperatorStation(operator, keys, "panel", user="op1")
        assert op.take_lock().ok and op.request(Reset()).ok
        sup.wait_until(lambda: logic(sup)["drives_on"] == 1, 5.0, "the operator's reset")
        assert get(observer, f"{keys.alarms_history}?after=0", HistoryPage).last_seq >= 0, "observers read the history"
        assert not watcher.upload("x.ngc", PART).ok
        assert op.upload("part.ngc", PART).ok
        # nobody acts as someone else, or reaches the controller's internal keys
        forged = list(observer.get(keys.cmd("reset", "op1"), payload=b"{}", attachment=op.attachment, timeout=2.0))
        assert not [r for r in forged if r.ok is not None], "an observer used the operator's command key"
        for session_ in (observer, operator):
            assert not [r for r in session_.get(keys.logic("drives"), payload=b'{"on": true}', timeout=2.0)
                        if r.ok is not None], "a station reached internal/logic"
        assert "is an operator; this needs an engineer" in op.set_param("axis.x.kp_1_s", 30.0).reason
        from hmi.connection import Connection
        from hmi.model import MachineModel

        screen = MachineModel("screen")  # an operator screen logged in as an observer catches up on everything
        with Connection(screen, endpoint, keys, "screen", credentials=("obs1", "obs-secret")):
            sup.wait_until(lambda: screen.reachable and screen.catalogue and screen.lock_holder == "panel"
                           and screen.program is not None and screen.program.segments == 6, 10.0, "the catch-up")
        sub.undeclare()
        for s in (watcher, op):
            s.close()
        observer.close()
        operator.close()


def test_every_command_verb_is_refused_with_a_reason_when_the_state_does_not_allow_it(controller, session, keys):
    from cnc.bus.messages import (
        Acknowledge, CalibrationLadder, CalibrationRecord, ControlRun, ControlSelect, DeleteProgram, Drives, GoTo, Hold, Jog,
        JogRefresh, JogStop,
        JetTest, LoadProgram, Mdi, Override,
        ProcedureConfirm, Recover, ProcedureEnd, ProcedureStart, ProcedureStop, Pump, Resume, SetCut, SimInput, Stop,
    )
    from cnc.bus.operator import OPERATOR_COMMANDS

    op = OperatorStation(session, keys, "op")
    assert op.take_lock().ok
    refusals = {
        "mode": (SetMode("SEMI"), "is not one of"),
        "start": (CycleStart(), "wrong operation mode"),
        "hold": (Hold(), "nothing to hold"),
        "resume": (Resume(), "nothing to resume"),
        "stop": (Stop(), "nothing to stop"),
        "reset": None,  # always accepted: it says what is still present
        "drives": None,
        "home": (Home(["q"]), "drives are not enabled"),
        "jog": (Jog("x", 10.0), "drives"),
        "jog_stop": (JogStop(), "not jogging"),
        "jog_refresh": (JogRefresh(), "no continuous jog to refresh"),
        "goto": (GoTo({"x": 100.0}), "drives"),
        "mdi": (Mdi("G0 X10"), "switch the drives on and home the machine"),
        "control_run": (ControlRun("circle", 5.0), "cannot start a control run while IDLE"),
        "control_select": (ControlSelect("no_such_law"), "'no_such_law' is neither a shipped program"),
        "recover": (Recover("continue"), "wrong operation mode: continuing a cut needs AUTO"),
        "program_delete": (DeleteProgram("../credentials"), "plain name"),
        "load": (LoadProgram("/nonexistent/part.ngc"), "outside the program directory"),
        "cut_setup": (SetCut("leather", 2.0, 3), "no program is loaded: load one, then choose its material"),
        "calibration_ladder": (CalibrationLadder("leather", 2.0, 600.0, 60000.0), "beyond this machine's"),
        "calibration_record": (CalibrationRecord("../leather", 2.0, 600.0, [600.0] * 5, 0.5, 0.2), "is not a material id"),
        "override": (Override(250.0), "out of range: 0 to 200"),
        "pump": (Pump(True, pressure_bar=-5.0), "out of range"),
        "jet_test": (JetTest(True), "jet test"),
        "acknowledge": (Acknowledge(4242), "alarm 4242 is not active"),
        "procedure_start": (ProcedureStart("nope"), "nope"),
        "procedure_confirm": (ProcedureConfirm(), "procedure"),
        "procedure_stop": (ProcedureStop(), "procedure"),
        "procedure_end": (ProcedureEnd(), "procedure"),
        "lock": None,
        "program": None,  # refusals covered by the upload test
        "sim": (SimInput("door", 1.0), "no simulated input 'door'"),  # the rest: tests/test_sim_inputs.py
        "stop_all": None,  # always accepted, lock or not: tests/test_stop_all.py
    }
    assert set(refusals) == set(OPERATOR_COMMANDS), "every verb has its case"
    wrong = []
    for verb, case in refusals.items():
        if case is None:
            continue
        msg, expected = case
        reply = op.request(msg)
        if reply.ok or not reply.reason.startswith(f"{verb}: ") or expected not in reply.reason:
            wrong.append((verb, reply.ok, reply.reason))
    assert not wrong, wrong
    assert op.request(Drives(True)).ok and op.request(Reset()).ok
    op.close()


def test_a_station_loads_programs_by_name_from_the_program_directory_only(controller, session, keys, tmp_path):
    """`cmd/load` reads nothing outside the program directory: the credentials file is not echoed
    back, a named pipe does not hang the controller, a plain name inside it loads."""
    import os

    from cnc.bus.messages import LoadProgram

    programs = tmp_path / "programs"  # beside the history: this controller's program directory
    programs.mkdir(exist_ok=True)
    (programs / "part.ngc").write_text("G21 G90\nG0 X20 Y20\nM3\nG1 X40 F600\nM5\nM2\n")
    os.mkfifo(programs / "pipe.ngc")
    secret = tmp_path / "credentials"
    secret.write_text("controller:s3cret-password\n")
    op = OperatorStation(session, keys, "op")
    try:
        assert op.take_lock().ok
        for name, why in ((str(secret), "outside the program directory"), ("../credentials", "outside the program directory"),
                          ("pipe.ngc", "is a named pipe"), ("/dev/zero", "outside the program directory")):
            reply = op.request(LoadProgram(name))
            assert not reply.ok and why in reply.reason and "s3cret" not in reply.reason, (name, reply)
        reply = op.request(LoadProgram("part.ngc"))
        assert reply.ok, reply.reason
        assert controller.motion()["program_name"] == "part.ngc"
    finally:
        op.close()


def test_every_command_and_refusal_is_in_the_audit_trail_with_its_user_and_station(controller, session, keys):
    """The audit trail keeps who sent what and the answer, refusals included; a parameter change
    runs the machine file's cross-checks (fifo_high_ms must stay above fifo_low_ms + a period)."""
    from cnc.bus.messages import AuditPage, JogRefresh

    op = OperatorStation(session, keys, "panel")
    try:
        assert "nobody holds the command lock" in op.request(Reset()).reason
        assert op.take_lock().ok and op.request(Reset()).ok
        op.request(JogRefresh())  # the dead-man's refreshes are not recorded
        refused = op.set_param("planner.fifo_high_ms", 4.0)
        assert not refused.ok and "fifo_high_ms" in refused.reason and "must exceed fifo_low_ms" in refused.reason, refused
        sup = controller
        sup.wait_until(lambda: len(get(session, f"{keys.audit_history}?order=oldest", AuditPage).entries) >= 4, 10.0,
                       "the audit trail")
        rows = get(session, f"{keys.audit_history}?order=oldest", AuditPage).entries
        assert [(r.user, r.station, r.verb, r.ok) for r in rows] == [
            ("local", "panel", "reset", False), ("local", "panel", "lock", True), ("local", "panel", "reset", True),
            ("local", "panel", "param planner.fifo_high_ms", False)]
        assert "nobody holds the command lock" in rows[0].reason and '"value":4.0' in rows[3].command.replace(" ", "")
        assert rows[0].at_ns <= rows[-1].at_ns and [r.seq for r in rows] == sorted(r.seq for r in rows)
    finally:
        op.close()


def test_a_lock_holder_that_stops_answering_is_lost_even_while_its_token_stays(tmp_path):
    """The gateway asks the lock holder's station for an answer: a station whose link is dead but
    whose token a router keeps (Zenoh does not expire a stuck TLS link) still loses the lock."""
    config = machine_config(**NEAR_HOME, **{"gateway.station_ping_ms": 200.0, "gateway.station_lost_ms": 1000.0})
    keys = Keys(config.zenoh.key_prefix, config.machine.name)
    with Supervisor(config, clock="virtual", history_path=tmp_path / "h.sqlite", plc_sim_times=fast_plant()) as sup:
        session = open_client([config.zenoh.listen[0]])
        op = OperatorStation(session, keys, "panel")
        try:
            assert op.take_lock().ok and get(session, keys.lock, LockState).holder == "panel"
            op.pong.undeclare()  # it stops answering; its liveliness token stays
            sup.wait_until(lambda: get(session, keys.lock, LockState).holder == "", 10.0, "the silent holder lost")
            assert get(session, keys.lock, LockState).stations == [], "its token no longer counts"
            refused = op.take_lock()
            assert not refused.ok and "does not answer the controller's ping" in refused.reason, refused
            op.pong = session.declare_queryable(keys.ping("panel", "local", str(session.zid())),
                                                lambda q: q.reply(q.key_expr, b"pong"))
            assert op.take_lock().ok, "answering again, the station takes the lock again"
            assert get(session, keys.lock, LockState).stations == ["panel"], "and counts among the stations again"
            op.pong.undeclare()  # silent again; this time it answers again without asking for the lock
            sup.wait_until(lambda: get(session, keys.lock, LockState).holder == "", 10.0, "the silent holder lost again")
            op.pong = session.declare_queryable(keys.ping("panel", "local", str(session.zid())),
                                                lambda q: q.reply(q.key_expr, b"pong"))
            sup.wait_until(lambda: get(session, keys.lock, LockState).stations == ["panel"], 10.0,
                           "the gateway's ping finding it answering again")
            assert get(session, keys.lock, LockState).holder == "", "the lock stays free until it is asked for"
        finally:
            op.close()
            session.close()
