"""Condition expressions over named signals, compiled once and evaluated every logic scan.

The machine file writes the conditions of guided procedures (and, later, interlocks) as small
boolean expressions over the signals the logic publishes:

    din.estop_ok
    din.mains_on and plc.mains_on
    pump_pressure >= 1000
    state == READY and not plc.pump_fault

Grammar (comparisons bind tightest, then `not`, `and`, `or`, as in Python):

    condition  := or_expr END
    or_expr    := and_expr ("or" and_expr)*
    and_expr   := not_expr ("and" not_expr)*
    not_expr   := "not" not_expr | comparison
    comparison := "(" or_expr ")" | operand [cmp_op operand]
    operand    := NAME | NUMBER | WORD      (WORD: an all-capital bare word right of == or !=)
    cmp_op     := "==" | "!=" | "<" | "<=" | ">" | ">="

A NAME is a signal key, plain (`homed`) or dotted (`plc.pump_running`), looked up as one flat
key in the mapping given to `Condition.evaluate`. A WORD such as READY or AUTO is an enum value
compared as text: an `enum.Enum` signal compares by its `.name`, anything else by `str()`.

The text is tokenized and parsed once, into nested closures; evaluating does no parsing, so a
scan can afford dozens of conditions every few milliseconds. There is no `eval`: the language
can read signals and compare them, nothing else.

Evaluation is fail-safe: a condition that reads a signal absent from the mapping (or None), or
compares values that cannot be compared (a text with a number by `<`), is false as a whole.
So `not plc.pump_fault` does not pass while the PLC image is missing.
"""

from __future__ import annotations

import difflib
import enum
import operator
import re
from collections.abc import Callable, Iterable, Mapping

MAX_NESTING = 32  # parentheses and `not`s deep; far beyond any sensible condition

_TOKEN = re.compile(
    r"(?P<space>\s+)"
    r"|(?P<number>-?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)"
    r"|(?P<name>[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)"
    r"|(?P<op>==|!=|<=|>=|<|>)"
    r"|(?P<paren>[()])"
)
_ENUM_WORD = re.compile(r"[A-Z][A-Z0-9_]*\Z")
_KEYWORDS = ("and", "or", "not")
_COMPARE: dict[str, Callable[[object, object], bool]] = {
    "==": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge,
}
_OPERATORS = "== != < <= > >="

Signals = Mapping[str, object]
_Fn = Callable[[Signals], object]


class ConditionError(ValueError):
    """A condition is not valid; the message names where it is written, the column and what is wrong."""

    def __init__(self, where: str, reason: str, text: str = "", column: int = 0) -> None:
        self.where, self.reason, self.text, self.column = where, reason, text, column
        at = f"column {column}: " if column else ""
        shown = f" in {text!r}" if text else ""
        super().__init__(f"{where}: {at}{reason}{shown}")


class _Unknown(Exception):
    """Raised inside evaluation when a signal is missing or values cannot be compared."""


class Condition:
    """A compiled condition: `evaluate(signals)` tells whether it holds; `names` are the signals it reads."""

    __slots__ = ("text", "names", "_fn")

    def __init__(self, text: str, names: frozenset[str], fn: _Fn) -> None:
        self.text, self.names, self._fn = text, names, fn

    def evaluate(self, signals: Signals) -> bool:
        """Whether the condition holds for these signal values; false (never an exception) when
        a signal it reads is missing or a comparison does not apply to the values present."""
        try:
            return bool(self._fn(signals))
        except (KeyError, _Unknown):
            return False

    def __repr__(self) -> str:
        return f"Condition({self.text!r})"


