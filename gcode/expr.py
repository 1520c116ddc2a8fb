"""LinuxCNC expressions and parameter references, parsed once into nodes that evaluate fast.

The text is a line as LinuxCNC normalises it: lower case, no spaces or tabs outside comments.
Parsing builds a tree of small nodes and closures; `node.evaluate(params)` runs it. A plain number becomes a
`Const` whose value is `node.const` (None on every other node), so the interpreter can skip
evaluation for the common case, and constant sub-expressions are folded at parse time.

Semantics follow LinuxCNC's interp_read.cc / interp_execute.cc, checked against `rs274`:

- Precedence, tightest first: `**`; `* / mod`; `+ -`; `eq ne gt ge lt le`; `and or xor`.
  Left-associative at every level, `**` included: [2**3**2] is 64.
- A sign binds to the value right after it, before any operator: [-2**2] is 4.
- EQ and NE compare with |a - b| < 0.0001 (TOLERANCE_EQUAL); LT, LE, GT and GE are exact, as
  in the rs274 of LinuxCNC 2.9 (later LinuxCNC also applies the tolerance to LE and GE).
- `a mod b` is C fmod plus |b| when negative, so it is never negative: [-7 mod 3] is 2.
- ROUND rounds half away from zero, FIX is floor, FUP is ceil.
- Angles are degrees, converted with long-double pi as LinuxCNC does, so sin[30] is exactly 0.5.
- A bracketed expression or function whose value is infinite or NaN is an error; inside a
  bracket an infinite or NaN intermediate is not: [10**400 gt 1] is 1, as in C.

Value errors (division by zero, sqrt of a negative, #0, ...) are raised when the node is
evaluated, not when it is parsed: LinuxCNC reports them only for lines it executes, and a
line inside a branch that is never taken must not fail. Syntax errors are raised by the parser.
"""

from __future__ import annotations

import math
import re
from typing import Callable, NamedTuple

import numpy as np

from .errors import GCodeError
from .params import MAX_PARAMETER, READ_ONLY_NUMBERS, Parameters, Target

Evaluate = Callable[[Parameters], float]

TOLERANCE_EQUAL = 0.0001  # LinuxCNC's TOLERANCE_EQUAL for EQ and NE
INTEGER_TOLERANCE = 0.0001  # a parameter number must be this close to an integer
MAX_NESTING = 100  # brackets, signs, functions and # nested in one another
MAX_HEIGHT = 256  # operations stacked in one tree: bounds the evaluation's recursion

# LinuxCNC converts angles as x * M_PIl / 180.0 in long double; numpy's longdouble is the
# platform's C long double, so results match to the last bit.
_PI_L = np.longdouble("3.14159265358979323846264338327950288")
_180_L = np.longdouble(180)

_LITERAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?![0-9.])")
_match_literal = _LITERAL.match  # bound once: this is the hot path
# A bracket holding one number, as CAM posts write subroutine arguments: `[40.000]`
_match_bracketed_literal = re.compile(r"\[([+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))\]").match
_match_simple_parameter = re.compile(r"#([0-9]+)(?![0-9.])").match
_NUMBER_SPAN = re.compile(r"[+-]*[0-9.]*")
_WORD = re.compile(r"[a-z]+")


class Node:
    """A parsed value: `evaluate(params) -> float`; `const` is the value if known at parse time."""

    __slots__ = ()
    const: float | None = None
    height = 0

    def evaluate(self, params: Parameters) -> float:  # pragma: no cover - overridden
        raise NotImplementedError


class Const(Node):
    """A number known at parse time."""

    __slots__ = ("const",)

    def __init__(self, value: float) -> None:
        self.const = value

    def evaluate(self, params: Parameters) -> float:
        return self.const

    def __repr__(self) -> str:
        return f"Const({self.const!r})"


class Computed(Node):
    """A value computed from parameters (or one whose evaluation raises the deferred error)."""

    __slots__ = ("evaluate", "height")

    def __init__(self, evaluate: Evaluate, height: int) -> None:
        self.evaluate = evaluate
        self.height = height


