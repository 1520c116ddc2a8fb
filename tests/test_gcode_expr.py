"""LinuxCNC expressions and parameters: values, scoping and errors as LinuxCNC's rs274 gives them.

Every expected value below was checked with LinuxCNC 2.9's standalone `rs274 -g` through
`#1=[...] (DEBUG,#1)`; bit-exact trig values were read back scaled by a power of two.
"""

from __future__ import annotations

import math

import pytest

from gcode.errors import GCodeError
from gcode.expr import (
    MAX_NESTING,
    Const,
    parse_expression,
    parse_parameter_ref,
    parse_real_value,
)
from gcode.params import MAX_PARAMETER, Parameters

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

try:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st
except ImportError:  # pragma: no cover - hypothesis is a test-only dependency
    st = None

needs_hypothesis = pytest.mark.skipif(st is None, reason="hypothesis is not installed")


def value(text: str, params: Parameters | None = None) -> float:
    node, end = parse_real_value(text, 0)
    assert end == len(text), f"parsed only {text[:end]!r} of {text!r}"
    return node.evaluate(params if params is not None else Parameters())


def error(text: str, params: Parameters | None = None) -> GCodeError:
    with pytest.raises(GCodeError) as caught:
        node, _ = parse_real_value(text, 0)
        node.evaluate(params if params is not None else Parameters())
    return caught.value


# -- literals and the fast path -----------------------------------------------------------------


@pytest.mark.parametrize(
    "text, pos, expected, end",
    [
        ("12", 0, 12.0, 2),
        ("-3.5", 0, -3.5, 4),
        (".5", 0, 0.5, 2),
        ("+2.", 0, 2.0, 3),
        ("007", 0, 7.0, 3),
        ("x12.5y-3", 1, 12.5, 5),
        ("x12.5y-3", 6, -3.0, 8),
        ("g1x0", 1, 1.0, 2),
    ],
)
def test_a_plain_number_is_a_constant_node_readable_without_evaluation(text, pos, expected, end):
    node, stop = parse_real_value(text, pos)
    assert isinstance(node, Const)
    assert node.const == expected and stop == end


def test_constant_sub_expressions_are_folded_at_parse_time():
    node, _ = parse_real_value("[1+2*3-sin[30]]", 0)
    assert node.const == 6.5
    node, _ = parse_real_value("[#1+2*3]", 0)
    assert node.const is None


# -- operators ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[1+2*3]", 7.0),
        ("[2*3**2]", 18.0),
        ("[2-3*4/5]", -0.4),
        ("[9+8*7/6+5-4*3**2+1]", -11.666667),
        ("[1+2mod3]", 3.0),
        ("[6/4mod1]", 0.5),
        ("[1+1eq2]", 1.0),
        ("[3-2-1eq0]", 1.0),
        ("[2eq2and3]", 1.0),
        ("[1lt2and3gt2]", 1.0),
        ("[1or0eq0]", 1.0),
        ("[0eq0or1]", 1.0),
    ],
)
def test_precedence_is_power_then_times_then_plus_then_comparison_then_logic(text, expected):
    assert value(text) == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[2**3**2]", 64.0),  # (2**3)**2: power is left-associative too
        ("[8/2/2]", 2.0),
        ("[10-4-3]", 3.0),
        ("[5gt3gt0]", 1.0),
        ("[1or0and0]", 0.0),  # and/or/xor share one level: (1 or 0) and 0
        ("[0and1or1]", 1.0),
    ],
)
def test_operators_of_equal_precedence_associate_left(text, expected):
    assert value(text) == expected


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[-2**2]", 4.0),  # the sign belongs to the number, before any operator
        ("[2**-1]", 0.5),
        ("[2*-3]", -6.0),
        ("[1--1]", 2.0),
        ("[--[2]]", 2.0),
        ("[+-+3]", -3.0),
        ("[-.5+-.5]", -1.0),
        ("-[2+3]", -5.0),
        ("-sin[90]", -1.0),
    ],
)
def test_a_sign_applies_to_the_value_right_after_it(text, expected):
    assert value(text) == expected


