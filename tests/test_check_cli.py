"""`waterjet check`: summary and exit 0 for a valid program, the error with its line and caret and exit 1 otherwise."""

from __future__ import annotations

import json
import subprocess
import sys

from .conftest import MACHINE_FILE, REPO

PART = """%
(leather part 12)
G21 G90 G17
G0 X100 Y100
M3
G4 P0.4
G41 D1 G1 X110 Y100 F1200
G1 X110 Y150
G3 X100 Y160 R10
G1 X50 Y160
G40 G1 X40 Y160
M5
G0 X0 Y0
M2
%
"""


def check(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "cnc.cli", "check", *args, "--machine", str(MACHINE_FILE)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )


def test_valid_program_prints_a_summary_and_exits_0(tmp_path):
    prog = tmp_path / "part.ngc"
    prog.write_text(PART)
    res = check(str(prog))
    assert res.returncode == 0, res.stderr
    out = res.stdout
    assert f"{prog}: valid" in out
    for needle in ("lines            15", "pierces          1", "dwell            0.40 s", "bounds X", "within travel"):
        assert needle in out, out
    assert res.stderr == "", "no progress bar when stderr is not a terminal"


def test_segments_file_is_the_exchange_format(tmp_path):
    prog, seg = tmp_path / "part.ngc", tmp_path / "part.jsonl"
    prog.write_text(PART)
    assert check(str(prog), "--segments", str(seg)).returncode == 0
    recs = [json.loads(line) for line in seg.read_text().splitlines()]
    assert [r["kind"] for r in recs] == ["rapid", "dwell", "line", "line", "arc", "line", "line", "rapid"]
    assert recs[0] == {"kind": "rapid", "start": [0.0, 0.0, 0.0], "end": [100.0, 100.0, 0.0], "feed": None, "line": 4}
    assert recs[1] == {"kind": "dwell", "seconds": 0.4, "line": 6}
    assert recs[4]["cw"] is False and recs[4]["turns"] == 0 and recs[4]["feed"] == 1200.0
    # kerf 0.25 mm from nozzle 1 of the machine file: the vertical edge is cut 0.125 mm to the left
    assert recs[3]["start"][0] == recs[3]["end"][0] == 110.0 - 0.125


def test_tool_table_option_overrides_the_machines_nozzles(tmp_path):
    prog, seg, tbl = tmp_path / "part.ngc", tmp_path / "part.jsonl", tmp_path / "t.tbl"
    prog.write_text(PART)
    tbl.write_text("T1 P1 D2.0 Z0 ;2 mm kerf\n")
    assert check(str(prog), "--tool-table", str(tbl), "--segments", str(seg)).returncode == 0
    recs = [json.loads(line) for line in seg.read_text().splitlines()]
    assert recs[3]["start"][0] == 110.0 - 1.0


def test_invalid_program_prints_the_error_with_line_column_and_caret_and_exits_1(tmp_path):
    prog = tmp_path / "bad.ngc"
    prog.write_text("G21\nG0 X10 Y10\nG1 X20 Y20 X30 F100\nM2\n")
    res = check(str(prog))
    assert res.returncode == 1 and res.stdout == ""
    assert res.stderr.splitlines() == [
        f"{prog}:3:12: error: multiple X words on one line",
        "     3 | G1 X20 Y20 X30 F100",
        "       |            ^",
    ]


def test_program_outside_travel_is_flagged_in_the_summary(tmp_path):
    prog = tmp_path / "big.ngc"
    prog.write_text("G0 X10 Y10\nG1 X1700 Y10 F100\nM2\n")
    res = check(str(prog))
    assert res.returncode == 0 and "OUTSIDE travel 0 .. 1600 mm" in res.stdout


def test_unreadable_program_and_bad_tool_table_are_named(tmp_path):
    res = check(str(tmp_path / "missing.ngc"))
    assert res.returncode == 1 and "missing.ngc: error: cannot read the program" in res.stderr
    prog, tbl = tmp_path / "p.ngc", tmp_path / "bad.tbl"
    prog.write_text("M2\n")
    tbl.write_text("T1 P1 D2.0\nthis is not a tool\n")
    res = check(str(prog), "--tool-table", str(tbl))
    assert res.returncode == 1 and f"{tbl}:2:1: error: tool table line must be fields like 'T1 P1 D2.0'" in res.stderr


def test_a_progress_bar_is_drawn_on_a_terminal_for_long_programs(tmp_path):
    import os
    import pty

    prog = tmp_path / "long.ngc"
    # one straight run of short chords: long to interpret, quick to plan (the bar is the interpreter's)
    body = "".join(f"G1 X{k * 0.01:.2f} Y{k * 0.005:.3f}\n" for k in range(1, 100_001))
    prog.write_text("G21 G90 F3000\n" + body + "M2\n")
    master, slave = pty.openpty()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "cnc.cli", "check", str(prog), "--machine", str(MACHINE_FILE)],
            cwd=REPO, stdout=subprocess.PIPE, stderr=slave, text=True,
        )
        os.close(slave)
        seen = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:
                break
            if not chunk:
                break
            seen += chunk
        out, _ = proc.communicate(timeout=120)
    finally:
        os.close(master)
    assert proc.returncode == 0, out
    assert b"[#" in seen and b"% line" in seen, seen[:200]
    assert "lines            100002" in out



def test_a_numbered_output_the_machine_lacks_is_an_error_at_its_line(tmp_path):
    prog = tmp_path / "out.ngc"
    prog.write_text("G0 X10 Y10\nM62 P1\nM62 P7\nG1 X20 F100\nM2\n")
    res = check(str(prog))
    assert res.returncode == 1
    assert f"{prog}:3:" in res.stderr and "output number P7 must be a whole number 0 to 3" in res.stderr


def test_a_check_without_programmed_corners_does_not_load_the_lp_solver(tmp_path):
    """scipy's optimiser takes a third of a second to import: `waterjet check` of a program whose
    corners are not programmed does not pay it; one with such a corner (a gentle turn between two
    long lines at speed) loads it and solves."""
    plain = tmp_path / "plain.ngc"
    plain.write_text("G21 G90 G64 P0.05\nF3000\nG1 X10 Y0\nG1 X10 Y10\nG1 X0 Y10\nM2\n")
    gentle = tmp_path / "gentle.ngc"
    gentle.write_text("G21 G90 G64 P0.05\nF12000\nG1 X200 Y0\nG1 X400 Y60\nM2\n")
    probe = ("import sys; from cnc.cli import main; code = main(['check', sys.argv[1], '--machine', sys.argv[2]]); "
             "print(code, 'scipy.optimize' in sys.modules)")
    for path, loaded in ((plain, "False"), (gentle, "True")):
        res = subprocess.run([sys.executable, "-c", probe, str(path), str(MACHINE_FILE)], cwd=REPO,
                             capture_output=True, text=True, timeout=120)
        assert res.stdout.split()[-2:] == ["0", loaded], res.stdout + res.stderr
