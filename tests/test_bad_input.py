"""Bad input: a corpus of broken programs and machine files (tests/bad_input/, its expected.toml says
what each must be refused with), generated monsters (a 10 MB line, binary files, nesting thousands
deep) and malformed commands to every command key of a running controller. Each is refused with an
error naming where (file:line:column, or the machine file's table and key) and what; nothing moves,
nothing crashes, and the controller keeps serving."""

from __future__ import annotations

import io
import json
import random
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import msgspec
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cnc.bus.keys import Keys
from cnc.bus.messages import LOGIC_COMMANDS, LockRequest, Override, Reply, UploadProgram, decode
from cnc.bus.operator import OperatorStation
from cnc.bus.session import open_client
from cnc.check import check_program
from cnc.cli import main as waterjet
from cnc.config import ConfigError, MachineConfig, load_machine
from cnc.data.layout import PlannerState
from cnc.logic.states import MachineState
from cnc.machine_dialect import dialect_for
from cnc.planner.preflight import PreflightError, preflight
from cnc.runtime.supervisor import Supervisor
from gcode.errors import GCodeError
from gcode.interp import Interpreter

from .conftest import MACHINE_FILE, NEAR_HOME, full_controller, logic, machine_config, reset_and_home
from .test_zenoh_interface import PART

CORPUS = Path(__file__).parent / "bad_input"
EXPECTED = tomllib.loads((CORPUS / "expected.toml").read_text())
REFUSED_PROGRAMS = {name: e for name, e in EXPECTED["program"].items() if e.get("stage") != "preflight"}
BEYOND_TRAVEL = {name: e for name, e in EXPECTED["program"].items() if e.get("stage") == "preflight"}
BROKEN_MACHINES = EXPECTED["machine"]
UPLOAD_LIMIT = 1 << 20  # the bench controller's max_program_bytes: a 10 MB line is beyond it
NESTING = 5000



@dataclass(frozen=True)
class Case:
    """A broken program made by the test, and where and what its error must name."""

    data: bytes
    line: int
    column: int
    error: str


def _deep_ifs_around_an_error() -> Case:
    ifs = "".join(f"o{k} if [1]\n" for k in range(NESTING))
    endifs = "".join(f"o{k} endif\n" for k in reversed(range(NESTING)))
    return Case(f"G21 G90 F1200\n{ifs}G77\n{endifs}M2\n".encode(), NESTING + 2, 1, "unknown G code G77")


def _long_call_chain() -> Case:
    subs = "".join(f"o{k} sub\no{k + 1} call\no{k} endsub\n" for k in range(1, 500))
    # o<k> calls o<k+1> on line 3k: the eleventh call in the chain, o11's, is one too deep
    return Case(f"G21 G90 F1200\n{subs}o500 sub\no500 endsub\no1 call\nM2\n".encode(), 3 * 10, 1,
                "subroutine calls nested deeper than 10")


def _deep(opening: bytes, count: int, closing: bytes = b"") -> Case:
    """An X word nested `count` deep: refused where the nesting passes 100 levels, column 5 + 101."""
    word = b"G1 X" + opening * count + b"1" + closing * count
    return Case(b"G21 F1200\n" + word + b"\nM2\n", 2, 106, "nested too deeply (more than 100 levels)")


def _random_bytes() -> Case:
    data = random.Random(9).randbytes(65536)
    nul = data.index(0)
    line = data.count(b"\n", 0, nul) + 1
    return Case(data, line, nul - (data.rfind(b"\n", 0, nul) + 1) + 1, "file contains NUL bytes")


