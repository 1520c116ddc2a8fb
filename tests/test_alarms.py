"""Alarms and messages: the catalogue, the SQLite history (sequence, catch-up, filters, crash
survival) and the alarm book (latching, reset, acknowledge, restart, stored before published)."""

from __future__ import annotations

import dataclasses
import os
import re
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time
from contextlib import closing

import pytest

from cnc.alarms import (
    AlarmAction,
    AlarmBook,
    AlarmHistory,
    AlarmLevel,
    Catalogue,
    HistoryError,
    UnknownAlarm,
)
from cnc.bus.messages import AlarmEvent, decode, encode
from cnc.config import load_machine

from .conftest import MACHINE_FILE, REPO

DAY_NS = 86400 * 10**9


@pytest.fixture(scope="module")
def catalogue() -> Catalogue:
    return Catalogue(load_machine(MACHINE_FILE))


class FakeClock:
    """Wall-clock time the test sets: 1 s per reading, from a fixed start."""

    def __init__(self, start_ns: int = 1_700_000_000 * 10**9) -> None:
        self.now_ns = start_ns

    def __call__(self) -> int:
        self.now_ns += 10**9
        return self.now_ns


def append(history: AlarmHistory, stamp_ns: int = 0, code: int = 1001, id: str = "estop",
           level: AlarmLevel = AlarmLevel.FATAL, action: AlarmAction = AlarmAction.RAISED,
           text: str = "Emergency stop", detail: str = "") -> AlarmEvent:
    return history.append(stamp_ns=stamp_ns, code=code, id=id, level=level, action=action, text=text, detail=detail)


def open_book(path, catalogue, published=None, clock=None) -> AlarmBook:
    sink = published if published is not None else []
    return AlarmBook(catalogue, AlarmHistory(path), sink.append, clock or FakeClock())


# -- catalogue -------------------------------------------------------------------------------


def test_levels_are_ordered_by_severity_and_fatal_and_error_stop_the_cut():
    assert sorted([AlarmLevel.WARNING, AlarmLevel.FATAL, AlarmLevel.INFO, AlarmLevel.ERROR]) == [
        AlarmLevel.INFO, AlarmLevel.WARNING, AlarmLevel.ERROR, AlarmLevel.FATAL,
    ]
    assert [lv.stops_cut for lv in AlarmLevel] == [False, False, True, True]
    assert AlarmLevel.parse("warning") is AlarmLevel.WARNING and AlarmLevel.ERROR.text == "error"
    with pytest.raises(ValueError, match="'severe' is not one of info, warning, error, fatal"):
        AlarmLevel.parse("severe")


def test_catalogue_finds_entries_by_id_and_by_code(catalogue):
    estop = catalogue.entry("estop")
    assert (estop.code, estop.level, estop.text) == (1001, AlarmLevel.FATAL, "Emergency stop")
    assert catalogue.by_code(1001) is estop and catalogue.lookup(1001) is estop and catalogue.lookup("estop") is estop
    assert catalogue.entry("procedure_stop").level is AlarmLevel.WARNING
    assert "x_drive" in catalogue and "nonsense" not in catalogue
    assert len(catalogue) == len(list(catalogue)) > 10


def test_unknown_alarm_id_or_code_is_a_key_error_naming_it_and_the_machine_file(catalogue):
    with pytest.raises(KeyError) as caught:
        catalogue.entry("x_drvie")
    assert isinstance(caught.value, UnknownAlarm)
    assert str(caught.value) == f"alarm id 'x_drvie' is not in the [[alarm]] catalogue of {MACHINE_FILE}"
    with pytest.raises(UnknownAlarm, match="alarm code 4242 is not in the"):
        catalogue.by_code(4242)


# -- history ---------------------------------------------------------------------------------


def test_sequence_numbers_increase_by_one_per_entry_and_continue_after_reopening(tmp_path):
    path = tmp_path / "history.sqlite"
    with AlarmHistory(path) as history:
        assert history.last_seq() == 0
        assert [append(history, detail=str(k)).seq for k in range(5)] == [1, 2, 3, 4, 5]
    with AlarmHistory(path) as history:
        assert history.last_seq() == 5
        assert [append(history).seq for _ in range(3)] == [6, 7, 8]
        assert [e.detail for e in history.after(0).entries[:5]] == ["0", "1", "2", "3", "4"]


