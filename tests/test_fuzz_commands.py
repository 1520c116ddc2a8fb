"""Fuzz of the command decoder the gateway, the control logic, the planner and the logger use
(`cnc.bus.messages.decode`): arbitrary bytes and structurally mutated valid commands give either a
valid command or one of the decode errors the doors turn into a refusal, never another exception.
Bounded and derandomized, so that CI runs the same examples every time."""

from __future__ import annotations

import json
import math
from typing import Any

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cnc.bus.messages import (
    LOGIC_COMMANDS, MAX_CYCLES, PLANNER_COMMANDS, Acknowledge, CycleStart, Drives, GoTo, Hold, Home, JetTest, Jog, JogRefresh, JogStop,
    LoadProgram, LockRequest, LogSetting, LogStart, LogStop, Override, ProcedureConfirm, ProcedureEnd, ProcedureStart,
    ProcedureStop, Pump, Reset, Resume, SaveParams, SchemaVersionError, SetMode, SetParam, SimInput, Start, Stop, StopAll,
    UploadProgram, Mdi, DeleteProgram, Recover, RestartAt, SetCut, CalibrationLadder, CalibrationRecord, CheckRestart, ControlRun, ControlSelect,
    decode, encode,
)

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

DECODE_ERRORS = (msgspec.DecodeError, msgspec.ValidationError, SchemaVersionError)  # what the doors refuse with
FUZZ = settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])

VALID: list[msgspec.Struct] = [  # one well-formed command of every kind a door or the logger decodes
    SetMode("AUTO"), CycleStart(2), Start(), Hold(), Resume(), Stop(), Reset(), Drives(True), Home(["x", "y"]),
    Jog("x", 5.0, 1.0), JogStop(), JogRefresh(), GoTo({"x": 10.0, "y": 20.0}, 50.0), LoadProgram("/programs/part.ngc"), Override(50.0),
    Pump(True, 1000.0), JetTest(False), Acknowledge(3), ProcedureStart("transport"), ProcedureConfirm(), ProcedureStop(),
    ProcedureEnd(), LockRequest(False), UploadProgram("part.ngc", "G0 X1\nM2\n"), SetParam(120.0), SaveParams(),
    SimInput("doors_open", 1.0), StopAll("station x (local)"), Mdi("G0 X10 Y20\nG1 X30 F600"), DeleteProgram("part.ngc"),
    Recover("continue", overlap_mm=3.0), Recover("part", 4), Start(restart=RestartAt("line", number=12)),
    CheckRestart(RestartAt("part", number=3)), ControlRun("circle", 10.0), ControlSelect("cross_coupled"),
    SetCut("leather", 2.5, 3, "quality", 5), LoadProgram("part.ngc", cut=SetCut("leather", 2.5, 3)),
    CalibrationLadder("leather", 2.0, 3000.0, 24000.0, 8, 0.3),
    CalibrationRecord("leather", 2.0, 20000.0, [20000.0, 16000.0, 12000.0, 9000.0, 6000.0], 0.3, 0.2, [1.0] * 5),
    LogStart([LogSetting("x.following_error", "triggered", enable_when="jet")], "run"), LogStop(),
]
KINDS = sorted({type(m) for m in VALID}, key=lambda k: k.__name__)

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**80), 2**80) | st.floats() | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)


def check(payload: bytes, kind: type[msgspec.Struct]) -> msgspec.Struct | None:
    """Decode as the doors do: a command of `kind`, or None for a documented refusal with a reason."""
    try:
        msg = decode(payload, kind)
    except DECODE_ERRORS as exc:
        assert str(exc), "a refusal says what is wrong"
        return None
    assert type(msg) is kind and decode(encode(msg), kind) == msg
    assert all(math.isfinite(v) for v in _floats(msgspec.to_builtins(msg))), "no NaN or infinity gets through"
    return msg


def _floats(value: Any) -> list[float]:
    if isinstance(value, float):
        return [value]
    if isinstance(value, dict):
        value = list(value.values())
    return [f for v in value for f in _floats(v)] if isinstance(value, list) else []


def test_every_command_the_doors_serve_has_a_valid_example():
    served = {*LOGIC_COMMANDS.values(), *PLANNER_COMMANDS.values(), LockRequest, UploadProgram, SetParam, SaveParams}
    assert served <= set(KINDS)
    for msg in VALID:
        assert check(encode(msg), type(msg)) == msg


@FUZZ
@given(payload=st.binary(max_size=200), kind=st.sampled_from(KINDS))
def test_arbitrary_bytes_decode_to_a_command_or_a_documented_refusal(payload, kind):
    check(payload, kind)


@FUZZ
@given(data=st.data(), msg=st.sampled_from(VALID))
def test_mutated_valid_commands_decode_to_a_command_or_a_documented_refusal(data, msg):
    """Drop, add, retype or nest fields of a valid command; send it as its own kind or another's."""
    body: dict = json.loads(encode(msg))
    for _ in range(data.draw(st.integers(1, 3))):
        how = data.draw(st.sampled_from(("drop", "add", "retype", "nest")))
        keys = sorted(body)
        if how == "drop" and keys:
            body.pop(data.draw(st.sampled_from(keys)))
        elif how == "add":
            body[data.draw(st.text(max_size=10))] = data.draw(json_values)
        elif how == "retype" and keys:
            body[data.draw(st.sampled_from(keys))] = data.draw(json_values)
        elif how == "nest":
            body = {data.draw(st.text(max_size=6)): body, "version": 1}
    kind = data.draw(st.sampled_from((type(msg), type(msg), *KINDS)))
    check(json.dumps(body).encode(), kind)  # allow_nan: NaN and Infinity tokens go out too


@FUZZ
@given(msg=st.sampled_from(VALID), cut=st.floats(0, 1), extra=st.binary(max_size=8))
def test_truncated_or_padded_valid_commands_are_refused_not_misread(msg, cut, extra):
    payload = encode(msg)
    k = int(cut * (len(payload) - 1))
    assert check(payload[:k], type(msg)) is None, "a truncated command is never taken"
    check(payload[:k] + extra, type(msg))


@pytest.mark.parametrize(
    "payload, kind, reason",
    [
        (b'{"axis": "x", "distance": 5.0, "version": 1}', Jog, "unknown field `distance`"),  # not a continuous jog
        (b'{"percent": 50, "version": 1, "percentage": 80}', Override, "unknown field `percentage`"),
        (b'{"cycles": 1180591620717411303424, "version": 1}', CycleStart, f"Expected `int` <= {MAX_CYCLES} - at `$.cycles`"),
        (b'{"percent": 1e400, "version": 1}', Override, "Number out of range - at `$.percent`"),
        (b'{"percent": NaN, "version": 1}', Override, "JSON is malformed"),
        (b'[{"percent": 50, "version": 1}]', Override, "Expected `object`, got `array`"),
        (b'{"percent": 50, "version": "1"}', Override, "Expected `int | null`, got `str` - at `$.version`"),
        (b'{"variables": [{"name": "x", "modus": "timed"}], "version": 1}', LogStart, "unknown field `modus`"),
    ],
)
def test_the_refusal_names_the_field_or_what_is_wrong(payload, kind, reason):
    with pytest.raises(DECODE_ERRORS) as refused:
        decode(payload, kind)
    assert reason in str(refused.value)