GENERATED: dict[str, Callable[[], Case]] = {
    "nul_bytes.ngc": lambda: Case(b"G21 G90 F1200\nG0 X100\x00 Y100\nM2\n", 2, 8, "file contains NUL bytes"),
    "utf16.ngc": lambda: Case(PART.encode("utf-16"), 1, 4, "file contains NUL bytes"),
    "random_bytes.ngc": _random_bytes,
    "latin1_noise.ngc": lambda: Case(b"G21 G90 F1200\n\xff\xfe\xfd\x80\nM2\n", 2, 1, "bad character"),
    "line_of_10_mb.ngc": lambda: Case(b"G0 X" + b"1" * (10 << 20) + b"\nM2\n", 1, 4097, "line is 10485764 characters long"),
    "brackets_2000_deep.ngc": lambda: _deep(b"[", 2000, b"]"),
    "parameter_refs_4000_deep.ngc": lambda: _deep(b"#", 4000),
    "ifs_5000_deep_around_an_error.ngc": _deep_ifs_around_an_error,
    "call_chain_500_long.ngc": _long_call_chain,
}


def stored(name: str) -> Case:
    e = REFUSED_PROGRAMS[name]
    return Case((CORPUS / "programs" / name).read_bytes(), e["line"], e["column"], e["error"])


def every_broken_program() -> dict[str, Callable[[], Case]]:
    return {**{name: (lambda n=name: stored(n)) for name in REFUSED_PROGRAMS}, **GENERATED}


SHIPPED_DIALECT = dialect_for(load_machine(MACHINE_FILE))


@pytest.fixture(scope="module")
def shipped() -> MachineConfig:
    return machine_config()


# -- programs, in-process as `waterjet check` runs them --------------------------------------------


def test_the_corpus_lists_every_stored_file_and_stays_small():
    programs = {p.name for p in (CORPUS / "programs").iterdir()}
    machines = {p.name for p in (CORPUS / "machines").iterdir()}
    assert programs == set(EXPECTED["program"]) and machines == set(BROKEN_MACHINES)
    assert sum(p.stat().st_size for p in CORPUS.rglob("*") if p.is_file()) < 200_000


@pytest.mark.parametrize("name", list(every_broken_program()))
def test_waterjet_check_refuses_every_broken_program_naming_file_line_and_column(name, shipped, tmp_path):
    case = every_broken_program()[name]()
    path = tmp_path / name
    path.write_bytes(case.data)
    out, err = io.StringIO(), io.StringIO()
    assert check_program(str(path), shipped, None, None, out, err) == 1, out.getvalue()
    first, *shown = err.getvalue().splitlines()
    assert first.startswith(f"{path}:{case.line}:{case.column}: error: ") and case.error in first, first
    if "NUL bytes" not in case.error:  # a binary file's line is not shown
        assert len(shown) == 2 and shown[1].index("^") - shown[1].index("|") - 2 == case.column - 1, shown
    assert out.getvalue() == ""


@pytest.mark.parametrize("name", list(BEYOND_TRAVEL))
def test_a_program_beyond_travel_is_valid_g_code_but_the_preflight_refuses_it_naming_the_line(name, shipped):
    e, data = BEYOND_TRAVEL[name], (CORPUS / "programs" / name).read_bytes()
    program = Interpreter(dialect_for(shipped), name).run(data)
    with pytest.raises(PreflightError) as refused:
        preflight(program.segments, shipped, {"x": True, "y": True}, name)
    assert str(refused.value) == f"{name}:{e['line']}: {e['error']}" and refused.value.line == e["line"]
    out = io.StringIO()
    assert check_program(str(CORPUS / "programs" / name), shipped, None, None, out, io.StringIO()) == 0
    assert "OUTSIDE travel" in out.getvalue(), "waterjet check says so in its summary"


def test_a_program_cut_off_at_any_byte_is_refused_unless_its_end_made_it(shipped):
    dialect, data = dialect_for(shipped), PART.encode()
    for cut in range(1, len(data)):
        head = data[:cut]
        try:
            Interpreter(dialect, "cut.ngc").run(head)
        except GCodeError as err:
            assert b"M2" not in head, (cut, str(err))
            assert 1 <= err.line <= head.count(b"\n") + 1 and err.column >= 1, (cut, str(err))
            continue
        assert b"M2" in head, f"cut at byte {cut} was accepted: {head!r}"


_mutations = st.sampled_from(("truncate", "insert", "duplicate_line", "splice"))


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(name=st.sampled_from(sorted(EXPECTED["program"])), other=st.sampled_from(sorted(EXPECTED["program"])),
       how=_mutations, at=st.floats(0, 1), noise=st.binary(min_size=1, max_size=24))
