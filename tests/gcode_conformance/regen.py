#!/usr/bin/env python3
"""Regenerate the expected output of the G-code conformance suite from LinuxCNC's `rs274`.

    python tests/gcode_conformance/regen.py            # every program
    python tests/gcode_conformance/regen.py NAME ...   # only these (file stems, errors too)
    python tests/gcode_conformance/regen.py --check    # compare with the committed files, write nothing

For every `programs/<name>.ngc` this runs `rs274 -g` (LinuxCNC's stand-alone interpreter,
Debian package linuxcnc-uspace), converts its canonical calls into our exchange format
(one JSON object per line, machine coordinates in mm, see README.md) and writes
`expected/<name>.jsonl`. For every `programs/errors/<name>.ngc` it checks that rs274 rejects
the program with a message containing the program's `; expect:` text and writes
`expected/errors/<name>.txt` (message, line number, line text).

Conversion rules (found by experiment with LinuxCNC 2.9, see README.md):
- rs274 prints positions in the current *program* frame and current program units; the work
  offsets arrive as separate SET_G5X_OFFSET / SET_G92_OFFSET / SET_XY_ROTATION calls. Machine
  position = rotate(p + g92) + g5x, everything in mm (what LinuxCNC's emccanon does).
- Every length in a call is in the units of the last USE_LENGTH_UNITS; it is converted to mm
  when the call is seen (offsets included: canon stores them in machine units).
- SET_FEED_RATE is in program units per minute, converted when seen; the rate then holds
  across a later G20/G21 until the next SET_FEED_RATE. In G93 the interpreter itself
  turns the inverse-time F into a units/min SET_FEED_RATE before every move.
- rs274 reads the tool table in inches (its external length unit), so the suite's tool
  table (mm) is handed to it converted to inches.
- rs274 prints 4 decimals; segments computed from inch output carry a wider "tol" field.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

SUITE = Path(__file__).resolve().parent
PROGRAMS = SUITE / "programs"
ERROR_PROGRAMS = PROGRAMS / "errors"
EXPECTED = SUITE / "expected"
EXPECTED_ERRORS = EXPECTED / "errors"
TOOL_TABLE = SUITE / "tool.tbl"

MM_PER_INCH = 25.4
BASE_TOL_MM = 0.00051          # half a unit of rs274's 4th decimal, in mm, plus a little
RS274_TIMEOUT_S = 60.0

# `; conformance: block-delete` in a program: a machine switch the program is checked with,
# the rs274 option that means the same and the machine-file setting the test uses for it.
SWITCHES_RE = re.compile(r"^\s*;\s*conformance:\s*(.*?)\s*$", re.MULTILINE)
SWITCHES = {
    "block-delete": {"rs274": "-b", "machine": ("block_delete = false", "block_delete = true")},
}
EXPECT_RE = re.compile(r"^\s*;\s*expect:\s*(.*?)\s*$")
SEEKING_RE = re.compile(r"seeking o-word: .* from line: (\d+)")

# "   12 N..... ARC_FEED(30.0000, 20.0000, ...)" or "    8 N10    STRAIGHT_TRAVERSE(...)"
CALL_RE = re.compile(r"^\s*\d+\s+N\S*\s+([A-Z_][A-Z0-9_]*)\((.*)\)\s*$")
LENGTH_WORDS = "XYZUVWD"        # tool-table fields that are lengths


class RegenError(Exception):
    """rs274 did something the suite does not expect (or cannot convert)."""


# ---------------------------------------------------------------------------------------
# running rs274


def find_rs274(explicit: str | None = None) -> str | None:
    """Path of the rs274 executable: argument, $RS274, PATH, /usr/bin/rs274; None if absent."""
    for candidate in (explicit, os.environ.get("RS274"), shutil.which("rs274"), "/usr/bin/rs274"):
        if candidate and Path(candidate).is_file() and os.access(candidate, os.X_OK):
            return candidate
    return None


def program_switches(program: Path) -> list[str]:
    """Machine switches a program asks for with `; conformance: <switch> ...` (see SWITCHES)."""
    text = program.read_bytes().decode("utf-8", "replace")
    switches: list[str] = []
    for m in SWITCHES_RE.finditer(text):
        switches.extend(m.group(1).split())
    for sw in switches:
        if sw not in SWITCHES:
            raise RegenError(f"{program.name}: unknown conformance switch {sw!r} (known: {', '.join(SWITCHES)})")
    return switches


def inch_tool_table(text: str) -> str:
    """The suite's tool table (mm) with every length field converted to inches for rs274."""
    out = []
    for raw in text.splitlines():
        body, sep, comment = raw.partition(";")
        words = []
        for w in body.split():
            if w[:1].upper() in LENGTH_WORDS:
                value = float(w[1:]) / MM_PER_INCH
                w = f"{w[0]}{value:.12f}"
            words.append(w)
        out.append(" ".join(words) + (f" ;{comment}" if sep else ""))
    return "\n".join(out) + "\n"