def test_sequence_numbers_are_never_reused_after_pruning_every_entry(tmp_path):
    path = tmp_path / "history.sqlite"
    with AlarmHistory(path) as history:
        for _ in range(4):
            append(history, stamp_ns=0)
        assert history.prune(keep_days=1, now_ns=10 * DAY_NS) == 4
        assert history.after(0).entries == [] and history.last_seq() == 4
    with AlarmHistory(path) as history:
        assert append(history).seq == 5


def test_prune_deletes_only_entries_older_than_kept_days_and_spares_kept_sequence(tmp_path):
    with AlarmHistory(tmp_path / "h.sqlite") as history:
        for day in range(10):
            append(history, stamp_ns=day * DAY_NS)
        now_ns = 10 * DAY_NS
        assert history.prune(keep_days=7, now_ns=now_ns, keep_from_seq=2) == 1  # only day 0 (seq 1)
        assert history.prune(keep_days=7, now_ns=now_ns) == 2  # days 1 and 2; day 3 is exactly 7 days old
        assert [e.seq for e in history.after(0).entries] == [4, 5, 6, 7, 8, 9, 10]
        with pytest.raises(ValueError, match="keep_days must be positive, got 0"):
            history.prune(0)


def test_catch_up_after_a_sequence_number_returns_exactly_the_missed_entries(tmp_path):
    with AlarmHistory(tmp_path / "h.sqlite") as history:
        events = [append(history, detail=f"#{k}") for k in range(10)]
        seen_by_subscriber = 4
        page = history.after(seen_by_subscriber, limit=3)
        assert page.entries == events[4:7] and page.more and page.last_seq == 10
        page = history.after(page.entries[-1].seq, limit=3)
        assert page.entries == events[7:10] and not page.more
        assert history.after(10).entries == [] and not history.after(10).more
        with pytest.raises(ValueError, match="limit must be 1 to 1000, got 0"):
            history.after(0, limit=0)


def test_entries_round_trip_through_the_bus_encoding(tmp_path):
    with AlarmHistory(tmp_path / "h.sqlite") as history:
        event = history.append(stamp_ns=123, code=1010, id="following_error", level=AlarmLevel.ERROR,
                               action=AlarmAction.CLEARED, text="Following error too large", detail="X 2.5 mm",
                               source="servo", cause="c", remedy="r")
        stored = history.after(0).entries[0]
    assert stored == event
    assert decode(encode(stored), AlarmEvent) == event
    assert (stored.level, stored.action, stored.detail, stored.source) == ("error", "cleared", "X 2.5 mm", "servo")


@pytest.fixture
def mixed_history(tmp_path):
    """Twenty entries, one per second: errors, warnings and infos with varied text."""
    history = AlarmHistory(tmp_path / "h.sqlite")
    kinds = [
        (1010, "following_error", AlarmLevel.ERROR, "Following error too large", "Axis X"),
        (37, "wrong_mode", AlarmLevel.WARNING, "Wrong operation mode", "cycle start in MANUAL"),
        (2841, "press_start", AlarmLevel.INFO, "Press start button", ""),
        (1001, "estop", AlarmLevel.FATAL, "Emergency stop", "Tür offen"),
    ]
    for k in range(20):
        code, id, level, text, detail = kinds[k % 4]
        append(history, stamp_ns=k * 10**9, code=code, id=id, level=level, text=text, detail=detail)
    yield history
    history.close()