class ParamRef(Node):
    """`#n`, `##n`, `#[expr]` or `#<name>`: read with `evaluate(params)`; as an assignment
    target, `target(params)` gives the number (int) or the name (str), checked writable."""

    __slots__ = ()

    def target(self, params: Parameters) -> Target:  # pragma: no cover - overridden
        raise NotImplementedError


# -- public entry points ------------------------------------------------------------------------


def parse_real_value(text: str, pos: int) -> tuple[Node, int]:
    """One real value at text[pos]: number, [expression], #parameter, function call, or a sign
    applied to any of these. Returns the node and the position just after it."""
    match = _match_literal(text, pos)
    if match is not None:
        return Const(float(match.group())), match.end()
    return _value(text, pos, 0)


def parse_expression(text: str, pos: int) -> tuple[Node, int]:
    """The bracketed expression starting at text[pos] == '['."""
    if text[pos : pos + 1] != "[":
        raise _error(f"expected '[' to start an expression, found {_found(text, pos)}", pos)
    match = _match_bracketed_literal(text, pos)
    if match is not None:
        return Const(float(match.group(1))), match.end()
    return _bracket(text, pos, 0)


def parse_parameter_ref(text: str, pos: int) -> tuple[ParamRef, int]:
    """The parameter reference starting at text[pos] == '#'."""
    if text[pos : pos + 1] != "#":
        raise _error(f"expected '#' to start a parameter, found {_found(text, pos)}", pos)
    return _parameter(text, pos, 0)


# -- values -------------------------------------------------------------------------------------


def _operand(text: str, pos: int, depth: int) -> tuple[Node, int]:
    match = _match_literal(text, pos)
    if match is not None:
        return Const(float(match.group())), match.end()
    return _value(text, pos, depth)


def _value(text: str, pos: int, depth: int) -> tuple[Node, int]:
    if depth > MAX_NESTING:
        raise _too_deep(pos)
    if pos >= len(text):
        raise _error("expected a value but the line ends", pos)
    c = text[pos]
    if c == "[":
        return _bracket(text, pos, depth)
    if c == "#":
        return _parameter(text, pos, depth)
    if c in "+-" and pos + 1 < len(text) and text[pos + 1] not in "0123456789.":
        # A sign not followed by a number applies to the value after it: -[1], -#1, --1.
        node, end = _operand(text, pos + 1, depth + 1)
        return (_negate(node, pos) if c == "-" else node), end
    if "a" <= c <= "z":
        return _function(text, pos, depth)
    raise _bad_number(text, pos)


def _bad_number(text: str, pos: int) -> GCodeError:
    """Why text[pos] does not start a value; well-formed numbers were taken by _LITERAL."""
    span = _NUMBER_SPAN.match(text, pos).group()
    if not span:
        what = "number, #parameter, [expression] or function"
        return _error(f"expected a value ({what}), found {_found(text, pos)}", pos)
    if not any(ch.isdigit() for ch in span):
        return _error(f"bad number '{span}': no digits", pos, code="number")
    return _error(f"bad number '{span}': more than one decimal point", pos, code="number")


def _negate(node: Node, at: int) -> Node:
    if node.const is not None:
        return Const(-node.const)
    f = node.evaluate
    return Computed(lambda p: -f(p), _height(node.height + 1, at))


# -- brackets and binary operators -------------------------------------------------------------


class _Op(NamedTuple):
    symbol: str
    precedence: int
    apply: Callable[[float, float, int], float]  # (left, right, at) -> value, or GCodeError


def _divide(a: float, b: float, at: int) -> float:
    if b == 0.0:
        raise _error(f"Attempt to divide by zero: {_fmt(a)} / {_fmt(b)}", at, code="division-by-zero")
    return a / b


def _modulo(a: float, b: float, at: int) -> float:
    try:
        r = math.fmod(a, b)
    except ValueError:  # x mod 0 or inf mod x: NaN in C; the enclosing bracket may still be finite
        return math.nan
    return r + abs(b) if r < 0.0 else r


