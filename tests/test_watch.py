"""`waterjet watch` against the whole controller on the virtual clock: status at its rate, the
alarm history and live events, the human status line, no controller, another schema version,
and gaps in the alarm sequence filled from the history."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from cnc.bus.keys import Keys
from cnc.bus.messages import SCHEMA_VERSION, AlarmEvent, CycleStart, Status, decode
from cnc.bus.session import open_client, open_router
from cnc.data.layout import LinkState, PlannerState
from cnc.logic.states import CyclePhase, MachineState, Mode
from cnc.runtime.supervisor import Supervisor
from cnc.watch import AlarmFollower, History

from .conftest import MACHINE_FILE, REPO, free_port, full_controller, machine_config

WRONG_MODE = 37  # "Wrong operation mode": a refused CycleStart in MANUAL stores one


def _names(enum) -> str:
    return "|".join(m.name for m in enum)


# the human status line: states by their enum names, the table's X/Y, feed, jet, pump, link, alarms
STATE_LINE = re.compile(
    rf"\d\d:\d\d:\d\d (?:{_names(MachineState)}) (?:{_names(Mode)}) phase (?:{_names(CyclePhase)})"
    rf" \| planner (?:{_names(PlannerState)}) \| X +(?P<x>-?\d+\.\d{{3}}) Y +(?P<y>-?\d+\.\d{{3}})"
    r" \| feed +\d+\.\d mm/s \(\d+ %\) \| jet (?:ON|off) \| pump (?:ON|off) \d+ bar"
    rf" \| PLC (?:{_names(LinkState)}) \| alarms \d+(?: \((?:fatal|error|warning|info)\))? \| no program(?: \| FAULT .*)?"
)


@pytest.fixture(scope="module")
def controller(tmp_path_factory):
    """The whole controller, PLC simulator included, shared by the tests that only observe it."""
    config = machine_config()
    history = tmp_path_factory.mktemp("watch") / "history.sqlite"
    with full_controller(config, history) as sup:
        yield sup


def raise_wrong_mode(sup: Supervisor) -> None:
    """One new history entry (code 37), published as an AlarmEvent."""
    reply = sup.logic.request(CycleStart())
    assert not reply.ok and "wrong operation mode" in reply.reason, reply


def newest_seq(sup: Supervisor) -> int:
    return sup.area.reader("logic").read_dict()["alarm_seq"]


class Watch:
    """`python -m cnc.watch` as a subprocess, its stdout read line by line as it comes."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cnc.watch", "--machine", str(MACHINE_FILE), *args],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        self.lines: list[str] = []
        self.got_line = threading.Condition()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            with self.got_line:
                self.lines.append(line.rstrip("\n"))
                self.got_line.notify_all()

    def wait_for(self, predicate, timeout_s: float, what: str) -> None:
        with self.got_line:
            if not self.got_line.wait_for(lambda: any(predicate(line) for line in self.lines), timeout_s):
                raise TimeoutError(f"the watcher printed no {what} within {timeout_s:g} s: {self.lines[-5:]}")

    def finish(self, timeout_s: float = 30.0) -> tuple[int, list[str], str]:
        rc = self.proc.wait(timeout_s)
        self.reader.join(5.0)
        return rc, self.lines, self.proc.stderr.read()


def test_json_watch_sees_status_at_its_rate_the_history_before_it_and_the_alarms_during_it(controller):
    sup = controller
    for _ in range(2):
        raise_wrong_mode(sup)
    before = newest_seq(sup)
    watch = Watch("--connect", sup.config.zenoh.listen[0], "--json", "--seconds", "3")
    keys = sup.keys
    watch.wait_for(lambda line: json.loads(line)["key"] == keys.status, 10.0, "status")
    raise_wrong_mode(sup)
    rc, lines, err = watch.finish()
    assert rc == 0, err
    records = [json.loads(line) for line in lines]
    # every entry already stored, from the history, in sequence order
    history = [r["message"] for r in records if r["key"] == keys.alarms_history]
    assert [e["seq"] for e in history][:before] == list(range(1, before + 1))
    assert sum(1 for e in history if e["code"] == WRONG_MODE) >= 2
    # the one raised while it watched, live (other alarms may come and go meanwhile)
    live = [r["message"] for r in records if r["key"] == keys.event_alarm]
    assert any(e["seq"] > before and e["code"] == WRONG_MODE for e in live), live
    # together: every entry once, none missed
    seqs = [r["message"]["seq"] for r in records if r["key"] in (keys.alarms_history, keys.event_alarm)]
    assert seqs == list(range(1, len(seqs) + 1))
    # every status message, at the gateway's rate by their own publication stamps
    statuses = [decode(json.dumps(r["message"]).encode(), Status) for r in records if r["key"] == keys.status]
    span_s = (statuses[-1].stamp_ns - statuses[0].stamp_ns) / 1e9
    assert span_s > 1.0, f"status seen over {span_s:.2f} s only"
    rate_hz, expected_hz = (len(statuses) - 1) / span_s, sup.config.gateway.status_rate_hz
    assert 0.5 * expected_hz <= rate_hz <= 1.5 * expected_hz, f"{rate_hz:.1f} Hz, configured {expected_hz:g} Hz"
    assert [s.seq for s in statuses] == sorted(s.seq for s in statuses)