def test_query_filters_by_time_level_code_and_text(mixed_history):
    def seqs(**filters):
        return [e.seq for e in mixed_history.query(newest_first=False, **filters).entries]

    assert seqs(since_ns=5 * 10**9, until_ns=9 * 10**9) == [6, 7, 8, 9]  # stamps 5..8 s: half open
    assert seqs(levels=[AlarmLevel.FATAL, AlarmLevel.WARNING]) == [2, 4, 6, 8, 10, 12, 14, 16, 18, 20]
    assert seqs(codes=[1010]) == [1, 5, 9, 13, 17]
    assert seqs(codes=[]) == [] and seqs(levels=[]) == []
    assert seqs(text="FOLLOWING") == [1, 5, 9, 13, 17]  # case ignored, in the text
    assert seqs(text="manual") == [2, 6, 10, 14, 18]  # in the detail
    assert seqs(text="TÜR") == [4, 8, 12, 16, 20]  # Unicode case folding, not ASCII-only LIKE
    assert seqs(text="press_start", since_ns=10 * 10**9) == [11, 15, 19]  # in the id, with a time filter
    assert seqs(text="100%") == []  # LIKE wildcards mean nothing here


def test_query_pages_newest_first_by_offset_and_by_before_seq(mixed_history):
    errors = {"levels": [AlarmLevel.ERROR, AlarmLevel.FATAL]}
    first = mixed_history.query(limit=4, **errors)
    assert [e.seq for e in first.entries] == [20, 17, 16, 13] and first.more and first.last_seq == 20
    by_offset = mixed_history.query(limit=4, offset=4, **errors)
    by_keyset = mixed_history.query(limit=4, before_seq=first.entries[-1].seq, **errors)
    assert [e.seq for e in by_keyset.entries] == [e.seq for e in by_offset.entries] == [12, 9, 8, 5]
    last = mixed_history.query(limit=4, before_seq=5, **errors)
    assert [e.seq for e in last.entries] == [4, 1] and not last.more
    oldest_first = mixed_history.query(limit=3, after_seq=17, newest_first=False)
    assert [e.seq for e in oldest_first.entries] == [18, 19, 20] and not oldest_first.more


def test_a_read_only_reader_sees_each_committed_entry_while_the_writer_stays_open(tmp_path):
    path = tmp_path / "h.sqlite"
    with AlarmHistory(path) as writer, AlarmHistory(path, readonly=True) as reader:
        assert reader.last_seq() == 0
        for k in range(1, 4):
            event = append(writer, detail=str(k))
            assert reader.after(k - 1).entries == [event] and reader.last_seq() == k
        with pytest.raises(HistoryError, match="append refused, the history is open read-only"):
            append(reader)
        with closing(sqlite3.connect(path)) as db:
            assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_opening_a_history_creates_its_directory(tmp_path):
    path = tmp_path / "var" / "lib" / "waterjet" / "history.sqlite"
    with AlarmHistory(path) as history:
        append(history)
    assert path.is_file()


def test_a_file_that_is_not_an_alarm_history_is_refused_naming_the_path(tmp_path):
    garbage = tmp_path / "notes.sqlite"
    garbage.write_bytes(b"this is a shopping list, not a database\n" * 200)
    for readonly in (False, True):
        with pytest.raises(HistoryError, match=f"{re.escape(str(garbage))}: not a usable alarm history database"):
            AlarmHistory(garbage, readonly=readonly)
    assert garbage.read_bytes().startswith(b"this is a shopping list")

    foreign = tmp_path / "other.sqlite"
    with closing(sqlite3.connect(foreign)) as db:
        db.execute("CREATE TABLE parts (name TEXT)")
    with pytest.raises(HistoryError, match=f"{re.escape(str(foreign))}: an SQLite database of another program"):
        AlarmHistory(foreign)

    with pytest.raises(HistoryError, match=f"{re.escape(str(tmp_path / 'missing.sqlite'))}: no alarm history file there"):
        AlarmHistory(tmp_path / "missing.sqlite", readonly=True)