def run_rs274(program: Path, rs274: str, tool_table: Path = TOOL_TABLE) -> subprocess.CompletedProcess:
    """Run `rs274 -g` on one program in a fresh directory.

    The directory is also HOME: rs274 keeps its tool table in a memory-mapped $HOME/.tool.mmap
    that every rs274 of that HOME shares (two at once corrupt each other's tool table or die
    of SIGBUS), and reads and writes rs274ngc.var (persistent parameters such as the G54
    offsets) in its working directory. A fresh directory per run keeps runs independent.
    """
    flags = [SWITCHES[sw]["rs274"] for sw in program_switches(program)]
    with tempfile.TemporaryDirectory(prefix="rs274-") as tmp:
        tbl = Path(tmp) / "tool.tbl"
        tbl.write_text(inch_tool_table(tool_table.read_text()))
        try:
            return subprocess.run(
                [rs274, "-t", str(tbl), *flags, "-g", str(program.resolve())],
                cwd=tmp, env={**os.environ, "HOME": tmp}, stdin=subprocess.DEVNULL,
                capture_output=True, timeout=RS274_TIMEOUT_S,
                text=True, errors="replace",
            )
        except subprocess.TimeoutExpired:
            raise RegenError(f"{program.name}: rs274 did not finish in {RS274_TIMEOUT_S:g} s") from None


def rs274_error(proc: subprocess.CompletedProcess) -> tuple[str, str] | None:
    """(message, line text) of the error rs274 reported on stderr, or None if there was none.

    rs274 prints "executing", then on error the message and the raw text of the offending
    line (no line number), and exits 1.
    """
    lines = [l for l in proc.stderr.splitlines() if l.strip() != "executing"]
    if proc.returncode == 0 and not lines:
        return None
    if not lines:
        raise RegenError(f"rs274 exited {proc.returncode} without a message")
    return lines[0].strip(), (lines[1] if len(lines) > 1 else "")


# ---------------------------------------------------------------------------------------
# canonical calls -> exchange format


def _numbers(args: str) -> list[float]:
    return [float(a) for a in args.split(",")]


def _clean(v: float) -> float:
    v = round(v, 6)
    return 0.0 if v == 0 else v