def _power(a: float, b: float, at: int) -> float:
    if a < 0.0 and not (b.is_integer() or math.isinf(b)):
        raise _error(f"Attempt to raise negative number {_fmt(a)} to non-integer power {_fmt(b)}", at, code="domain")
    try:
        return math.pow(a, b)
    except (OverflowError, ValueError):
        # C pow overflows to +-inf and gives +-inf for 0 to a negative power; LinuxCNC only
        # rejects that if it is the value of the enclosing bracket: [10**400 gt 1] is 1.
        odd_integer = b.is_integer() and math.fmod(b, 2.0) != 0.0
        return math.copysign(math.inf, a) if odd_integer else math.inf


_OPERATORS = {
    "**": _Op("**", 6, _power),
    "*": _Op("*", 5, lambda a, b, c: a * b),
    "/": _Op("/", 5, _divide),
    "mod": _Op("mod", 5, _modulo),
    "+": _Op("+", 4, lambda a, b, c: a + b),
    "-": _Op("-", 4, lambda a, b, c: a - b),
    "eq": _Op("eq", 3, lambda a, b, c: 1.0 if abs(a - b) < TOLERANCE_EQUAL else 0.0),
    "ne": _Op("ne", 3, lambda a, b, c: 1.0 if abs(a - b) >= TOLERANCE_EQUAL else 0.0),
    "le": _Op("le", 3, lambda a, b, c: 1.0 if a <= b else 0.0),
    "ge": _Op("ge", 3, lambda a, b, c: 1.0 if a >= b else 0.0),
    "lt": _Op("lt", 3, lambda a, b, c: 1.0 if a < b else 0.0),
    "gt": _Op("gt", 3, lambda a, b, c: 1.0 if a > b else 0.0),
    "and": _Op("and", 2, lambda a, b, c: 1.0 if a != 0.0 and b != 0.0 else 0.0),
    "or": _Op("or", 2, lambda a, b, c: 1.0 if a != 0.0 or b != 0.0 else 0.0),
    "xor": _Op("xor", 2, lambda a, b, c: 1.0 if (a != 0.0) != (b != 0.0) else 0.0),
}
# Candidates by first character, longest first ("**" before "*").
_BY_FIRST = {
    first: sorted((s for s in _OPERATORS if s[0] == first), key=len, reverse=True)
    for first in {s[0] for s in _OPERATORS}
}


def _bracket(text: str, start: int, depth: int) -> tuple[Node, int]:
    """[v op v op ... v], read left to right as LinuxCNC does, then combined by precedence."""
    if depth > MAX_NESTING:
        raise _too_deep(start)
    operands: list[Node] = []
    operators: list[tuple[_Op, int]] = []
    pos = start + 1
    while True:
        node, pos = _operand(text, pos, depth + 1)
        operands.append(node)
        op = _read_operator(text, pos, start)
        if op is None:
            pos += 1
            break
        operators.append((op, pos))
        pos += len(op.symbol)
    return _finite(_combine(operands, operators), text[start:pos], start), pos


def _read_operator(text: str, pos: int, start: int) -> _Op | None:
    """The binary operator at text[pos], or None for the closing ']'."""
    if pos >= len(text):
        raise _error(f"Unclosed expression: '[' at column {start + 1} has no matching ']'", start)
    c = text[pos]
    if c == "]":
        return None
    for symbol in _BY_FIRST.get(c, ()):
        if text.startswith(symbol, pos):
            return _OPERATORS[symbol]
    word = _WORD.match(text, pos)
    raise _error(f"unknown operator '{word.group() if word else c}' in expression", pos)


def _combine(operands: list[Node], operators: list[tuple[_Op, int]]) -> Node:
    """Operator precedence with a stack; equal precedence reduces left first."""
    values = [operands[0]]
    pending: list[tuple[_Op, int]] = []
    for (op, at), right in zip(operators, operands[1:]):
        while pending and pending[-1][0].precedence >= op.precedence:
            _reduce(values, pending)
        pending.append((op, at))
        values.append(right)
    while pending:
        _reduce(values, pending)
    return values[0]


def _reduce(values: list[Node], pending: list[tuple[_Op, int]]) -> None:
    op, at = pending.pop()
    right = values.pop()
    values[-1] = _binary(op, values[-1], right, at)