def test_a_damaged_history_is_refused_naming_the_path(tmp_path):
    path = tmp_path / "h.sqlite"
    with AlarmHistory(path) as history:
        for k in range(300):
            append(history, detail="x" * 200 + str(k))
    with closing(sqlite3.connect(path)) as db:  # fold the WAL into the main file so the damage sticks
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    data = bytearray(path.read_bytes())
    data[4096 * 3: 4096 * 6] = b"\xff" * (4096 * 3)
    path.write_bytes(bytes(data))
    with pytest.raises(HistoryError, match=f"^{re.escape(str(path))}: .*malformed"):
        AlarmHistory(path)
    with AlarmHistory(path, readonly=True) as reader:  # readers skip the check, and fail at reading
        with pytest.raises(HistoryError, match=f"^{re.escape(str(path))}: cannot read .*malformed"):
            reader.after(0, 1000)


# The child appends as fast as it can and reports each seq only after append() returned.
CHILD = textwrap.dedent("""
    import sys
    from cnc.alarms import AlarmAction, AlarmHistory, AlarmLevel
    history = AlarmHistory(sys.argv[1])
    k = 0
    while True:
        event = history.append(stamp_ns=k, code=1001, id="estop", level=AlarmLevel.FATAL,
                               action=AlarmAction.RAISED, text="Emergency stop", detail=str(k))
        sys.stdout.write(f"{event.seq} {k}\\n")
        sys.stdout.flush()
        k += 1
""")


def read_reports(child: subprocess.Popen, reader: AlarmHistory, count: int) -> list[tuple[int, int]]:
    """(seq, k) pairs the child reported; every 50th is looked up at once by another connection."""
    reported: list[tuple[int, int]] = []
    deadline = time.monotonic() + 10.0
    while len(reported) < count:
        line = child.stdout.readline()
        assert line, f"the writer died on its own (exit {child.poll()})"
        seq, k = map(int, line.split())
        reported.append((seq, k))
        if k % 50 == 0:  # what append() returned is visible to a reader at once
            assert [(e.seq, e.detail) for e in reader.after(seq - 1, 1).entries] == [(seq, str(k))]
        assert time.monotonic() < deadline, f"only {len(reported)} entries in 10 s"
    return reported


def test_every_entry_a_killed_writer_reported_is_in_the_history_in_order(tmp_path):
    path = tmp_path / "h.sqlite"
    with AlarmHistory(path) as history:
        for _ in range(7):
            append(history, detail="before")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-c", CHILD, str(path)]
    with subprocess.Popen(argv, stdout=subprocess.PIPE, env=env, text=True) as child, \
            AlarmHistory(path, readonly=True) as reader:
        try:
            reported = read_reports(child, reader, count=400)
            os.kill(child.pid, signal.SIGKILL)  # mid-stream: it is appending as fast as it can
            tail = child.stdout.read()  # what it reported between our last read and the kill
        finally:
            child.kill()  # the child never ends by itself: never leave it running
    assert child.returncode == -signal.SIGKILL
    reported += [tuple(map(int, line.split())) for line in tail.splitlines(keepends=True) if line.endswith("\n")]

    seqs = [seq for seq, _ in reported]
    assert seqs == list(range(8, 8 + len(seqs)))
    assert [k for _, k in reported] == list(range(len(reported)))
    with AlarmHistory(path) as history:  # opens cleanly: WAL recovery and quick_check pass
        stored, page = {}, history.after(7, 1000)
        while page.entries:
            stored.update((e.seq, e.detail) for e in page.entries)
            page = history.after(page.entries[-1].seq, 1000)
        assert all(stored.get(seq) == str(k) for seq, k in reported)
        assert sorted(stored)[: len(seqs)] == seqs  # in order, nothing missing between them
        after_crash = append(history)
        assert after_crash.seq == max(stored) + 1
    with closing(sqlite3.connect(path)) as db:
        assert db.execute("PRAGMA integrity_check").fetchall() == [("ok",)]


# -- alarm book ------------------------------------------------------------------------------


def test_every_entry_is_in_the_database_before_it_is_published(tmp_path, catalogue):
    path = tmp_path / "h.sqlite"
    checked: list[int] = []
    with AlarmHistory(path) as history, AlarmHistory(path, readonly=True) as other_connection:

        def publish(event: AlarmEvent) -> None:
            assert other_connection.after(event.seq - 1, 1).entries == [event]
            checked.append(event.seq)

        book = AlarmBook(catalogue, history, publish, FakeClock())
        book.raise_("x_drive", "drive 1 reports fault 7", "logic")
        book.message("cycle_done", "part.ngc", "planner")
        book.clear("x_drive")
        book.acknowledge()
        book.reset()
    assert checked == [1, 2, 3, 4, 5]


