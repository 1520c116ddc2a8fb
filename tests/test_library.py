"""The program library: the program directory listed with what `waterjet check` finds (made in the
background, once per version of a file), each program's last run, previews of programs that are
not loaded, and deletion; on its own with real files and SQLite, and over Zenoh in the whole
controller with the screen's rights (listing for anyone, deleting with the lock)."""

from __future__ import annotations

import os
import threading
from pathlib import Path
from urllib.parse import quote

import pytest

from cnc.bus.messages import DeleteProgram, LoadProgram, ProgramInfo, ProgramList
from cnc.bus.operator import OperatorStation
from cnc.bus.service import CommandRefused
from cnc.check import program_timing
from cnc.gateway.jobs import JobHistory
from cnc.gateway.library import ProgramLibrary
from cnc.machine_dialect import dialect_for
from cnc.programs import ProgramDirectory
from gcode.interp import Interpreter

from .conftest import machine_config
from .test_zenoh_interface import get

NEST = """(two parts, kerf compensated, a pierce each)
G21 G90 G64 P0.05 F3000
G0 X20 Y20
M3
G4 P0.2
G41 G1 X25 Y20
G1 X60
G1 Y50
G3 X50 Y60 R10
G1 X25
G1 Y20
G40 G1 X20 Y20
M5
G0 X100 Y20
M3
G1 X140 Y20
G1 Y60
M5
M2
"""
BROKEN = "G21 G90\nG0 X10\nG1 X20 Q5 F100\nM2\n"


def wait_for(what: str, ready, polls: int = 6000):
    """`ready()`'s value once it has one, asked every 50 ms; a generous bound (5 min of polls) for
    the background checks, which run at low priority on a busy host."""
    pause = threading.Event()
    for _ in range(polls):
        value = ready()
        if value:
            return value
        pause.wait(0.05)
    raise AssertionError(f"no {what} after {polls} polls")


def entries(library: ProgramLibrary, loaded: str = "") -> dict:
    return {e.name: e for e in library.listing(loaded).entries}


def all_checked(library: ProgramLibrary):
    found = entries(library)
    return found if found and all(e.summary != "pending" for e in found.values()) else None


@pytest.fixture
def library(tmp_path):
    config = machine_config()
    programs = tmp_path / "programs"
    programs.mkdir()
    lib = ProgramLibrary(ProgramDirectory(programs, config.gcode.max_program_bytes), tmp_path / "library.sqlite",
                         tmp_path / "jobs.sqlite", config)
    yield lib
    lib.close()


def test_every_program_is_listed_with_what_check_finds_or_why_it_is_refused(library, tmp_path):
    root = library.programs.root
    (root / "nest.ngc").write_text(NEST)
    (root / "broken.ngc").write_text(BROKEN)
    (root / "image.ngc").write_bytes(b"G0 X1\n\x00\x01\x02PNG")
    (root / ".upload.part").write_text("G0 X1\n")  # an upload in progress is not a program yet
    listed = entries(library)
    assert set(listed) == {"nest.ngc", "broken.ngc", "image.ngc"}
    assert listed["nest.ngc"].bytes == len(NEST.encode()) and listed["nest.ngc"].modified_ns > 0

    found = wait_for("the summaries", lambda: all_checked(library))
    config = library.config
    program = Interpreter(dialect_for(config), "nest.ngc").run(NEST.encode())
    planned = program_timing(program, config).total_ticks * config.timing.period_s
    nest = found["nest.ngc"]
    assert nest.summary == "ready" and nest.error == ""
    assert (nest.lines, nest.segments, nest.pierces) == (program.stats.lines, program.stats.segments, 2)
    assert nest.cut_length_mm == pytest.approx(program.stats.cut_length_mm)
    assert nest.planned_s == pytest.approx(planned) and planned > 1.0, "the cycle time waterjet check plans"
    assert found["broken.ngc"].summary == "refused" and found["broken.ngc"].error.startswith("broken.ngc:3:")
    assert found["image.ngc"].summary == "refused" and "not text" in found["image.ngc"].error
    assert found["nest.ngc"].last_result == "" and found["nest.ngc"].last_run_end_ns == 0, "never run"


def test_a_changed_file_is_checked_again_and_the_last_run_is_shown(library):
    root = library.programs.root
    (root / "part.ngc").write_text(BROKEN)
    assert wait_for("the first check", lambda: all_checked(library))["part.ngc"].summary == "refused"
    made = library.summaries_made
    (root / "part.ngc").write_text(NEST)
    os.utime(root / "part.ngc", ns=(1, 1))  # another version of the file, whatever the clock's resolution
    assert entries(library)["part.ngc"].summary == "pending", "the old figures are not shown for the new text"
    assert wait_for("the second check", lambda: all_checked(library))["part.ngc"].summary == "ready"
    assert library.summaries_made == made + 1, "checked once per version"
    entries(library)
    assert library.summaries_made == made + 1

    jobs = JobHistory(library.jobs_path)
    jobs.append("part.ngc", "h1", 10, 20, "ABORTED", 3.0)
    jobs.append("other.ngc", "h2", 30, 40, "DONE", 4.0)
    jobs.append("part.ngc", "h3", 50, 90, "DONE", 5.5, 5.4)
    jobs.close()
    part = entries(library)["part.ngc"]
    assert (part.last_result, part.last_run_end_ns, part.last_cycle_s) == ("DONE", 90, 5.5)