def test_a_sign_applies_to_a_parameter():
    params = Parameters()
    params.set(1, 4.0)
    assert value("-#1", params) == -4.0
    assert value("[--#1*2]", params) == 8.0


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[7mod3]", 1.0),
        ("[-7mod3]", 2.0),
        ("[7mod-3]", 1.0),
        ("[-7mod-3]", 2.0),
        ("[7.5mod2]", 1.5),
        ("[-7.5mod2]", 0.5),
        ("[-7.5mod-2]", 0.5),
        ("[-6mod3]", 0.0),
    ],
)
def test_mod_is_fmod_made_non_negative_by_adding_the_divisor_magnitude(text, expected):
    assert value(text) == expected


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[1eq1.00009999]", 1.0),
        ("[1eq1.0001]", 1.0),  # 1.0001 - 1 is 9.99999999999989e-05 in doubles
        ("[0eq0.0001]", 0.0),  # strictly less than the tolerance
        ("[0.00005eq0]", 1.0),
        ("[1eq1.0002]", 0.0),
        ("[1ne1.0001]", 0.0),
        ("[1ne1.0002]", 1.0),
        ("[1.00005le1]", 0.0),  # LE, GE, LT and GT have no tolerance
        ("[1ge1.00005]", 0.0),
        ("[1lt1.00005]", 1.0),
        ("[1gt0.99995]", 1.0),
        ("[1le1]", 1.0),
    ],
)
def test_eq_and_ne_compare_within_linuxcnc_tolerance_of_0_0001(text, expected):
    assert value(text) == expected


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[2and3]", 1.0),
        ("[-1and0.5]", 1.0),
        ("[2and0]", 0.0),
        ("[0.5or0]", 1.0),
        ("[0or0]", 0.0),
        ("[2xor0]", 1.0),
        ("[1xor1]", 0.0),
        ("[0xor0]", 0.0),
    ],
)
def test_logical_operators_treat_any_non_zero_as_true_and_give_one_or_zero(text, expected):
    assert value(text) == expected


# -- functions ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, expected",
    [
        ("abs[-3]", 3.0),
        ("abs[3]", 3.0),
        ("exp[1]", math.e),
        ("ln[2.718281828459045]", 1.0),
        ("sqrt[16]", 4.0),
        ("fix[2.7]", 2.0),
        ("fix[-2.5]", -3.0),
        ("fup[2.1]", 3.0),
        ("fup[-2.5]", -2.0),
        ("round[2.5]", 3.0),
        ("round[-2.5]", -3.0),
        ("round[0.5]", 1.0),
        ("round[-0.5]", -1.0),
        ("round[1.4999]", 1.0),
    ],
)
def test_arithmetic_functions(text, expected):
    assert value(text) == expected


@pytest.mark.parametrize(
    "text, expected",
    [
        ("sin[30]", 0.5),
        ("sin[-90]", -1.0),
        ("cos[60]", 0.5),
        ("tan[45]", 1.0),
        ("asin[0.5]", 30.0),
        ("asin[1]", 90.0),
        ("acos[0.5]", 60.0),
        ("acos[0]", 90.0),
        ("atan[1]/[1]", 45.0),
        ("atan[-1]/[-1]", -135.0),
        ("atan[0]/[-1]", 180.0),
        ("atan[1]/[0]", 90.0),
    ],
)
def test_trig_functions_work_in_degrees_and_are_exact_where_linuxcnc_is(text, expected):
    assert value(text) == expected


def test_trig_matches_linuxcnc_long_double_conversion_to_the_last_bit():
    # rs274: [sin[180]*2**122] and [cos[90]*2**122]; double-precision radians would give
    # 1.2246e-16 and 6.1232e-17 instead.
    assert value("sin[180]") * 2.0**122 == -266725952849067584.0
    assert value("cos[90]") * 2.0**122 == -133362976424533792.0


def test_atan_arguments_may_be_expressions_of_parameters():
    params = Parameters()
    params.set(1, -3.0)
    params.set(2, 3.0)
    assert value("atan[#1]/[#2]", params) == -45.0