def test_published_entries_carry_the_catalogue_fields_and_the_clock(tmp_path, catalogue):
    published: list[AlarmEvent] = []
    clock = FakeClock()
    book = open_book(tmp_path / "h.sqlite", catalogue, published, clock)
    book.raise_("following_error", "X 2.51 mm", "servo")
    event = published[0]
    assert event == AlarmEvent(
        1, clock.now_ns, 1010, "following_error", "error", "raised", "Following error too large", "X 2.51 mm",
        "servo", catalogue.entry("following_error").cause, catalogue.entry("following_error").remedy,
    )


def test_raising_an_active_alarm_again_writes_nothing(tmp_path, catalogue):
    published: list[AlarmEvent] = []
    book = open_book(tmp_path / "h.sqlite", catalogue, published)
    assert book.raise_("following_error", "X")
    assert not book.raise_("following_error", "X")
    assert not book.raise_("following_error", "X", source="another check")
    assert book.raise_("following_error", "Y")  # same alarm on another axis: listed on its own
    assert [(e.seq, e.detail) for e in published] == [(1, "X"), (2, "Y")]
    assert book.history.last_seq() == 2
    assert [(a.id, a.detail) for a in book.active().alarms] == [("following_error", "X"), ("following_error", "Y")]


def test_a_cleared_alarm_stays_latched_until_reset(tmp_path, catalogue):
    published: list[AlarmEvent] = []
    book = open_book(tmp_path / "h.sqlite", catalogue, published)
    book.raise_("doors_open")
    assert book.clear("doors_open")
    assert not book.clear("doors_open")  # already cleared: nothing to write
    (alarm,) = book.active().alarms
    assert (alarm.id, alarm.active) == ("doors_open", False)
    assert book.blocking() and book.highest_level() is AlarmLevel.ERROR
    assert book.reset() == []
    assert book.active().alarms == [] and not book.blocking() and book.highest_level() is None
    assert [e.action for e in published] == ["raised", "cleared", "reset"]


def test_a_latched_alarm_raised_again_is_a_new_unacknowledged_occurrence(tmp_path, catalogue):
    book = open_book(tmp_path / "h.sqlite", catalogue)
    book.raise_("doors_open")
    book.clear("doors_open")
    book.acknowledge("doors_open")
    assert book.raise_("doors_open")
    (alarm,) = book.active().alarms
    assert (alarm.active, alarm.acknowledged, alarm.raised_seq) == (True, False, 4)


def test_info_prompts_are_not_latched_and_leave_the_list_when_cleared(tmp_path, catalogue):
    book = open_book(tmp_path / "h.sqlite", catalogue)
    book.raise_("press_start")
    assert [a.id for a in book.active().alarms] == ["press_start"] and not book.blocking()
    assert book.highest_level() is AlarmLevel.INFO
    book.clear("press_start")
    assert book.active().alarms == []


def test_reset_refuses_alarms_whose_condition_is_still_active(tmp_path, catalogue):
    published: list[AlarmEvent] = []
    book = open_book(tmp_path / "h.sqlite", catalogue, published)
    book.raise_("estop", source="safety")
    book.raise_("x_drive")
    book.raise_("press_start")
    book.clear("x_drive")
    refused = book.reset()
    assert [(a.id, a.active) for a in refused] == [("estop", True)]  # the info prompt is no alarm to reset
    assert [a.id for a in book.active().alarms] == ["estop", "press_start"]
    assert book.blocking() and book.highest_level() is AlarmLevel.FATAL
    assert [(e.id, e.action) for e in published[-1:]] == [("x_drive", "reset")]
    book.clear("estop")
    assert book.reset() == [] and [a.id for a in book.active().alarms] == ["press_start"]


