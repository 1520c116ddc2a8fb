"""Condition expressions: precedence, comparisons, fail-safe evaluation and errors that say where and what."""

from __future__ import annotations

import enum
import itertools

import pytest

from cnc.logic.conditions import ConditionError, compile_condition, describe_known

WHERE = "machines/waterjet.toml: [[procedure]] #1 (transport) step #3 condition"
KNOWN = {"din.*", "plc.mains_on", "plc.pump_fault", "plc.pump_running", "homed", "mode", "state", "pump_pressure"}


class Mode(enum.Enum):
    MANUAL = 1
    AUTO = 2


def holds(text: str, **signals: object) -> bool:
    return compile_condition(text).evaluate({k.replace("__", "."): v for k, v in signals.items()})


def test_a_plain_or_dotted_name_holds_when_its_signal_is_true():
    c = compile_condition("din.estop_ok", KNOWN, WHERE)
    assert c.names == {"din.estop_ok"}
    assert c.evaluate({"din.estop_ok": True}) is True
    assert c.evaluate({"din.estop_ok": False}) is False
    assert c.evaluate({"din.estop_ok": 0}) is False and c.evaluate({"din.estop_ok": 1}) is True


@pytest.mark.parametrize("a, b, c", list(itertools.product((False, True), repeat=3)))
def test_not_binds_tighter_than_and_which_binds_tighter_than_or(a, b, c):
    s = {"a": a, "b": b, "c": c}
    assert compile_condition("not a and b or c").evaluate(s) == (((not a) and b) or c)
    assert compile_condition("a or b and c").evaluate(s) == (a or (b and c))
    assert compile_condition("not a or b").evaluate(s) == ((not a) or b)
    assert compile_condition("not not a").evaluate(s) == a


@pytest.mark.parametrize("a, b, c", list(itertools.product((False, True), repeat=3)))
def test_parentheses_override_precedence(a, b, c):
    s = {"a": a, "b": b, "c": c}
    assert compile_condition("(a or b) and c").evaluate(s) == ((a or b) and c)
    assert compile_condition("not (a and b)").evaluate(s) == (not (a and b))
    assert compile_condition("((a))").evaluate(s) == a


def test_comparison_binds_tighter_than_not():
    assert holds("not pump_pressure >= 1000", pump_pressure=500) is True
    assert holds("not pump_pressure >= 1000", pump_pressure=1500) is False


@pytest.mark.parametrize(
    "text, pressure, expected",
    [
        ("pump_pressure >= 1000", 999.9, False), ("pump_pressure >= 1000", 1000, True),
        ("pump_pressure > 1000", 1000, False), ("pump_pressure < 1000", 999, True),
        ("pump_pressure <= 1e3", 1000.0, True), ("pump_pressure == 1000", 1000, True),
        ("pump_pressure != 1000", 1000, False), ("pump_pressure > -5.5", -5, True),
        ("1000 <= pump_pressure", 1200, True), ("pump_pressure >= .5", 0.25, False),
    ],
)
def test_comparisons_with_numbers(text, pressure, expected):
    assert holds(text, pump_pressure=pressure) is expected


def test_enum_words_right_of_equality_compare_as_text():
    c = compile_condition("state == READY and mode != MANUAL", KNOWN, WHERE)
    assert c.names == {"state", "mode"}  # READY and MANUAL are values, not signals
    assert c.evaluate({"state": "READY", "mode": Mode.AUTO}) is True
    assert c.evaluate({"state": "READY", "mode": Mode.MANUAL}) is False
    assert c.evaluate({"state": "RUNNING", "mode": Mode.AUTO}) is False


def test_two_signals_compare_numerically_or_as_text():
    assert holds("a >= b", a=5, b=3) is True
    assert holds("a == b", a="AUTO", b=Mode.AUTO) is True
    assert holds("a < b", a="x", b=3) is False  # no order between text and number: false, no exception