def test_exists_tells_whether_a_named_parameter_is_defined():
    params = Parameters(predefined=lambda name: 1.0 if name == "_metric" else None)
    assert value("exists[#<part>]", params) == 0.0
    params.set_named("part", 3.0)
    params.set_named("_count", 1.0)
    assert value("exists[#<part>]", params) == 1.0
    assert value("exists[#<_count>]", params) == 1.0
    assert value("exists[#<_metric>]", params) == 1.0
    assert value("exists[#<_imperial>]", params) == 0.0


def test_exists_of_a_numbered_parameter_tells_whether_the_number_is_in_range():
    assert value("exists[#2]") == 1.0
    assert value("exists[#[1+1]]") == 1.0
    assert value("exists[#0]") == 0.0
    assert value(f"exists[#{MAX_PARAMETER + 1}]") == 0.0


# -- parameters ---------------------------------------------------------------------------------


def test_nested_parameter_references_read_the_parameter_whose_number_is_stored():
    params = Parameters()
    params.set(2, 7.0)
    params.set(3, 2.0)
    params.set(7, 42.0)
    assert value("##3", params) == 7.0
    assert value("###3", params) == 42.0
    assert value("#[1+1]", params) == 7.0
    assert value("#[#3*3.5]", params) == 42.0
    params.set(1, 5.0)
    assert value("#1.99999", params) == 7.0  # within 0.0001 of an integer: #2
    assert value("#1.00001", params) == 5.0


def test_parameter_references_name_their_assignment_target():
    params = Parameters()
    params.set(3, 2.0)
    for text, expected in [("#5", 5), ("##3", 2), ("#[1+1]", 2), ("#<_g>", "_g"), ("#<loc>", "loc")]:
        ref, end = parse_parameter_ref(text, 0)
        assert end == len(text) and ref.target(params) == expected


def test_named_parameters_local_to_a_call_and_global_with_underscore():
    params = Parameters()
    params.set_named("part", 1.0)
    params.set_named("_total", 10.0)
    params.push_scope([])
    assert not params.exists("part")
    with pytest.raises(GCodeError, match=r"Named parameter #<part> not defined"):
        params.get_named("part")
    assert value("#<_total>", params) == 10.0
    params.set_named("part", 2.0)
    params.set_named("_total", 11.0)
    params.pop_scope()
    assert params.get_named("part") == 1.0
    assert params.get_named("_total") == 11.0


def test_a_call_passes_its_arguments_as_1_to_30_and_restores_the_callers_on_return():
    params = Parameters()
    params.apply([(1, 11.0), (2, 5.0), (31, 3.0)])
    params.push_scope([42.0])
    assert params.call_level == 1
    assert (params.get(1), params.get(2), params.get(31)) == (42.0, 0.0, 3.0)
    params.apply([(2, 99.0), (31, 31.0)])
    params.pop_scope()
    assert (params.get(1), params.get(2), params.get(31)) == (11.0, 5.0, 31.0)
    assert params.call_level == 0


def test_more_than_30_call_arguments_and_a_return_without_call_are_errors():
    params = Parameters()
    with pytest.raises(GCodeError, match="Too many subroutine parameters: 31"):
        params.push_scope([0.0] * 31)
    with pytest.raises(GCodeError, match="not called"):
        params.pop_scope()


def test_settings_on_one_line_use_the_old_values_parallel_assignment():
    params = Parameters()
    params.set(1, 5.0)
    line = "#1=10#2=#1"
    ref1, pos = parse_parameter_ref(line, 0)
    value1, pos = parse_real_value(line, pos + 1)
    ref2, pos = parse_parameter_ref(line, pos)
    value2, pos = parse_real_value(line, pos + 1)
    settings = [(ref.target(params), node.evaluate(params)) for ref, node in [(ref1, value1), (ref2, value2)]]
    params.apply(settings)
    assert (params.get(1), params.get(2)) == (10.0, 5.0)