def test_acknowledge_marks_one_alarm_by_code_or_id_or_all(tmp_path, catalogue):
    published: list[AlarmEvent] = []
    book = open_book(tmp_path / "h.sqlite", catalogue, published)
    book.raise_("following_error", "X")
    book.raise_("following_error", "Y")
    book.raise_("procedure_stop")
    book.raise_("estop")
    assert book.acknowledge(1010) == 2  # by code: both axes
    assert book.acknowledge("following_error") == 0  # already seen: no new entries
    assert {a.id: a.acknowledged for a in book.active().alarms} == {
        "following_error": True, "procedure_stop": False, "estop": False,
    }
    assert book.acknowledge() == 2
    assert all(a.acknowledged for a in book.active().alarms)
    assert [e.action for e in published].count("acknowledged") == 4
    assert book.blocking()  # seen is not reset
    with pytest.raises(UnknownAlarm, match="alarm code 999 is not in the"):
        book.acknowledge(999)


def test_a_restarted_book_rebuilds_its_active_list_from_the_history(tmp_path, catalogue):
    path = tmp_path / "h.sqlite"
    book = open_book(path, catalogue)
    book.raise_("estop")
    book.raise_("following_error", "X")
    book.raise_("x_drive")
    book.raise_("press_start")
    book.message("cycle_done", "part.ngc")
    book.clear("x_drive")
    book.reset()  # x_drive leaves the list
    book.clear("following_error")
    book.acknowledge("estop")
    before = book.active()
    book.history.close()  # the process dies here: nothing else is kept

    published: list[AlarmEvent] = []
    restarted = open_book(path, catalogue, published)
    after = restarted.active()
    # info prompts are not rebuilt: the live logic raises them again if their condition holds
    assert [a for a in before.alarms if a.level != "info"] == after.alarms
    assert [(a.id, a.active, a.acknowledged) for a in after.alarms] == [
        ("estop", True, True), ("following_error", False, False),
    ]
    assert after.last_seq == before.last_seq == 9
    assert restarted.blocking()
    assert not restarted.raise_("estop")  # still active after the restart: no duplicate entry
    restarted.clear("estop")
    assert restarted.reset() == [] and restarted.active().alarms == []
    assert [e.seq for e in published] == [10, 11, 12]


def test_messages_are_stored_and_published_but_never_listed(tmp_path, catalogue):
    published: list[AlarmEvent] = []
    book = open_book(tmp_path / "h.sqlite", catalogue, published)
    event = book.message("program_message", "MSG, check the nozzle", "planner")
    assert published == [event] and book.history.after(0).entries == [event]
    assert (event.level, event.action, event.detail) == ("info", "raised", "MSG, check the nozzle")
    assert book.active().alarms == [] and book.active().last_seq == 1
    with pytest.raises(ValueError, match="alarm 'estop' is level fatal: only info-level entries"):
        book.message("estop")
    with pytest.raises(UnknownAlarm, match="'no_such_message'"):
        book.message("no_such_message")
    assert book.history.last_seq() == 1


def test_unknown_alarm_ids_are_refused_before_anything_is_written(tmp_path, catalogue):
    book = open_book(tmp_path / "h.sqlite", catalogue)
    for call in (lambda: book.raise_("x_drvie"), lambda: book.clear("x_drvie")):
        with pytest.raises(UnknownAlarm, match="alarm id 'x_drvie' is not in the"):
            call()
    assert book.history.last_seq() == 0


def test_pruning_keeps_the_entries_a_restart_needs_for_listed_alarms(tmp_path, catalogue):
    path = tmp_path / "h.sqlite"
    clock = FakeClock()
    book = open_book(path, catalogue, clock=clock)
    book.raise_("procedure_stop")
    book.clear("procedure_stop")
    book.reset()
    book.raise_("estop")  # seq 4, still active a year later
    book.message("cycle_done")
    clock.now_ns += 400 * DAY_NS
    book.message("cycle_done")
    assert book.prune(keep_days=365) == 3  # the finished procedure_stop alarm only
    book.history.close()
    restarted = open_book(path, catalogue, clock=clock)
    assert [(a.id, a.raised_seq) for a in restarted.active().alarms] == [("estop", 4)]