def test_human_watch_prints_the_history_one_state_line_a_second_and_each_alarm(controller):
    sup = controller
    raise_wrong_mode(sup)
    watch = Watch("--connect", sup.config.zenoh.listen[0], "--seconds", "2.5")
    watch.wait_for(lambda line: " phase " in line, 10.0, "status line")
    raise_wrong_mode(sup)
    rc, lines, err = watch.finish()
    assert rc == 0, err
    assert lines[0].startswith("alarm history: ") and "entries" in lines[0]
    state_lines = [line for line in lines if " phase " in line]
    assert 1 <= len(state_lines) <= 4, "about one a second, not the 20 Hz stream"
    match = STATE_LINE.fullmatch(state_lines[0])
    assert match, f"not a state line: {state_lines[0]!r}"
    assert (float(match["x"]), float(match["y"])) == (800.0, 600.0), "the table where the simulator switched it on"
    # the history block is indented under its heading; the live alarm comes on its own line
    live = re.compile(rf"\d\d:\d\d:\d\d #\d+ RAISED info {WRONG_MODE} Wrong operation mode: cycle start needs AUTO mode")
    assert any(live.match(line) for line in lines[lines.index(state_lines[0]):]), lines


def test_watch_exits_1_naming_the_endpoint_when_no_controller_runs():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    started = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "cnc.watch", "--machine", str(MACHINE_FILE), "--connect", endpoint],
                          cwd=REPO, capture_output=True, text=True, timeout=30)
    assert proc.returncode == 1
    assert f"no controller at {endpoint}: is it running?" in proc.stderr
    assert proc.stdout == ""
    assert time.monotonic() - started < 15.0


def test_watch_refuses_a_controller_speaking_another_schema_version():
    """A stand-in router answers the history with a page of a future schema version."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = open_router([endpoint])
    keys = Keys("wj", "waterjet")
    future = json.dumps({"entries": [], "last_seq": 0, "more": False, "version": SCHEMA_VERSION + 1}).encode()
    queryable = router.declare_queryable(keys.alarms_history, lambda q: q.reply(keys.alarms_history, future))
    try:
        proc = subprocess.run([sys.executable, "-m", "cnc.watch", "--machine", str(MACHINE_FILE), "--connect", endpoint,
                               "--seconds", "10"], cwd=REPO, capture_output=True, text=True, timeout=30)
    finally:
        queryable.undeclare()
        router.close()
    assert proc.returncode == 1
    assert f"refusing the controller at {endpoint}" in proc.stderr
    expected = f"HistoryPage: message schema version {SCHEMA_VERSION + 1} is not the supported version {SCHEMA_VERSION}"
    assert expected in proc.stderr


def test_a_gap_in_the_alarm_sequence_is_filled_from_the_history_without_repeats(controller):
    sup = controller
    session = open_client([sup.config.zenoh.listen[0]])
    try:
        seen: list[AlarmEvent] = []
        got = threading.Condition()

        def on_alarm(sample: zenoh.Sample) -> None:
            with got:
                seen.append(decode(sample.payload.to_bytes(), AlarmEvent))
                got.notify_all()

        sub = session.declare_subscriber(sup.keys.event_alarm, on_alarm)
        base = newest_seq(sup)
        follower = AlarmFollower(History(session, sup.keys, page_size=2), last_seq=base)  # small pages: paging too
        for _ in range(7):
            raise_wrong_mode(sup)
        with got:
            arrived = lambda: sum(1 for e in seen if e.code == WRONG_MODE)  # noqa: E731
            assert got.wait_for(lambda: arrived() == 7, 10.0), f"{arrived()} of 7 events arrived"
        sub.undeclare()
        live = sorted(seen, key=lambda e: e.seq)
        assert [e.seq for e in live] == list(range(base + 1, base + 1 + len(live)))
        # events base+2..base+5 are lost on the way (a reconnect): the next one brings them back
        shown = follower.accept(live[0]) + follower.accept(live[5])
        assert shown == live[:6], "the missed entries are read from the history, in order"
        assert shown[5] is live[5]
        assert follower.accept(live[3]) == [], "a late repeat is not shown twice"
        # the last event is lost too: a status announcing it makes the follower catch up
        assert follower.catch_up() == live[6:]
        assert follower.last_seq == live[-1].seq and follower.holes == []
    finally:
        session.close()


def test_a_gap_the_history_cannot_fill_yet_is_kept_and_filled_later(controller):
    """The control logic is away (restarting): the event is shown, the gap read once it answers."""
    sup = controller
    session = open_client([sup.config.zenoh.listen[0]])
    try:
        base = newest_seq(sup)
        for _ in range(3):
            raise_wrong_mode(sup)
        entries = History(session, sup.keys).after(base, up_to=base + 3)
        assert [e.seq for e in entries] == [base + 1, base + 2, base + 3]
        away = History(session, Keys(sup.keys.prefix, "no-such-machine"), timeout_s=0.5)  # nobody answers here
        follower = AlarmFollower(away, last_seq=base)
        assert follower.accept(entries[2]) == [entries[2]]
        assert follower.holes == [(base + 1, base + 2)]
        assert follower.fill_holes() == [] and follower.holes == [(base + 1, base + 2)]
        follower.history = History(session, sup.keys)  # the logic is back
        assert follower.fill_holes() == entries[:2]
        assert follower.holes == []
    finally:
        session.close()



@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_watch_without_a_time_limit_stops_with_0_on_sigint_and_sigterm(controller, signum):
    watch = Watch("--connect", controller.config.zenoh.listen[0])
    watch.wait_for(lambda line: " phase " in line, 10.0, "status line")
    watch.proc.send_signal(signum)
    rc, lines, err = watch.finish(10.0)
    assert rc == 0, err
    assert "Traceback" not in err