class Converter:
    """Follows the canonical calls and turns motion into segments in machine mm."""

    def __init__(self) -> None:
        self.scale = 1.0                 # mm per program unit (USE_LENGTH_UNITS)
        self.g5x = [0.0, 0.0, 0.0]       # mm
        self.g92 = [0.0, 0.0, 0.0]       # mm
        self.rotation = 0.0              # degrees (G10 L2 R)
        self.offset_scale = 1.0          # coarsest unit the offsets were given in
        self.pos = [0.0, 0.0, 0.0]       # machine mm
        self.pos_tol = BASE_TOL_MM
        self.feed: float | None = None   # mm/min
        self.plane = "CANON_PLANE_XY"
        self.segments: list[dict] = []

    def to_machine(self, x: float, y: float, z: float) -> list[float]:
        s = self.scale
        px, py, pz = x * s + self.g92[0], y * s + self.g92[1], z * s + self.g92[2]
        if self.rotation:
            t = math.radians(self.rotation)
            px, py = px * math.cos(t) - py * math.sin(t), px * math.sin(t) + py * math.cos(t)
        return [px + self.g5x[0], py + self.g5x[1], pz + self.g5x[2]]

    def _tol(self) -> float:
        return BASE_TOL_MM * max(self.scale, self.offset_scale)

    def _emit(self, kind: str, end: list[float], **extra) -> None:
        tol = max(self._tol(), self.pos_tol)
        seg: dict = {
            "kind": kind,
            "start": [_clean(v) for v in self.pos],
            "end": [_clean(v) for v in end],
            "feed": None if kind == "rapid" else self.feed,
        }
        seg.update(extra)
        seg["line"] = None             # rs274 does not print source lines
        if tol > BASE_TOL_MM:
            seg["tol"] = round(tol, 6)
        self.segments.append(seg)
        self.pos, self.pos_tol = end, self._tol()

    def call(self, name: str, args: str) -> None:
        if name == "USE_LENGTH_UNITS":
            units = args.strip()
            self.scale = {"CANON_UNITS_MM": 1.0, "CANON_UNITS_INCHES": MM_PER_INCH, "CANON_UNITS_CM": 10.0}[units]
        elif name == "SET_G5X_OFFSET":
            v = _numbers(args)
            self.g5x = [v[1] * self.scale, v[2] * self.scale, v[3] * self.scale]
            self.offset_scale = max(self.offset_scale, self.scale)
        elif name == "SET_G92_OFFSET":
            v = _numbers(args)
            self.g92 = [v[0] * self.scale, v[1] * self.scale, v[2] * self.scale]
            self.offset_scale = max(self.offset_scale, self.scale)
        elif name == "SET_XY_ROTATION":
            self.rotation = _numbers(args)[0]
        elif name == "SET_FEED_RATE":
            self.feed = _clean(_numbers(args)[0] * self.scale)
        elif name == "SELECT_PLANE":
            self.plane = args.strip()
        elif name == "STRAIGHT_TRAVERSE":
            v = _numbers(args)
            self._emit("rapid", self.to_machine(v[0], v[1], v[2]))
        elif name == "STRAIGHT_FEED":
            v = _numbers(args)
            self._emit("line", self.to_machine(v[0], v[1], v[2]))
        elif name == "ARC_FEED":
            if self.plane != "CANON_PLANE_XY":
                raise RegenError(f"ARC_FEED in {self.plane}: the exchange format has XY arcs only")
            v = _numbers(args)
            x, y, cx, cy, rotation, z = v[0], v[1], v[2], v[3], int(v[4]), v[5]
            if rotation == 0:
                raise RegenError("ARC_FEED with rotation 0")
            end = self.to_machine(x, y, z)
            center = self.to_machine(cx, cy, 0.0)[:2]
            self._emit("arc", end, center=[_clean(c) for c in center], cw=rotation < 0, turns=abs(rotation) - 1)
        elif name == "DWELL":
            self.segments.append({"kind": "dwell", "seconds": _clean(_numbers(args)[0]), "line": None})
        elif name in ("STRAIGHT_PROBE", "RIGID_TAP", "NURBS_FEED", "SPLINE_FEED"):
            raise RegenError(f"{name} has no equivalent in the exchange format")
        elif name == "SET_FEED_MODE":
            # SET_FEED_MODE(spindle, mode): mode 1 = units per revolution (G95), which we do not
            # support; G93 is converted to units/min by the interpreter itself.
            if int(_numbers(args)[-1]) != 0:
                raise RegenError(f"SET_FEED_MODE({args}): only units/min and inverse time are supported")
        # everything else (spindle, coolant, outputs, comments, tool change, ...) has no segment


def canon_to_segments(stdout: str) -> list[dict]:
    """Convert rs274's canonical-call listing into exchange-format records."""
    conv = Converter()
    for raw in stdout.splitlines():
        m = CALL_RE.match(raw)
        if not m:
            continue
        conv.call(m.group(1), m.group(2))
    return conv.segments


def to_jsonl(records: list[dict]) -> str:
    return "".join(json.dumps(r, separators=(", ", ": ")) + "\n" for r in records)


# ---------------------------------------------------------------------------------------
# programs


def generate_program(program: Path, rs274: str) -> str:
    """Expected JSONL text for one valid program."""
    proc = run_rs274(program, rs274)
    err = rs274_error(proc)
    if err is not None:
        raise RegenError(f"{program.name}: rs274 rejected it: {err[0]!r} at {err[1]!r}")
    return to_jsonl(canon_to_segments(proc.stdout))


def expected_substring(program: Path) -> str:
    first = program.read_bytes().decode("utf-8", "replace").splitlines()[0] if program.stat().st_size else ""
    m = EXPECT_RE.match(first)
    if not m or not m.group(1):
        raise RegenError(f"{program.name}: first line must be '; expect: <part of LinuxCNC's message>'")
    return m.group(1)