def test_an_alarm_the_machine_file_no_longer_declares_comes_back_latched_and_resets(tmp_path, catalogue):
    path = tmp_path / "h.sqlite"
    book = open_book(path, catalogue)
    book.raise_("plc_error", "PLC alarm 17")
    book.raise_("estop")
    book.history.close()
    config = load_machine(MACHINE_FILE)
    shrunk = Catalogue(dataclasses.replace(config, alarm=[a for a in config.alarm if a.id != "plc_error"]))
    restarted = open_book(path, shrunk)
    assert [(a.id, a.active) for a in restarted.active().alarms] == [("plc_error", False), ("estop", True)]
    assert [a.id for a in restarted.reset()] == ["estop"]
    assert [a.id for a in restarted.active().alarms] == ["estop"]


def older_file(path, *statements: str):
    """A store as an older version wrote it: its statements run on a new SQLite file."""
    import sqlite3

    db = sqlite3.connect(path)
    for statement in statements:
        db.execute(statement)
    db.commit()
    db.close()
    return path


def test_cut_points_written_before_how_far_into_the_segment_was_kept_are_migrated_and_read(tmp_path):
    """An older jobs.sqlite whose cut points lack segment_mm: read as unknown (-1, an arc's first
    turn) before and after the writer adds the column; a new cut point keeps it."""
    from cnc.gateway.jobs import CutPoint, CutPoints

    path = older_file(tmp_path / "jobs.sqlite",
                      "CREATE TABLE cut_points (hash TEXT PRIMARY KEY, program TEXT NOT NULL, segment INTEGER NOT NULL, "
                      "x_mm REAL NOT NULL, y_mm REAL NOT NULL, line INTEGER NOT NULL, updated_ns INTEGER NOT NULL)",
                      "INSERT INTO cut_points VALUES ('h', 'old.ngc', 4, 10.5, 20.25, 9, 1)")
    reader = CutPoints(path, readonly=True)
    assert reader.get("h") == CutPoint("h", "old.ngc", 4, 10.5, 20.25, 9, 1, -1.0)
    writer = CutPoints(path)
    assert writer.get("h").segment_mm == -1.0
    writer.save(CutPoint("h2", "new.ngc", 7, 1.0, 2.0, 12, 5, segment_mm=180.5))
    assert CutPoints(path, readonly=True).get("h2") == CutPoint("h2", "new.ngc", 7, 1.0, 2.0, 12, 5, 180.5)
    writer.close()
    reader.close()


def test_a_job_history_written_before_planned_times_were_kept_is_migrated_and_read(tmp_path):
    """An older jobs.sqlite (no planned_s column) is read as before, and the writer adds the column:
    its old runs read -1 (not known), new runs keep their planned cycle time."""
    from cnc.gateway.jobs import JobHistory

    path = older_file(tmp_path / "jobs.sqlite",
                      "CREATE TABLE jobs (seq INTEGER PRIMARY KEY AUTOINCREMENT, program TEXT NOT NULL, hash TEXT NOT NULL, "
                      "start_ns INTEGER NOT NULL, end_ns INTEGER NOT NULL, result TEXT NOT NULL, cycle_time_s REAL NOT NULL)",
                      "INSERT INTO jobs (program, hash, start_ns, end_ns, result, cycle_time_s) "
                      "VALUES ('old.ngc', 'h', 1, 2, 'DONE', 9.5)")
    reader = JobHistory(path, readonly=True)
    assert [(j.program, j.cycle_time_s, j.planned_s) for j in reader.page().entries] == [("old.ngc", 9.5, -1.0)]
    writer = JobHistory(path)
    writer.append("new.ngc", "h2", 3, 4, "DONE", 12.0, 11.25)
    assert [(j.program, j.planned_s) for j in JobHistory(path, readonly=True).page().entries] == [("new.ngc", 11.25),
                                                                                               ("old.ngc", -1.0)]
    writer.close()
    reader.close()