def compile_condition(text: str, known_signals: Iterable[str] | None = None, where: str = "condition") -> Condition:
    """Parse `text` into a `Condition`.

    `known_signals` lists the names the condition may read; an entry ending in `.*` (`din.*`)
    admits every name under that prefix. None admits any name (for tests and tools that do
    not know the machine). `where` says where the text was written, for the error message.
    Raises `ConditionError` naming `where`, the 1-based column and what is wrong.
    """
    known = None if known_signals is None else frozenset(known_signals)
    parser = _Parser(text, _tokenize(text, where), known, where)
    fn = parser.parse()
    return Condition(text, frozenset(parser.names), fn)


# -- tokenizer ---------------------------------------------------------------------------------


class _Tok:
    __slots__ = ("kind", "text", "column")

    def __init__(self, kind: str, text: str, column: int) -> None:
        self.kind, self.text, self.column = kind, text, column

    def describe(self) -> str:
        return "the end of the condition" if self.kind == "end" else repr(self.text)


def _tokenize(text: str, where: str) -> list[_Tok]:
    tokens: list[_Tok] = []
    pos = 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            char = text[pos]
            hint = f" (comparisons are {_OPERATORS}; combine with and, or, not)" if char in "=!&|+-*/" else ""
            raise ConditionError(where, f"unexpected character {char!r}{hint}", text, pos + 1)
        kind = m.lastgroup or ""
        if (kind == "name" and m.group() in _KEYWORDS) or kind == "paren":
            kind = m.group()  # keywords and parentheses are their own kinds
        if kind != "space":
            tokens.append(_Tok(kind, m.group(), pos + 1))
        pos = m.end()
    tokens.append(_Tok("end", "", len(text) + 1))
    return tokens


# -- parser: builds closures while it reads ----------------------------------------------------