def _binary(op: _Op, left: Node, right: Node, at: int) -> Node:
    lc, rc = left.const, right.const
    if lc is not None and rc is not None:
        return _fold(op.apply, lc, rc, at)
    height = _height(max(left.height, right.height) + 1, at)
    lf, rf = left.evaluate, right.evaluate
    # The common arithmetic gets closures without the extra call through op.apply.
    if op.symbol == "+":
        fn = (lambda p: lf(p) + rc) if rc is not None else (lambda p: lf(p) + rf(p))
    elif op.symbol == "-":
        fn = (lambda p: lf(p) - rc) if rc is not None else (lambda p: lf(p) - rf(p))
    elif op.symbol == "*":
        if rc is not None:
            fn = lambda p: lf(p) * rc  # noqa: E731
        elif lc is not None:
            fn = lambda p: lc * rf(p)  # noqa: E731
        else:
            fn = lambda p: lf(p) * rf(p)  # noqa: E731
    else:
        apply = op.apply
        fn = lambda p: apply(lf(p), rf(p), at)  # noqa: E731
    return Computed(fn, height)


def _fold(fn: Callable[..., float], *args) -> Node:
    """fn(*args) as a constant, or a node that raises fn's error when evaluated."""
    try:
        return Const(fn(*args))
    except GCodeError as error:
        return _raising(error)


def _raising(error: GCodeError) -> Computed:
    def evaluate(params: Parameters) -> float:
        raise GCodeError(error.message, code=error.code, column=error.column)

    return Computed(evaluate, 1)


def _finite(node: Node, source: str, start: int) -> Node:
    """LinuxCNC rejects a value that is infinite or NaN once a bracket has been read."""
    if node.const is not None:
        return node if math.isfinite(node.const) else _raising(_not_finite(node.const, source, start))
    f = node.evaluate

    def evaluate(p: Parameters) -> float:
        v = f(p)
        if v - v:  # NaN (true) for inf and NaN, 0.0 otherwise
            raise _not_finite(v, source, start)
        return v

    return Computed(evaluate, _height(node.height + 1, start))


def _not_finite(value: float, source: str, at: int) -> GCodeError:
    if math.isnan(value):
        return _error(f"Calculation resulted in 'not a number': {source}", at, code="domain")
    return _error(f"Calculation resulted in 'infinity': {source}", at, code="overflow")


# -- functions ----------------------------------------------------------------------------------


def _radians_l(x: float) -> np.longdouble:
    return np.longdouble(x) * _PI_L / _180_L


def _degrees_l(radians: float) -> float:
    # LinuxCNC: (r * 180.0) / M_PIl, the product in double, the quotient in long double.
    return float(np.longdouble(radians * 180.0) / _PI_L)


def _inverse_trig(name: str, fn: Callable[[float], float]) -> Callable[[float, int], float]:
    def apply(x: float, at: int) -> float:
        if x < -1.0 or x > 1.0:
            raise _error(f"Argument to {name} out of range: {_fmt(x)} is not within [-1, 1]", at, code="domain")
        return _degrees_l(fn(x))

    return apply


def _sqrt(x: float, at: int) -> float:
    if x < 0.0:
        raise _error(f"square root of negative number {_fmt(x)}", at, code="domain")
    return math.sqrt(x)


def _ln(x: float, at: int) -> float:
    if x <= 0.0:
        raise _error(f"natural logarithm of zero or negative number {_fmt(x)}", at, code="domain")
    return math.log(x)


def _exp(x: float, at: int) -> float:
    try:
        return math.exp(x)
    except OverflowError:
        raise _error(f"Calculation resulted in 'infinity': exp[{_fmt(x)}]", at, code="overflow") from None


def _round(x: float, at: int) -> float:
    # LinuxCNC: (int)(x + (x < 0 ? -0.5 : 0.5)), half away from zero, the sum in double.
    # Beyond the C int range LinuxCNC's cast overflows; this returns the rounded value instead.
    return float(math.trunc(x - 0.5 if x < 0.0 else x + 0.5))