def test_deleting_removes_the_program_and_nothing_outside_the_directory(library, tmp_path):
    root = library.programs.root
    (root / "part.ngc").write_text(NEST)
    (root / "keep.ngc").write_text(NEST)
    (root / "link.ngc").symlink_to(root / "keep.ngc")
    (root / "sub").mkdir()
    (root / "sub" / "deep.ngc").write_text(NEST)
    outside = tmp_path / "secret.ngc"
    outside.write_text("G0 X1\nM2\n")
    wait_for("the summaries", lambda: all_checked(library))
    library.delete("part.ngc")
    assert not (root / "part.ngc").exists() and "part.ngc" not in entries(library)
    library.delete("link.ngc")
    assert not (root / "link.ngc").exists() and (root / "keep.ngc").read_text() == NEST, "the link, not its target"
    for name, why in (("../secret.ngc", "plain name"), ("sub/deep.ngc", "plain name"), ("sub", "not a program file"),
                      ("gone.ngc", "no such program"), (".hidden", "plain name"), ("", "plain name")):
        with pytest.raises(CommandRefused, match=why):
            library.delete(name)
    assert outside.exists() and (root / "sub" / "deep.ngc").exists()


def test_the_library_over_zenoh_lists_previews_loads_and_deletes(library_controller, tmp_path):
    """An observer lists and previews; the lock holder loads from the list and deletes; the
    loaded program is marked, a preview loads nothing, a refused program's preview says where."""
    from cnc.bus.keys import Keys
    from cnc.bus.session import open_client

    sup = library_controller
    keys = Keys(sup.config.zenoh.key_prefix, sup.config.machine.name)
    programs = tmp_path / "programs"
    programs.mkdir(exist_ok=True)
    (programs / "nest.ngc").write_text(NEST)
    (programs / "broken part.ngc").write_text(BROKEN)
    session = open_client([sup.config.zenoh.listen[0]])
    op = OperatorStation(session, keys, "op")
    try:
        assert get(session, keys.programs, ProgramList).directory == str(programs)
        listed = wait_for("the library's summaries", lambda: _checked(get(session, keys.programs, ProgramList)))
        assert set(listed) == {"nest.ngc", "broken part.ngc"}
        assert listed["nest.ngc"].planned_s > 1.0 and not listed["nest.ngc"].loaded

        preview = get(session, f"{keys.program_preview}?name={quote('nest.ngc', safe='')}", ProgramInfo)
        assert preview.text == NEST and preview.path is not None and len(preview.path.kind) >= 10
        assert preview.planned_s == pytest.approx(listed["nest.ngc"].planned_s) and not preview.errors
        assert sup.motion()["program_name"] == "", "a preview loads nothing"
        broken = get(session, f"{keys.program_preview}?name={quote('broken part.ngc', safe='')}", ProgramInfo)
        assert broken.path is None and (broken.errors[0].line, broken.errors[0].column) == (3, 8)
        refused = list(session.get(f"{keys.program_preview}?name={quote('../history.sqlite', safe='')}", timeout=10.0))
        assert refused[0].ok is None and "outside the program directory" in refused[0].err.payload.to_string()

        assert "take it first" in op.request(DeleteProgram("nest.ngc")).reason, "deleting needs the lock"
        assert op.take_lock().ok
        reply = op.request(LoadProgram("broken part.ngc"))
        assert not reply.ok and reply.errors and reply.errors[0].line == 3, reply
        assert op.request(LoadProgram("nest.ngc")).ok
        assert sup.motion()["program_name"] == "nest.ngc"
        loaded = get(session, f"{keys.program}?path=1", ProgramInfo)
        assert loaded.text == NEST and loaded.path is not None, "a program loaded by name is previewed like an upload"
        assert [e.name for e in get(session, keys.programs, ProgramList).entries if e.loaded] == ["nest.ngc"]

        reply = op.request(DeleteProgram("nest.ngc"))
        assert reply.ok and "keeps it loaded" in reply.reason, reply
        assert not (programs / "nest.ngc").exists()
        assert [e.name for e in get(session, keys.programs, ProgramList).entries] == ["broken part.ngc"]
    finally:
        op.close()
        session.close()


def _checked(listing: ProgramList) -> dict | None:
    """The listing's entries by name once none is pending."""
    by_name = {e.name: e for e in listing.entries}
    return by_name if by_name and all(e.summary != "pending" for e in by_name.values()) else None