class _Parser:
    def __init__(self, text: str, tokens: list[_Tok], known: frozenset[str] | None, where: str) -> None:
        self.text, self.tokens, self.known, self.where = text, tokens, known, where
        self.pos = 0
        self.depth = 0  # parentheses and `not`s open, bounded by MAX_NESTING
        self.parens = 0  # parentheses open
        self.names: set[str] = set()

    def parse(self) -> _Fn:
        if self.tokens[0].kind == "end":
            raise self._error("empty condition", self.tokens[0])
        fn = self._or()
        tok = self._peek()
        if tok.kind == ")":
            raise self._error("unbalanced parenthesis: ')' has no matching '('", tok)
        if tok.kind != "end":
            raise self._error(f"unexpected {tok.describe()}; expected and, or, or the end of the condition", tok)
        return fn

    def _peek(self) -> _Tok:
        return self.tokens[self.pos]

    def _next(self) -> _Tok:
        tok = self.tokens[self.pos]
        self.pos += 1
        return tok

    def _error(self, reason: str, tok: _Tok) -> ConditionError:
        return ConditionError(self.where, reason, self.text, tok.column)

    def _or(self) -> _Fn:
        fn = self._and()
        while self._peek().kind == "or":
            self._next()
            fn = _either(fn, self._and())
        return fn

    def _and(self) -> _Fn:
        fn = self._not()
        while self._peek().kind == "and":
            self._next()
            fn = _both(fn, self._not())
        return fn

    def _not(self) -> _Fn:
        if self._peek().kind != "not":
            return self._comparison()
        tok = self._next()
        self._nest(tok)
        inner = self._not()
        self.depth -= 1
        return lambda s: not inner(s)

    def _comparison(self) -> _Fn:
        tok = self._peek()
        if tok.kind == "(":
            self._next()
            self._nest(tok)
            self.parens += 1
            fn = self._or()
            self.depth -= 1
            self.parens -= 1
            close = self._peek()
            if close.kind != ")":
                if close.kind == "end":
                    raise self._error("unbalanced parenthesis: '(' is not closed", tok)
                raise self._error(f"unexpected {close.describe()}; expected and, or, or ')'", close)
            self._next()
            return fn
        left, left_kind = self._operand(after=None)
        if self._peek().kind != "op":
            if left_kind == "number":
                raise self._error("a number alone is not a condition; compare a signal with it, e.g. pump_pressure >= 1000", tok)
            return left
        op = self._next()
        right, right_kind = self._operand(after=op)
        if self._peek().kind == "op":
            raise self._error("comparisons do not chain; join them with and", self._peek())
        return _compare(op.text, left, left_kind, right, right_kind)

    def _operand(self, after: _Tok | None) -> tuple[_Fn, str]:
        """A signal lookup, a number or (right of == and !=) an enum word, with its kind."""
        tok = self._next()
        if tok.kind == "number":
            value = float(tok.text)
            return (lambda s: value), "number"
        if tok.kind == "name":
            if after is not None and after.text in ("==", "!=") and _ENUM_WORD.match(tok.text):
                word = tok.text
                return (lambda s: word), "word"
            self._check_known(tok)
            self.names.add(tok.text)
            return _lookup(tok.text), "name"
        if tok.kind == ")" and not self.parens:
            raise self._error("unbalanced parenthesis: ')' has no matching '('", tok)
        if after is not None:
            word = ", a number or a word such as READY" if after.text in ("==", "!=") else " or a number"
            raise self._error(f"expected a signal name{word} after {after.text!r}, found {tok.describe()}", tok)
        prev = self.tokens[self.pos - 2].text if self.pos >= 2 else ""
        what = f"after {prev!r}" if prev in (*_KEYWORDS, "(") else "here"
        raise self._error(f"expected a signal name, a number or '(' {what}, found {tok.describe()}", tok)

    def _nest(self, tok: _Tok) -> None:
        self.depth += 1
        if self.depth > MAX_NESTING:
            raise self._error(f"nested more than {MAX_NESTING} deep", tok)

    def _check_known(self, tok: _Tok) -> None:
        if self.known is None or tok.text in self.known:
            return
        if "." in tok.text and tok.text.rsplit(".", 1)[0] + ".*" in self.known:
            return
        exact = sorted(k for k in self.known if not k.endswith(".*"))
        close = difflib.get_close_matches(tok.text, exact, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise self._error(f"unknown signal {tok.text!r}{hint}; known: {describe_known(self.known)}", tok)


def describe_known(known: Iterable[str]) -> str:
    """The known signal names, short: every dotted family as `prefix.*`, then the plain names."""
    prefixes = sorted({k.rsplit(".", 1)[0] + ".*" for k in known if "." in k})
    plain = sorted(k for k in known if "." not in k)
    return ", ".join(prefixes + plain) or "(none)"


# -- closures ----------------------------------------------------------------------------------


def _lookup(name: str) -> _Fn:
    def get(s: Signals) -> object:
        value = s[name]  # KeyError: missing, the condition is false
        if value is None:
            raise _Unknown(name)
        return value

    return get


def _either(a: _Fn, b: _Fn) -> _Fn:
    return lambda s: a(s) or b(s)


def _both(a: _Fn, b: _Fn) -> _Fn:
    return lambda s: a(s) and b(s)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, enum.Enum)


def _as_text(value: object) -> str:
    return value.name if isinstance(value, enum.Enum) else str(value)


def _compare(op: str, left: _Fn, left_kind: str, right: _Fn, right_kind: str) -> _Fn:
    """A comparison specialised at compile time for the operand kinds it meets."""
    cmp = _COMPARE[op]
    if right_kind == "word":  # enum value: compare as text
        return lambda s: cmp(_as_text(left(s)), right(s))
    if right_kind == "number" and left_kind == "name":  # the usual case: pump_pressure >= 1000

        def against_number(s: Signals) -> bool:
            value = left(s)
            if not _is_number(value):
                raise _Unknown(value)
            return cmp(value, right(s))

        return against_number

    def general(s: Signals) -> bool:
        a, b = left(s), right(s)
        if _is_number(a) and _is_number(b):
            return cmp(a, b)
        if op in ("==", "!="):
            return cmp(_as_text(a), _as_text(b))
        raise _Unknown(op)

    return general