_FUNCTIONS: dict[str, Callable[[float, int], float]] = {
    "abs": lambda x, at: -x if x < 0.0 else x,
    "acos": _inverse_trig("acos", math.acos),
    "asin": _inverse_trig("asin", math.asin),
    "cos": lambda x, at: float(np.cos(_radians_l(x))),
    "exp": _exp,
    "fix": lambda x, at: float(math.floor(x)),
    "fup": lambda x, at: float(math.ceil(x)),
    "ln": _ln,
    "round": _round,
    "sin": lambda x, at: float(np.sin(_radians_l(x))),
    "sqrt": _sqrt,
    "tan": lambda x, at: float(np.tan(_radians_l(x))),
}
_FUNCTION_NAMES = ", ".join(sorted([*_FUNCTIONS, "atan", "exists"]))


def _function(text: str, pos: int, depth: int) -> tuple[Node, int]:
    name = _WORD.match(text, pos).group()
    end = pos + len(name)
    if name != "atan" and name != "exists" and name not in _FUNCTIONS:
        raise _error(f"unknown function '{name}' (known: {_FUNCTION_NAMES})", pos, code="unknown-word")
    if text[end : end + 1] != "[":
        raise _error(f"Left bracket missing after function name '{name}'", end)
    if name == "exists":
        return _exists(text, end, depth + 1)
    arg, end = _bracket(text, end, depth + 1)
    if name == "atan":
        return _atan(text, arg, end, depth + 1)
    fn = _FUNCTIONS[name]
    if arg.const is not None:
        return _fold(fn, arg.const, pos), end
    f = arg.evaluate
    return Computed(lambda p: fn(f(p), pos), _height(arg.height + 1, pos)), end


def _atan(text: str, y: Node, pos: int, depth: int) -> tuple[Node, int]:
    """atan[y]/[x]: atan2 in degrees, -180..180."""
    if text[pos : pos + 1] != "/":
        raise _error("Slash missing after first atan argument: atan needs the form atan[y]/[x]", pos)
    if text[pos + 1 : pos + 2] != "[":
        raise _error("Left bracket missing after slash with atan: atan needs the form atan[y]/[x]", pos + 1)
    x, end = _bracket(text, pos + 1, depth)
    if y.const is not None and x.const is not None:
        return Const(_degrees_l(math.atan2(y.const, x.const))), end
    yf, xf = y.evaluate, x.evaluate
    height = _height(max(y.height, x.height) + 1, pos)
    return Computed(lambda p: _degrees_l(math.atan2(yf(p), xf(p))), height), end


def _exists(text: str, pos: int, depth: int) -> tuple[Node, int]:
    """exists[#<name>] is 1.0 if the named parameter exists; exists[#n] if n is in range."""
    at = pos + 1
    if text[at : at + 1] != "#":
        raise _error(f"Expected # reading parameter in exists[...], found {_found(text, at)}", at)
    if text[at + 1 : at + 2] == "<":
        name, end = _name(text, at + 1)
        node: Node = Computed(lambda p: 1.0 if p.exists(name) else 0.0, 1)
    else:
        index, end = _operand(text, at + 1, depth + 1)
        if index.const is not None:
            node = _fold(lambda: 1.0 if 0 < _index(index.const, at) <= MAX_PARAMETER else 0.0)
        else:
            f = index.evaluate
            node = Computed(
                lambda p: 1.0 if 0 < _index(f(p), at) <= MAX_PARAMETER else 0.0, _height(index.height + 1, at)
            )
    if text[end : end + 1] != "]":
        raise _error(f"Expected ] reading bracketed parameter in exists[...], found {_found(text, end)}", end)
    return node, end + 1


# -- parameters ---------------------------------------------------------------------------------


def _parameter(text: str, pos: int, depth: int) -> tuple[ParamRef, int]:
    simple = _match_simple_parameter(text, pos)
    if simple is not None:
        number = int(simple.group(1))
        if 0 < number <= MAX_PARAMETER:
            return NumberedRef(number, pos), simple.end()
    if depth > MAX_NESTING:
        raise _too_deep(pos)
    if text[pos + 1 : pos + 2] == "<":
        name, end = _name(text, pos + 1)
        return NamedRef(name, pos), end
    index, end = _operand(text, pos + 1, depth + 1)
    if index.const is None:
        return IndirectRef(index, pos), end
    try:
        number = _index(index.const, pos)
        _check_range(number, pos)
    except GCodeError as error:
        return _BadRef(error), end
    return NumberedRef(number, pos), end