def test_mutated_corpus_programs_give_a_program_or_an_error_naming_a_real_place(name, other, how, at, noise):
    """Hypothesis over the corpus: cut, poke bytes into, repeat a line of or splice two broken programs."""
    data = (CORPUS / "programs" / name).read_bytes()
    k = int(at * len(data))
    if how == "truncate":
        data = data[:k]
    elif how == "insert":
        data = data[:k] + noise + data[k:]
    elif how == "duplicate_line":
        lines = data.splitlines(keepends=True)
        i = int(at * (len(lines) - 1))
        data = b"".join(lines[: i + 1] + lines[i:])
    else:
        data = data[:k] + (CORPUS / "programs" / other).read_bytes()[k:]
    try:
        Interpreter(SHIPPED_DIALECT, name).run(data)
    except GCodeError as err:
        assert err.file == name and err.message and err.column >= 1
        assert 1 <= err.line <= data.count(b"\n") + 1 + data.count(b"\r"), str(err)


# -- machine files ----------------------------------------------------------------------------------


def _place(path: Path, where: str) -> str:
    """How a ConfigError begins: `file:line:col:` for TOML syntax, else `file: [table] key:`."""
    return f"{path.parent}/{where}: " if where.startswith(path.name) else f"{path}: {where}: "


@pytest.mark.parametrize("name", list(BROKEN_MACHINES))
def test_every_broken_machine_file_is_a_config_error_naming_file_and_key(name):
    path, e = CORPUS / "machines" / name, BROKEN_MACHINES[name]
    with pytest.raises(ConfigError) as err:
        load_machine(path)
    assert str(err.value).startswith(_place(path, e["where"])) and e["error"] in str(err.value), str(err.value)


@pytest.mark.parametrize(
    "data, where, error",
    [
        (b"[axis.x]\ntravel_min_mm = 0\n\xff\xfe\x00\x01", "", "not UTF-8 text (byte 27)"),
        ("[axis.x]\ntravel_min_mm = 0\n".encode("utf-16"), "", "not UTF-8 text (byte 0)"),
        (b"[axis.x]\ntravel_min_mm = 0\x00\x00\ntravel_max_mm = 1\n", ":2:18", "TOML syntax error"),
        (random.Random(4).randbytes(4096), "", "not UTF-8 text"),
    ],
    ids=["binary", "utf16", "nul_bytes", "random_bytes"],
)
def test_a_binary_machine_file_is_a_config_error_naming_the_file(tmp_path, data, where, error):
    path = tmp_path / "machine.toml"
    path.write_bytes(data)
    with pytest.raises(ConfigError) as err:
        load_machine(path)
    assert str(err.value).startswith(f"{path}{where}: ") and error in str(err.value), str(err.value)