def error_line_number(program: Path, text: str) -> int:
    """The 1-based line whose raw text rs274 printed; the text must occur exactly once."""
    lines = program.read_bytes().decode("utf-8", "replace").splitlines()
    hits = [i + 1 for i, l in enumerate(lines) if l.rstrip() == text.rstrip()]
    if len(hits) != 1:
        raise RegenError(
            f"{program.name}: rs274 named the line {text!r}, which occurs {len(hits)} times; "
            "make the offending line unique so its number is known"
        )
    return hits[0]


def generate_error(program: Path, rs274: str) -> str:
    """Expected error text for one program LinuxCNC must reject."""
    want = expected_substring(program)
    proc = run_rs274(program, rs274)
    err = rs274_error(proc)
    if err is None:
        raise RegenError(f"{program.name}: rs274 accepted a program that should be rejected")
    message, text = err
    # rs274 quotes the program by the path it was given: keep the expected file portable
    message = message.replace(str(program.resolve()), program.name)
    if want.lower() not in message.lower():
        raise RegenError(f"{program.name}: rs274 said {message!r}, which does not contain {want!r}")
    seeking = SEEKING_RE.search(message)
    if seeking:
        # a call of an undefined subroutine: rs274 reads to the end of the file looking for
        # it and shows the last line, but the message names the line of the call
        line = int(seeking.group(1))
        text = program.read_bytes().decode("utf-8", "replace").splitlines()[line - 1]
    else:
        line = error_line_number(program, text)
    return f"message: {message}\nline: {line}\ntext: {text}\n"


def parse_error_file(text: str) -> dict:
    """{"message": str, "line": int, "text": str} from an expected/errors/*.txt file."""
    out: dict = {}
    for raw in text.splitlines():
        key, sep, value = raw.partition(": ")
        if sep:
            out[key] = value
        elif raw.endswith(":"):
            out[raw[:-1]] = ""
    out["line"] = int(out["line"])
    return out


def all_programs() -> list[Path]:
    return sorted(PROGRAMS.glob("*.ngc"))


def all_error_programs() -> list[Path]:
    return sorted(ERROR_PROGRAMS.glob("*.ngc"))


def expected_path(program: Path) -> Path:
    if program.parent == ERROR_PROGRAMS:
        return EXPECTED_ERRORS / f"{program.stem}.txt"
    return EXPECTED / f"{program.stem}.jsonl"


def generate(program: Path, rs274: str) -> str:
    if program.parent == ERROR_PROGRAMS:
        return generate_error(program, rs274)
    return generate_program(program, rs274)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("names", nargs="*", help="program stems to regenerate (default: all)")
    ap.add_argument("--rs274", help="rs274 executable (default: $RS274, PATH, /usr/bin/rs274)")
    ap.add_argument("--check", action="store_true", help="compare with the committed files, write nothing")
    args = ap.parse_args(argv)
    rs274 = find_rs274(args.rs274)
    if rs274 is None:
        print("regen: rs274 not found; install LinuxCNC (Debian: apt-get install linuxcnc-uspace)", file=sys.stderr)
        return 2
    programs = all_programs() + all_error_programs()
    if args.names:
        wanted = set(args.names)
        programs = [p for p in programs if p.stem in wanted]
        missing = wanted - {p.stem for p in programs}
        if missing:
            print(f"regen: no such program: {', '.join(sorted(missing))}", file=sys.stderr)
            return 2
    failures = differ = 0
    for program in programs:
        try:
            text = generate(program, rs274)
        except RegenError as exc:
            print(f"FAIL {exc}", file=sys.stderr)
            failures += 1
            continue
        out = expected_path(program)
        if args.check:
            if not out.is_file() or out.read_text() != text:
                print(f"DIFFERS {out.relative_to(SUITE)}")
                differ += 1
            continue
        out.parent.mkdir(parents=True, exist_ok=True)
        if not out.is_file() or out.read_text() != text:
            out.write_text(text)
            print(f"wrote {out.relative_to(SUITE)}")
    if not args.names:
        keep = {expected_path(p) for p in programs}
        for stale in sorted(set(EXPECTED.glob("*.jsonl")) | set(EXPECTED_ERRORS.glob("*.txt"))):
            if stale not in keep:
                if args.check:
                    print(f"STALE {stale.relative_to(SUITE)}")
                    differ += 1
                else:
                    stale.unlink()
                    print(f"removed {stale.relative_to(SUITE)}")
    print(f"{len(programs)} programs, {failures} failed" + (f", {differ} differ" if args.check else ""))
    return 1 if failures or differ else 0


if __name__ == "__main__":
    sys.exit(main())
