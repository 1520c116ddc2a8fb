"""The one command service every door uses (`cnc.bus.service`), over a real Zenoh session: decode,
check the caller from the key and the lock, run, reply ok or the one refusal; a bug by the third
tier's policy (logged with its stack, reported, answered as an internal error) and the door goes
on serving; a stop's lane never waits behind another's work. The same policy through the real
processes, in the middle of a cut, is in `test_fault_injection.py` (the "bug in ..." faults) and
`test_bugs_in_every_door_are_alarmed_answered_and_the_door_goes_on` below."""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path

import pytest
import zenoh

from cnc.alarms import AlarmHistory
from cnc.bus.access import Roles
from cnc.bus.keys import Keys
from cnc.bus.messages import (
    Acknowledge, AlarmList, LogState, Override, Reply, SetMode, SetParam, Stop, decode, encode,
)
from cnc.bus.service import DEFERRED, CommandRefused, CommandService, Request, Route
from cnc.bus.session import zenoh_config

KEYS = Keys("svc", "m1")


@pytest.fixture
def session():
    s = zenoh.open(zenoh_config("peer", listen=[]))
    yield s
    s.close()


class Bugs:
    """What `on_bug` was told."""

    def __init__(self) -> None:
        self.seen: list[tuple[str, bool, BaseException]] = []

    def __call__(self, request: Request, exc: BaseException) -> None:
        self.seen.append((request.what, request.motion, exc))


def ask(session, key: str, payload: bytes | None = None, station: str = "", timeout: float = 10.0):
    """One query; the reply (ok sample or error) as (payload text, is_error)."""
    attachment = json.dumps({"station": station}).encode() if station else None
    [reply] = list(session.get(key, payload=payload, attachment=attachment, timeout=timeout))
    if reply.ok is not None:
        return reply.ok.payload.to_bytes(), False
    return reply.err.payload.to_bytes(), True


def reply_of(session, key: str, payload: bytes | None = None, station: str = "") -> Reply:
    data, err = ask(session, key, payload, station)
    assert not err, data
    return decode(data, Reply)


def test_a_request_is_decoded_run_and_answered_and_every_refusal_is_one_reply(session):
    bugs = Bugs()
    service = CommandService(session, KEYS, "test", bugs)

    def override(request: Request) -> Reply:
        if request.message.percent > 150:
            raise CommandRefused(f"override {request.message.percent:g} % is more than 150 %")
        return Reply(True, f"override {request.message.percent:g} %")

    def state(request: Request) -> LogState:
        if request.params.get("run") == "x":
            raise CommandRefused("parameter run='x' is not a number")
        return LogState([], 0.001, 0, [])

    service.serve(Route("override", KEYS.logic("override"), override, Override),
                  Route("state", KEYS.log("state"), state, read=True))
    results: dict = {}
    done = threading.Event()

    def station() -> None:
        results["ok"] = reply_of(session, KEYS.logic("override"), encode(Override(80.0)))
        results["refused"] = reply_of(session, KEYS.logic("override"), encode(Override(180.0)))
        results["malformed"] = reply_of(session, KEYS.logic("override"), b'{"percent": "fast", "version": 1}')
        results["unversioned"] = reply_of(session, KEYS.logic("override"), b'{"percent": 50}')
        results["read"] = ask(session, KEYS.log("state"))
        results["read refused"] = ask(session, KEYS.log("state?run=x"))
        done.set()

    asker = threading.Thread(target=station)
    asker.start()
    while not done.is_set():  # a polled service: the process's own loop serves
        service.poll()
        done.wait(0.001)
    asker.join()
    service.close()
    assert results["ok"] == Reply(True, "override 80 %")
    assert results["refused"] == Reply(False, "override: override 180 % is more than 150 %")
    assert results["malformed"].reason.startswith("override: malformed command: Expected `float`, got `str`")
    assert "schema version None" in results["unversioned"].reason
    assert decode(results["read"][0], LogState).period_s == 0.001 and not results["read"][1]
    assert results["read refused"] == (b"state: parameter run='x' is not a number", True), "a read refuses with an error"
    assert bugs.seen == []