def test_waterjet_up_with_a_broken_machine_file_exits_non_zero_with_the_error_and_starts_nothing(monkeypatch, capsys):
    def no_controller(*_args, **_kwargs) -> None:
        raise AssertionError("a controller was started from a broken machine file")

    monkeypatch.setattr(Supervisor, "__init__", no_controller)
    path = CORPUS / "machines" / "out_of_range.toml"
    assert waterjet(["up", "--machine", str(path), "--clock", "virtual"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"waterjet up: {path}: [axis.y] max_velocity_mm_s: 20000.0 is out of range"), err


# -- the same over Zenoh, to one running controller ----------------------------------------------------


@dataclass
class Bench:
    """The controller on the virtual clock, homed, PART loaded; station `bench` holds the lock."""

    sup: Supervisor
    session: zenoh.Session
    keys: Keys
    op: OperatorStation

    def ask(self, key: str, payload: bytes | None, attachment: bytes | None = None) -> Reply:
        """One query with a raw payload; the Reply (every command key answers with one)."""
        replies = list(self.session.get(key, payload=payload, attachment=attachment, timeout=30.0))
        assert replies and replies[0].ok is not None, f"no Reply from {key}"
        return decode(replies[0].ok.payload.to_bytes(), Reply)

    def snapshot(self) -> dict:
        """What must not change: states, mode, the loaded program, the commanded position, alarms."""
        lo, mo, sv = logic(self.sup), self.sup.motion(), self.sup.servo()
        return {"state": MachineState(lo["state"]).name, "mode": lo["mode"], "alarms": lo["alarms_active"],
                "planner": PlannerState(mo["state"]).name, "program": (mo["program_name"], mo["program_hash"]),
                "commanded_mm": [round(v, 6) for v in sv["commanded_mm"]], "gateway_pid": self.gateway_pid()}

    def actual_mm(self) -> list[float]:
        return list(self.sup.servo()["actual_mm"])

    def gateway_pid(self) -> int:
        return self.sup.children["gateway"].process.pid


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    config = machine_config(**NEAR_HOME, **{"gcode.max_program_bytes": UPLOAD_LIMIT})
    with full_controller(config, tmp_path_factory.mktemp("bad_input") / "history.sqlite") as sup:
        session = open_client([config.zenoh.listen[0]])
        keys = Keys(config.zenoh.key_prefix, config.machine.name)
        op = OperatorStation(session, keys, "bench")
        assert op.take_lock().ok
        reset_and_home(sup, op.request)
        sup.wait_until(lambda: logic(sup)["state"] == MachineState.READY and sup.motion()["state"] == PlannerState.IDLE,
                       60.0, "homing")
        assert op.upload("part.ngc", PART).ok
        yield Bench(sup, session, keys, op)
        op.close()
        session.close()


def _unchanged(bench: Bench, before: dict, position: list[float]) -> None:
    assert bench.snapshot() == before
    assert all(abs(a - b) < 0.005 for a, b in zip(bench.actual_mm(), position)), "the axes moved"
    assert bench.sup.failed is None and not bench.sup.children["gateway"].restarts


def _upload_cases() -> dict[str, Case]:
    cases = {name: stored(name) for name in REFUSED_PROGRAMS}
    for name in ("brackets_2000_deep.ngc", "ifs_5000_deep_around_an_error.ngc", "call_chain_500_long.ngc"):
        cases[name] = GENERATED[name]()
    cases["line_of_100_kb.ngc"] = Case(b"G0 X" + b"1" * 100_000 + b"\nM2\n", 1, 4097, "line is 100004 characters long")
    nul = GENERATED["nul_bytes.ngc"]()
    cases["nul_bytes.ngc"] = Case(nul.data, nul.line, nul.column, "not text: control character '\\x00'")
    cases["utf16.ngc"] = Case(PART.encode("utf-16"), 1, 4, "not text: control character '\\x00'")
    return cases


def test_every_broken_program_uploaded_is_refused_naming_name_line_and_column_and_nothing_changes(bench):
    before, position = bench.snapshot(), bench.actual_mm()
    for name, case in _upload_cases().items():
        reply = bench.op.upload(name, case.data.decode("latin-1"))
        assert not reply.ok and f"program: {name}:{case.line}:{case.column}: " in reply.reason, (name, reply.reason)
        assert case.error in reply.reason and (reply.errors[0].line, reply.errors[0].column) == (case.line, case.column)
    for name, size in (("line_of_10_mb.ngc", 10 << 20), ("one_byte_too_many.ngc", UPLOAD_LIMIT + 1)):
        reply = bench.op.upload(name, "G0 X" + "1" * (size - 4))
        assert not reply.ok and reply.reason == f"program: {name} is {size} bytes; this machine accepts at most {UPLOAD_LIMIT}"
    _unchanged(bench, before, position)
    assert bench.op.upload("part.ngc", PART).ok, "the gateway still loads a good program"


def test_a_program_beyond_travel_is_refused_at_upload_on_a_homed_machine_naming_the_line(bench):
    """Refused when it is loaded, not when a cycle reaches its cutting phase with the material fed."""
    name = "out_of_travel.ngc"
    before, position = bench.snapshot(), bench.actual_mm()
    refused = bench.op.upload(name, (CORPUS / "programs" / name).read_text())
    assert not refused.ok and f"{name}:4: {BEYOND_TRAVEL[name]['error']}" in refused.reason, refused.reason
    _unchanged(bench, before, position)
    assert bench.op.upload("part.ngc", PART).ok


# -- malformed commands to every command key ---------------------------------------------------------

VALID = {  # a well-formed payload per command (without version); mutated below, never sent as is
    "mode": {"mode": "MANUAL"}, "start": {"cycles": 1}, "drives": {"on": True}, "home": {"axes": ["x"]},
    "jog": {"axis": "x", "velocity_mm_s": 5.0, "distance_mm": 1.0}, "goto": {"position_mm": {"x": 50.0}, "feed_mm_s": 10.0},
    "load": {"path": "/nonexistent.ngc"}, "override": {"percent": 100.0}, "pump": {"on": False, "pressure_bar": 1000.0},
    "jet_test": {"on": False}, "acknowledge": {"code": 1}, "procedure_start": {"id": "transport"},
    "lock": {"take": True}, "program": {"name": "p.ngc", "text": "M2\n"},
    "control_run": {"trajectory": "hold", "duration_s": 1.0},
}
KINDS = {**LOGIC_COMMANDS, "lock": LockRequest, "program": UploadProgram}
WRONG = {"nested": "object"}  # a JSON value of the wrong type for every field but a dict


def _json(body: dict) -> bytes:
    return json.dumps({**body, "version": 1}).encode()


def malformed(verb: str) -> list[tuple[str, bytes, str]]:
    """(what, payload, what the refusal must say) for one command verb."""
    kind, valid = KINDS[verb], VALID.get(verb, {})
    fields = [f for f in msgspec.structs.fields(kind) if f.name != "version"]
    cases = [
        ("empty", b"", "Input data was truncated"),
        ("random bytes", b"\xfe" + random.Random(verb).randbytes(63), "JSON is malformed"),
        ("JSON array", b"[1, 2, 3]", "Expected `object`, got `array`"),
        ("JSON number", b"42", "Expected `object`, got `int`"),
        ("no version", json.dumps(valid).encode(), "schema version None"),
        ("version as text", json.dumps({**valid, "version": "1"}).encode(), "at `$.version`"),
        ("unknown field", _json({**valid, "speed": 3}), "unknown field `speed`"),
        ("NaN", _json(valid)[:-1] + b', "x": NaN}', "JSON is malformed"),
        ("huge", _json({**valid, "pad": "x" * (2 << 20)}), "unknown field `pad`"),
    ]
    for f in fields:
        if f.required:
            cases.append((f"missing {f.name}", _json({k: v for k, v in valid.items() if k != f.name}),
                          f"missing required field `{f.name}`"))
        cases.append((f"{f.name} of the wrong type", _json({**valid, f.name: [1] if f.name == "position_mm" else WRONG}),
                      f"`$.{f.name}`"))
    return cases


OUT_OF_RANGE = [  # well-formed, each refused by the logic or the planner with the value named
    ("override", b'{"percent": 1e400, "version": 1}', "Number out of range"),
    ("override", _json({"percent": 1e308}), "override 1e+308 % is out of range: 0 to 200 %"),
    ("override", _json({"percent": -1.0}), "override -1 % is out of range"),
    ("jog", _json({"axis": "x", "velocity_mm_s": 1e308}), "jog speed 1e+308 mm/s is out of range"),
    ("jog", _json({"axis": "x", "distance_mm": 1e308}), "outside the travel 0 to 1600 mm"),
    ("jog", _json({"axis": "x", "distance_mm": -1e308}), "outside the travel 0 to 1600 mm"),
    ("jog", _json({"axis": "q"}), "no axis 'q'"),
    ("goto", _json({"position_mm": {"x": 1e308}}), "X1e+308 is outside the travel 0 to 1600 mm"),
    ("goto", _json({"position_mm": {"x": 50.0}, "feed_mm_s": -1.0}), "feed -1.0 mm/s must be positive"),
    ("goto", _json({"position_mm": {"w": 5.0}}), "no axis 'w'"),
    ("pump", _json({"on": True, "pressure_bar": 1e308}), "pressure_bar 1e+308 is out of range"),
    ("start", _json({"cycles": 2**70}), "Expected `int` <= 1000000 - at `$.cycles`"),
    ("acknowledge", _json({"code": -(2**70)}), f"alarm {-(2**70)} is not active"),
    ("home", _json({"axes": ["q"]}), "no axis 'q'"),
    ("mode", _json({"mode": "TURBO"}), "mode 'TURBO' is not one of"),
    ("procedure_start", _json({"id": "../../etc"}), "procedure"),
]

BOGUS_STATIONS = [
    (None, "the query carries no station id"),
    (b"\xff\x00 not json", "the query carries no station id"),
    (b'["bench"]', "the query carries no station id"),
    (b'{"station": 5}', "the query carries no station id"),
    (b'{"station": "intruder"}', "read-only: station 'bench' holds the command lock"),
]


def test_malformed_commands_to_every_command_key_are_refused_naming_what_and_nothing_moves(bench):
    before, position = bench.snapshot(), bench.actual_mm()
    attachment = bench.op.attachment
    for verb in KINDS:
        for what, payload, expected in malformed(verb):
            reply = bench.ask(bench.keys.cmd(verb), payload, attachment)
            assert not reply.ok and reply.reason.startswith(f"{verb}: malformed command: ") and expected in reply.reason, \
                (verb, what, reply.reason[:300])
    for verb, payload, expected in OUT_OF_RANGE:
        reply = bench.ask(bench.keys.cmd(verb), payload, attachment)
        assert not reply.ok and expected in reply.reason, (verb, payload[:80], reply.reason)
    for station, expected in BOGUS_STATIONS:
        for verb in ("override", "jog", "program"):
            reply = bench.ask(bench.keys.cmd(verb), _json(VALID[verb]), station)
            assert not reply.ok and expected in reply.reason, (verb, station, reply.reason)
    _unchanged(bench, before, position)
    assert bench.op.request(Override(100.0)).ok, "a valid command after the barrage"
    assert bench.op.request(LockRequest(take=True)).ok and bench.sup.motion()["program_name"] == "part.ngc"


def _param(bench: Bench, name: str) -> float:
    return next(p.value for p in bench.op.params().params if p.name == name)


def test_malformed_parameter_changes_are_refused_naming_what_and_nothing_changes(bench):
    before, position = bench.snapshot(), bench.actual_mm()
    attachment, name = bench.op.attachment, "axis.x.kp_1_s"
    value = _param(bench, name)
    for what, payload, expected in [
        ("random bytes", b"\xfe" + random.Random(1).randbytes(63), "malformed command: JSON is malformed"),
        ("JSON array", b"[1]", "Expected `object`, got `array`"),
        ("missing value", _json({}), "missing required field `value`"),
        ("value as text", _json({"value": "stiff"}), "Expected `float`, got `str` - at `$.value`"),
        ("unknown field", _json({"value": 100.0, "unit": "1/s"}), "unknown field `unit`"),
        ("1e400", b'{"value": 1e400, "version": 1}', "Number out of range"),
        ("out of range", _json({"value": 1e308}), "out of range"),
    ]:
        reply = bench.ask(bench.keys.user_param("local", name), payload, attachment)
        assert not reply.ok and expected in reply.reason, (what, reply.reason)
    unknown = bench.ask(bench.keys.user_param("local", "axis.x.warp_factor"), _json({"value": 1.0}), attachment)
    assert not unknown.ok and "no control parameter 'axis.x.warp_factor'" in unknown.reason
    assert "the query carries no station id" in bench.ask(bench.keys.user_param("local", name), _json({"value": value}), None).reason
    save = bench.ask(bench.keys.user_params("local"), b'{"version": 1, "to": "/etc/passwd"}', attachment)
    assert not save.ok and "unknown field `to`" in save.reason
    assert _param(bench, name) == value
    _unchanged(bench, before, position)