def _name(text: str, pos: int) -> tuple[str, int]:
    """The name in `<name>` at text[pos] == '<'; LinuxCNC takes anything up to '>'."""
    close = text.find(">", pos + 1)
    if close < 0:
        raise _error(f"Named parameter not terminated: '#{text[pos:]}' has no closing '>'", pos, code="parameter")
    return text[pos + 1 : close], close + 1


class NumberedRef(ParamRef):
    """#n with n known at parse time and in range."""

    __slots__ = ("number", "at")
    height = 1

    def __init__(self, number: int, at: int) -> None:
        self.number, self.at = number, at

    def evaluate(self, params: Parameters) -> float:
        return params.values[self.number]

    def target(self, params: Parameters) -> Target:
        _check_writable(self.number, self.at)
        return self.number


class NamedRef(ParamRef):
    """#<name>: global if the name starts with '_', else local to the current call level."""

    __slots__ = ("name", "at")
    height = 1

    def __init__(self, name: str, at: int) -> None:
        self.name, self.at = name, at

    def evaluate(self, params: Parameters) -> float:
        try:
            return params.get_named(self.name)
        except GCodeError as error:
            raise _located(error, self.at) from None

    def target(self, params: Parameters) -> Target:
        try:
            params.check_writable(self.name)
        except GCodeError as error:
            raise _located(error, self.at) from None
        return self.name


class IndirectRef(ParamRef):
    """##n or #[expr]: the number is computed when the line runs."""

    __slots__ = ("index", "at", "height")

    def __init__(self, index: Node, at: int) -> None:
        self.index, self.at = index.evaluate, at
        self.height = _height(index.height + 1, at)

    def number(self, params: Parameters) -> int:
        n = _index(self.index(params), self.at)
        _check_range(n, self.at)
        return n

    def evaluate(self, params: Parameters) -> float:
        return params.values[self.number(params)]

    def target(self, params: Parameters) -> Target:
        n = self.number(params)
        _check_writable(n, self.at)
        return n


class _BadRef(ParamRef):
    """A constant parameter number that is invalid (#0, #1.5): the error comes when it runs."""

    __slots__ = ("error",)
    height = 1

    def __init__(self, error: GCodeError) -> None:
        self.error = error

    def evaluate(self, params: Parameters) -> float:
        raise GCodeError(self.error.message, code=self.error.code, column=self.error.column)

    target = evaluate  # type: ignore[assignment]


def _index(value: float, at: int) -> int:
    """LinuxCNC's read_integer_value: within 0.0001 of an integer, else an error."""
    if not math.isfinite(value):
        raise _error(f"Parameter number {_fmt(value)} is not a finite number", at, code="parameter")
    n = math.floor(value)
    if value - n > 1.0 - INTEGER_TOLERANCE:
        n += 1
    elif value - n > INTEGER_TOLERANCE:
        raise _error(f"Non integer value for integer: parameter number {_fmt(value)}", at, code="parameter")
    return n


def _check_range(number: int, at: int) -> None:
    if not 0 < number <= MAX_PARAMETER:
        raise _error(f"Parameter number #{number} out of range 1..{MAX_PARAMETER}", at, code="parameter")


def _check_writable(number: int, at: int) -> None:
    if number in READ_ONLY_NUMBERS:
        raise _error(f"Parameter #{number} is read-only", at, code="parameter")


# -- helpers ------------------------------------------------------------------------------------


def _height(height: int, at: int) -> int:
    if height > MAX_HEIGHT:
        raise _error(f"expression nested too deeply (more than {MAX_HEIGHT} operations)", at)
    return height


def _too_deep(at: int) -> GCodeError:
    return _error(f"expression nested too deeply (more than {MAX_NESTING} levels)", at)


def _error(message: str, at: int, code: str = "expression") -> GCodeError:
    """An error at text[at] (column at + 1)."""
    return GCodeError(message, code=code, column=at + 1)


def _located(error: GCodeError, at: int) -> GCodeError:
    if not error.column:
        error.column = at + 1
    return error


def _found(text: str, pos: int) -> str:
    return f"'{text[pos]}'" if pos < len(text) else "the end of the line"


def _fmt(x: float) -> str:
    return f"{x:.10g}"