def test_a_bug_is_logged_with_its_stack_reported_answered_as_internal_error_and_serving_goes_on(session, caplog):
    bugs = Bugs()
    service = CommandService(session, KEYS, "test", bugs, threaded=True)
    calls = []

    def stop(request: Request) -> Reply:
        calls.append(request.message)
        if len(calls) == 1:
            return {}["no such key"]  # a bug
        return Reply(True, "stopping")

    def mode(request: Request) -> None:
        raise ZeroDivisionError("a bug at rest")

    service.serve(Route("stop", KEYS.logic("stop"), stop, Stop, motion=True, lane="realtime"),
                  Route("mode", KEYS.logic("mode"), mode, SetMode))
    with caplog.at_level(logging.ERROR, logger="cnc.bus.service"):
        first = reply_of(session, KEYS.logic("stop"), encode(Stop()))
        second = reply_of(session, KEYS.logic("stop"), encode(Stop()))
        at_rest = reply_of(session, KEYS.logic("mode"), encode(SetMode("AUTO")))
    service.close()
    assert not first.ok and first.reason.startswith("stop: internal error in the test: KeyError('no such key')")
    assert "safe state" in first.reason and "alarm internal_error" in first.reason
    assert second == Reply(True, "stopping"), "the door goes on serving"
    assert not at_rest.ok and "ZeroDivisionError('a bug at rest')" in at_rest.reason and "safe state" not in at_rest.reason
    assert [(what, motion, type(exc)) for what, motion, exc in bugs.seen] == [("stop", True, KeyError),
                                                                            ("mode", False, ZeroDivisionError)]
    stacks = [r for r in caplog.records if r.exc_info and "failed (a bug)" in r.getMessage()]
    assert len(stacks) == 2 and stacks[0].exc_info[0] is KeyError, "logged with the stack"


def test_the_caller_is_the_user_the_key_names_with_its_role_and_the_lock_never_what_the_query_says(session):
    class Lock:
        def require(self, user: str, station: str) -> None:
            if (user, station) != ("alice", "panel"):
                raise CommandRefused(f"read-only: station 'panel' of alice holds the command lock (not {user}/{station})")

    audit: list[tuple[str, str, str, bool]] = []
    service = CommandService(
        session, KEYS, "gateway", Bugs(), threaded=True, roles=Roles({"alice": "operator", "olga": "observer",
                                                                      "erin": "engineer"}),
        lock=Lock(), audit=lambda request, reply: audit.append((request.caller.user, request.caller.station,
                                                                 request.what, reply.ok)))
    seen: list[Request] = []

    def accept(request: Request) -> Reply:
        seen.append(request)
        return Reply(True)

    service.serve(Route("acknowledge", KEYS.cmd_any("acknowledge"), accept, Acknowledge, role="operator", lock=True,
                        audit=True),
                  Route("set_param", KEYS.user_param("*", "**"), accept, SetParam, role="engineer", lock=True, audit=True,
                        what=lambda key: f"param {key.rsplit('/', 1)[1]}"))
    ack = encode(Acknowledge())
    observer = reply_of(session, KEYS.cmd("acknowledge", "olga"), ack, station="panel")
    stranger = reply_of(session, KEYS.cmd("acknowledge", "mallory"), ack, station="panel")
    no_lock = reply_of(session, KEYS.cmd("acknowledge", "alice"), ack, station="desk")
    operator = reply_of(session, KEYS.cmd("acknowledge", "alice"), ack, station="panel")
    claimed = list(session.get(KEYS.cmd("acknowledge", "olga"), payload=ack,
                               attachment=json.dumps({"station": "panel", "user": "alice"}).encode(), timeout=10.0))
    not_engineer = reply_of(session, KEYS.user_param("alice", "axis.x.kp_1_s"), encode(SetParam(1.0)), station="panel")
    service.close()
    assert observer == Reply(False, "acknowledge: user 'olga' is an observer; this needs an operator")
    assert stranger == Reply(False, "acknowledge: user 'mallory' has no account on this machine")
    assert not no_lock.ok and no_lock.reason.startswith("acknowledge: read-only: ")
    assert operator.ok and [(r.caller.user, r.caller.station) for r in seen] == [("alice", "panel")]
    assert not decode(claimed[0].ok.payload.to_bytes(), Reply).ok, "an attachment naming another user changes nothing"
    assert not_engineer == Reply(False, "param axis.x.kp_1_s: user 'alice' is an operator; this needs an engineer")
    assert audit == [("olga", "panel", "acknowledge", False), ("mallory", "panel", "acknowledge", False),
                     ("alice", "desk", "acknowledge", False), ("alice", "panel", "acknowledge", True),
                     ("olga", "panel", "acknowledge", False), ("alice", "panel", "param axis.x.kp_1_s", False)]


def test_a_stop_on_its_own_lane_is_answered_while_another_lane_is_busy_and_deferred_answers_come_later(session):
    service = CommandService(session, KEYS, "gateway", Bugs(), threaded=True)
    busy, release = threading.Event(), threading.Event()
    later: list[Request] = []

    def load(request: Request) -> Reply:
        busy.set()
        release.wait(30.0)
        return Reply(True, "loaded")

    def start(request: Request) -> object:
        later.append(request)
        return DEFERRED

    service.serve(Route("load", KEYS.logic("load"), load, lane="cmd"),
                  Route("stop", KEYS.logic("stop"), lambda _r: Reply(True, "stopped"), Stop, lane="realtime"),
                  Route("start", KEYS.logic("start"), start, lane="cmd2"))
    loading = session.get(KEYS.logic("load"), timeout=30.0)
    assert busy.wait(30.0)
    assert reply_of(session, KEYS.logic("stop"), encode(Stop())) == Reply(True, "stopped"), "not behind the load"
    release.set()
    assert decode(next(iter(loading)).ok.payload.to_bytes(), Reply) == Reply(True, "loaded")
    starting = session.get(KEYS.logic("start"), timeout=30.0)
    while not later:
        busy.wait(0.001)
    later[0].answer(Reply(True, "started, later"))
    assert decode(next(iter(starting)).ok.payload.to_bytes(), Reply) == Reply(True, "started, later")
    service.close()