def test_a_missing_signal_makes_the_whole_condition_false():
    assert holds("plc.pump_fault") is False
    assert holds("not plc.pump_fault") is False  # fail-safe: a missing PLC image passes no check
    assert holds("not plc.pump_fault", plc__pump_fault=False) is True
    assert holds("pump_pressure >= 1000") is False
    assert holds("state != READY") is False
    assert holds("not plc.pump_fault", plc__pump_fault=None) is False  # None counts as missing
    assert holds("a or b", b=True) is False  # any missing name: the condition is false as a whole


def test_a_text_signal_compared_with_a_number_is_false_not_an_error():
    assert holds("pump_pressure >= 1000", pump_pressure="high") is False
    assert holds("mode == 2", mode=Mode.AUTO) is False


def test_known_signal_families_admit_any_name_under_their_prefix():
    assert compile_condition("din.anything_at_all and plc.mains_on", KNOWN, WHERE).names == {
        "din.anything_at_all", "plc.mains_on",
    }


def _error(text: str, known: set[str] | None = None) -> ConditionError:
    with pytest.raises(ConditionError) as info:
        compile_condition(text, known, WHERE)
    assert isinstance(info.value, ValueError)
    assert str(info.value).startswith(WHERE + ": ")
    return info.value


def test_unknown_signal_error_names_it_the_column_a_suggestion_and_the_known_prefixes():
    e = _error("din.mains_on and plc.mains_of", KNOWN)
    assert e.column == 18
    msg = str(e)
    assert "column 18" in msg and "unknown signal 'plc.mains_of'" in msg and "did you mean 'plc.mains_on'" in msg
    assert "din.*, plc.*" in msg and "homed" in msg and "'din.mains_on and plc.mains_of'" in msg


@pytest.mark.parametrize(
    "text, column, reason",
    [
        ("a and", 6, "expected a signal name, a number or '(' after 'and', found the end of the condition"),
        ("(a", 1, "unbalanced parenthesis: '(' is not closed"),
        ("(a or (b)", 1, "unbalanced parenthesis: '(' is not closed"),
        ("a)", 2, "unbalanced parenthesis: ')' has no matching '('"),
        ("a === b", 5, "unexpected character '='"),
        ("1 +", 3, "unexpected character '+'"),
        ("a = b", 3, "unexpected character '='"),
        ("a b", 3, "unexpected 'b'; expected and, or, or the end of the condition"),
        ("a < b < c", 7, "comparisons do not chain"),
        ("1000", 1, "a number alone is not a condition"),
        ("()", 2, "expected a signal name, a number or '(' after '(', found ')'"),
        ("not", 4, "expected a signal name, a number or '(' after 'not'"),
        ("a >= ", 6, "expected a signal name or a number after '>=', found the end of the condition"),
        ("state == (READY)", 10, "expected a signal name, a number or a word such as READY after '==', found '('"),
        ("", 1, "empty condition"),
    ],
)
def test_bad_input_is_refused_with_the_column_and_what_is_wrong(text, column, reason):
    e = _error(text)
    assert e.column == column
    assert e.reason.startswith(reason)
    assert f"column {column}: {reason}" in str(e)


def test_nesting_is_bounded():
    e = _error("(" * 40 + "a" + ")" * 40)
    assert "nested more than" in e.reason


def test_describe_known_lists_families_then_plain_names():
    assert describe_known({"plc.b", "plc.a", "din.*", "homed", "mode"}) == "din.*, plc.*, homed, mode"


def test_fifty_conditions_evaluated_scan_after_scan_give_what_each_says():
    """Compiled once, evaluated every scan against the scan's signals (their cost within the 4 ms
    scan is measured with the whole scan by bench/logic_scan.py, not here)."""
    texts = ["din.estop_ok and plc.mains_on", "pump_pressure >= 1000", "state == READY and not plc.pump_fault",
             "(homed or mode == MANUAL) and not (plc.pump_fault or pump_pressure > 4000)", "missing_signal"] * 10
    conds = [compile_condition(t) for t in texts]
    signals = {"din.estop_ok": True, "plc.mains_on": True, "pump_pressure": 1200.0, "state": "READY",
               "plc.pump_fault": False, "homed": True, "mode": Mode.AUTO}
    for _ in range(200):
        assert [c.evaluate(signals) for c in conds] == [True, True, True, True, False] * 10