def test_a_line_with_one_bad_setting_changes_nothing():
    params = Parameters(predefined=lambda name: 0.0 if name == "_x" else None)
    with pytest.raises(GCodeError):
        params.apply([(1, 1.0), ("_x", 2.0)])
    with pytest.raises(GCodeError):
        params.apply([(1, 1.0), (0, 2.0)])
    assert params.get(1) == 0.0


def test_declare_creates_a_named_parameter_as_linuxcnc_does_when_it_reads_the_setting():
    # rs274: "#<a>=1 #<b>=#<a>" sets b to 0: a exists (as 0) once its setting has been read.
    params = Parameters()
    params.declare("a")
    assert params.get_named("a") == 0.0
    params.set_named("a", 1.0)
    params.declare("a")
    assert params.get_named("a") == 1.0


def test_predefined_parameters_come_from_the_hook_and_are_read_only():
    state = {"_x": 12.5, "_metric": 1.0}
    params = Parameters(predefined=state.get)
    assert value("[#<_x>*2]", params) == 25.0
    assert params.exists("_metric")
    state["_x"] = 3.0
    assert value("#<_x>", params) == 3.0
    with pytest.raises(GCodeError, match=r"Cannot assign to read-only parameter #<_x>") as caught:
        params.set_named("_x", 1.0)
    assert caught.value.code == "parameter"
    ref, _ = parse_parameter_ref("#<_x>", 0)
    with pytest.raises(GCodeError, match="read-only") as caught:
        ref.target(params)
    assert caught.value.column == 1


def test_position_and_tool_parameters_are_read_only_to_programs_but_not_to_the_interpreter():
    params = Parameters()
    ref, _ = parse_parameter_ref("#5420", 0)
    with pytest.raises(GCodeError, match=r"Parameter #5420 is read-only"):
        ref.target(params)
    with pytest.raises(GCodeError, match="read-only"):
        params.set(5400, 1.0)
    params.set_system(5420, 12.0)
    assert value("#5420", params) == 12.0
    params.set(5399, 1.0)  # just below the read-only block


@pytest.mark.parametrize("number", [0, -1, MAX_PARAMETER + 1])
def test_the_store_rejects_numbers_outside_1_to_5601(number):
    params = Parameters()
    with pytest.raises(GCodeError, match=rf"#{number} out of range 1\.\.5601"):
        params.get(number)
    with pytest.raises(GCodeError, match=rf"#{number} out of range"):
        params.set(number, 1.0)