def test_bugs_are_injected_only_where_the_injection_names_the_process_and_verb(session):
    bugs = Bugs()
    injected = {"now": "test/stop,other/mode"}
    service = CommandService(session, KEYS, "test", bugs, threaded=True, inject=lambda: injected["now"])
    service.serve(Route("stop", KEYS.logic("stop"), lambda _r: Reply(True), Stop, motion=True),
                  Route("mode", KEYS.logic("mode"), lambda _r: Reply(True), SetMode))
    failed = reply_of(session, KEYS.logic("stop"), encode(Stop()))
    assert reply_of(session, KEYS.logic("mode"), encode(SetMode("AUTO"))).ok, "another process's verb"
    injected["now"] = ""
    assert reply_of(session, KEYS.logic("stop"), encode(Stop())).ok, "cleared"
    service.close()
    assert not failed.ok and "InjectedBug" in failed.reason and [b[0] for b in bugs.seen] == ["stop"]


# -- through the real processes -------------------------------------------------------------------


def test_bugs_in_every_door_are_alarmed_answered_and_the_door_goes_on(plc_controller):
    """A bug in a handler of each door (the gateway's commands and reads, its parameter door, the
    logic, the planner, the logger), injected on the simulated board: the asker is told internal
    error, the history holds the internal-error alarm naming the process and the request, the same
    door answers its next request, and a reset clears the alarm without a restart."""
    from cnc.bus.messages import HistoryPage, JobPage, LoadProgram, Reset
    from cnc.bus.operator import OperatorStation
    from cnc.bus.session import open_client
    from cnc.runtime.procs import program_dir

    sup = plc_controller
    keys = sup.keys
    path = Path(program_dir(sup.config, sup.runtime.history_path)) / "square.ngc"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("G21 G90\nG0 X40 Y40\nG1 X60 F3000\nG1 Y60\nM2\n")
    with AlarmHistory(sup.history_path, readonly=True) as history:
        seq0 = history.last_seq()
    session = open_client([sup.config.zenoh.listen[0]])
    station = OperatorStation(session, keys, "bugs")
    try:
        assert station.take_lock().ok
        sup.set_sim(inject_bug="gateway/history,gateway/set_param,logic/acknowledge,planner/load,logger/state")
        history_text, history_err = ask(session, keys.alarms_history)
        param = station.set_param("axis.x.kp_1_s", 120.0)
        acknowledge = sup.logic.request(Acknowledge())
        load = sup.logic.request(LoadProgram(str(path)))
        log_text, log_err = ask(session, keys.log("state"))
        assert history_err and b"history: internal error in the gateway: InjectedBug(" in history_text
        assert not param.ok and param.reason.startswith("param axis.x.kp_1_s: internal error in the gateway")
        assert not acknowledge.ok and acknowledge.reason.startswith("acknowledge: internal error in the logic")
        assert not load.ok and load.reason.startswith("load: internal error in the planner")
        assert log_err and b"log state: internal error in the logger" in log_text
        for reply in (param, acknowledge, load):
            assert "safe state" not in reply.reason, "none of these moves the machine"

        # each door goes on serving
        data, err = ask(session, keys.jobs_history)
        assert not err and decode(data, JobPage).entries == []
        assert station.request(SetMode("AUTO")).ok and station.request(SetMode("MANUAL")).ok
        data, err = ask(session, keys.log("runs/1"))
        assert err and b"no such log run" in data
        assert station.params().params, "the parameter door reads"

        expected = ["gateway: history", "gateway: param axis.x.kp_1_s", "control logic: acknowledge", "planner: load",
                    "logger: log state"]

        def alarmed() -> list[str]:
            with AlarmHistory(sup.history_path, readonly=True) as history:
                raised = [e for e in history.after(seq0, 1000).entries if e.id == "internal_error" and e.action == "raised"]
            return [want for want in expected if any(e.detail.startswith(want) for e in raised)]
        sup.wait_until(lambda: alarmed() == expected, 30.0, "an internal-error alarm for each bug")

        sup.set_sim(inject_bug="")
        data, err = ask(session, keys.alarms_history)
        assert not err and any(e.id == "internal_error" for e in decode(data, HistoryPage).entries)
        def listed() -> bool:
            data, err = ask(session, keys.alarms_active)
            return not err and any(a.id == "internal_error" for a in decode(data, AlarmList).alarms)
        assert listed(), "latched until reset"
        assert station.request(Reset()).ok
        sup.wait_until(lambda: not listed(), 30.0, "the reset to clear the internal errors")
        assert sup.logic.request(LoadProgram(str(path))).ok, "the planner loads again"
    finally:
        sup.set_sim(inject_bug="")
        station.close()
        session.close()