# -- errors -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, code, column, message",
    [
        ("[1+2", "expression", 1, "Unclosed expression"),
        ("[[1]", "expression", 1, "Unclosed expression"),
        ("[1foo2]", "expression", 3, "unknown operator 'foo'"),
        ("[1an2]", "expression", 3, "unknown operator 'an'"),
        ("[1e5]", "expression", 3, "unknown operator 'e'"),
        ("[1&2]", "expression", 3, "unknown operator '&'"),
        ("[foo[2]]", "unknown-word", 2, "unknown function 'foo'"),
        ("[ab[1]]", "unknown-word", 2, "unknown function 'ab'"),
        ("[sin30]", "expression", 5, "Left bracket missing after function name 'sin'"),
        ("[atan[1]]", "expression", 9, "Slash missing after first atan argument"),
        ("[atan[1]/2]", "expression", 10, "Left bracket missing after slash with atan"),
        ("exists[1]", "expression", 8, "Expected # reading parameter"),
        ("exists[#<a>+1]", "expression", 12, "Expected ] reading bracketed parameter"),
        ("[1/0]", "division-by-zero", 3, "Attempt to divide by zero: 1 / 0"),
        ("[2/[1-1]]", "division-by-zero", 3, "Attempt to divide by zero: 2 / 0"),
        ("[5mod0]", "domain", 1, "Calculation resulted in 'not a number': [5mod0]"),
        ("[2*[5mod0]]", "domain", 4, "Calculation resulted in 'not a number': [5mod0]"),
        ("[10**400*0]", "domain", 1, "Calculation resulted in 'not a number': [10**400*0]"),
        ("[sqrt[-4]]", "domain", 2, "square root of negative number -4"),
        ("[ln[0]]", "domain", 2, "natural logarithm of zero or negative number 0"),
        ("[ln[-2.5]]", "domain", 2, "natural logarithm of zero or negative number -2.5"),
        ("acos[2]", "domain", 1, "Argument to acos out of range: 2"),
        ("asin[-1.5]", "domain", 1, "Argument to asin out of range: -1.5"),
        ("[[-2]**0.5]", "domain", 6, "Attempt to raise negative number -2 to non-integer power 0.5"),
        ("[exp[1000]]", "overflow", 2, "Calculation resulted in 'infinity': exp[1000]"),
        ("[0**-1]", "overflow", 1, "Calculation resulted in 'infinity': [0**-1]"),
        ("[-3**1001]", "overflow", 1, "Calculation resulted in 'infinity'"),
        ("[10**200*10**200]", "overflow", 1, "Calculation resulted in 'infinity': [10**200*10**200]"),
        ("[1.2.3]", "number", 2, "bad number '1.2.3': more than one decimal point"),
        ("[.]", "number", 2, "bad number '.': no digits"),
        ("[]", "expression", 2, "expected a value"),
        ("[1+]", "expression", 4, "expected a value"),
        ("[1+", "expression", 4, "expected a value but the line ends"),
        ("-", "number", 1, "bad number '-'"),
        ("", "expression", 1, "expected a value but the line ends"),
        ("#0", "parameter", 1, "Parameter number #0 out of range 1..5601"),
        ("[2*#5602]", "parameter", 4, "Parameter number #5602 out of range"),
        ("#-1", "parameter", 1, "#-1 out of range"),
        ("#1.5", "parameter", 1, "Non integer value for integer: parameter number 1.5"),
        ("##9", "parameter", 1, "Parameter number #0 out of range"),
        ("[#<abc]", "parameter", 3, "Named parameter not terminated"),
        ("[1+#<abc>]", "parameter", 4, "Named parameter #<abc> not defined"),
    ],
)
def test_bad_input_raises_gcode_error_naming_what_and_where(text, code, column, message):
    caught = error(text)
    assert (caught.code, caught.column) == (code, column), caught.message
    assert message in caught.message


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[10**400gt1]", 1.0),
        ("[0**-1gt0]", 1.0),
        ("[-3**1001lt0]", 1.0),
        ("[5mod0lt1]", 0.0),  # NaN compares false, as in C
        ("[5mod0ne1]", 0.0),
        ("[5mod0eq5mod0]", 0.0),
    ],
)
def test_an_infinite_or_nan_intermediate_is_fine_if_the_bracket_value_is_finite(text, expected):
    assert value(text) == expected


def test_value_errors_wait_until_the_line_runs_so_a_branch_not_taken_cannot_fail():
    node, _ = parse_real_value("[1/0]", 0)  # parses: LinuxCNC only fails when it executes it
    for _ in range(2):
        with pytest.raises(GCodeError, match="divide by zero"):
            node.evaluate(Parameters())
    ref, _ = parse_parameter_ref("#0", 0)
    with pytest.raises(GCodeError, match="out of range"):
        ref.target(Parameters())


def test_parse_expression_and_parse_parameter_ref_insist_on_their_opening_character():
    with pytest.raises(GCodeError, match=r"expected '\['") as caught:
        parse_expression("x[1]", 0)
    assert caught.value.column == 1
    with pytest.raises(GCodeError, match="expected '#'"):
        parse_parameter_ref("[1]", 0)
    node, end = parse_expression("g[1+1]x", 1)
    assert (node.const, end) == (2.0, 6)


@pytest.mark.parametrize(
    "text",
    [
        "[" * 200 + "1" + "]" * 200,
        "-" * 500 + "1",
        "#" * 300 + "1",
        "sin[" * 150 + "1" + "]" * 150,
        "[" + "+".join(["#1"] * 2000) + "]",
        "[" + "*".join(["[#1+1]"] * 1000) + "]",
    ],
)
def test_deep_nesting_is_an_error_not_a_crash(text):
    with pytest.raises(GCodeError, match="nested too deeply") as caught:
        parse_real_value(text, 0)
    assert caught.value.code == "expression"


def test_nesting_up_to_the_limit_works():
    depth = MAX_NESTING // 2
    assert value("[" * depth + "1" + "]" * depth) == 1.0
    params = Parameters()
    params.set(1, 2.0)
    assert value("[" + "+".join(["#1"] * 200) + "]", params) == 400.0


# -- properties ---------------------------------------------------------------------------------

if st is not None:
    _ALPHABET = "0123456789.+-*/[]#<>_abcdefgilmnopqrstuxz"
    _TOKENS = st.sampled_from(
        ["[", "]", "#", "#<a>", "#<_g>", "#<", ">", "+", "-", "*", "**", "/", "mod", "and", "or", "xor"]
        + ["eq", "ne", "gt", "ge", "lt", "le", "sin[", "atan[", "]/[", "exists[", "sqrt[", "round["]
        + ["1", "0", "2.5", ".", "-3", "5601", "5602", "30"]
    )
    _TEXT = st.one_of(st.text(_ALPHABET, max_size=60), st.lists(_TOKENS, max_size=40).map("".join))

    def _params() -> Parameters:
        params = Parameters(predefined=lambda name: 7.0 if name == "_x" else None)
        params.set_named("a", 3.0)
        params.set_named("_g", -2.0)
        params.set(1, 2.0)
        return params

    @needs_hypothesis
    @settings(max_examples=800, deadline=None, suppress_health_check=[HealthCheck.too_slow])  # bounded for the suite's time
    @given(_TEXT, st.integers(min_value=0, max_value=3))
    def test_any_text_raises_only_gcode_error_and_never_hangs(text, pos):
        for parse in (parse_real_value, parse_expression, parse_parameter_ref):
            try:
                node, end = parse(text, pos)
                assert pos < end <= len(text)
                result = node.evaluate(_params())
                assert isinstance(result, float)
            except GCodeError as caught:
                assert caught.column >= 1 and caught.message and caught.code

    _NUMBERS = st.sampled_from([0.0, 1.0, -1.0, 2.5, -3.0, 0.5, 7.0, 30.0, 1000.0])
    _BINARY = ["+", "-", "*", "/", "mod", "**", "eq", "ne", "lt", "le", "gt", "ge", "and", "or", "xor"]
    _UNARY = ["abs", "acos", "asin", "cos", "exp", "fix", "fup", "ln", "round", "sin", "sqrt", "tan"]

    def _expressions(leaf):
        def extend(inner):
            binary = st.tuples(inner, st.sampled_from(_BINARY), inner).map(lambda t: f"[{t[0]}{t[1]}{t[2]}]")
            unary = st.tuples(st.sampled_from(_UNARY), inner).map(lambda t: f"{t[0]}[{t[1]}]")
            atan = st.tuples(inner, inner).map(lambda t: f"atan[{t[0]}]/[{t[1]}]")
            return binary | unary | atan | inner.map(lambda e: f"-{e}")

        return st.recursive(leaf, extend, max_leaves=12)

    @needs_hypothesis
    @settings(max_examples=250, deadline=None)  # bounded for the suite's time
    @given(st.lists(_NUMBERS, min_size=20, max_size=20), st.data())
    def test_folding_constants_gives_what_evaluating_parameters_gives(numbers, data):
        # The same expression with numbers (folded at parse time) and with #n holding those
        # numbers (computed at run time) gives the same value, or the same error.
        index = st.integers(min_value=1, max_value=20)
        shape = data.draw(_expressions(index.map(lambda k: f"#{k}")))
        constant = shape
        for k in range(20, 0, -1):
            constant = constant.replace(f"#{k}", f"[{numbers[k - 1]!r}]")
        params = Parameters()
        for k, number in enumerate(numbers, start=1):
            params.set(k, number)
        outcomes = []
        for text in (shape, constant):
            node, _ = parse_real_value(text, 0)
            try:
                outcomes.append(node.evaluate(params))
            except GCodeError as caught:
                outcomes.append(caught.code)
        assert outcomes[0] == outcomes[1] or (outcomes[0] != outcomes[0] and outcomes[1] != outcomes[1])
