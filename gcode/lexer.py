"""Lexer: one source line to a `Block` of words, parameter settings, comments and an O-word.

LinuxCNC reads a line by dropping spaces and tabs and folding case everywhere outside
comments, so `g 1 x 1 0` is `G1 X10`; comments keep their text. Values are parsed once into
expression nodes (`gcode.expr`), plain numbers into constants. A line made only of
letter-number pairs (most CAM output) takes a regular-expression fast path.
Positions are kept in the normalised text and mapped back to source columns only when an
error is reported.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from . import expr
from .errors import GCodeError

WORD_LETTERS = frozenset("abcdfghijklmpqrstuvwxyz")  # N and O are handled apart
O_KEYWORDS = (
    "endsub", "sub", "call", "return", "elseif", "else", "endif", "if",
    "endwhile", "while", "do", "endrepeat", "repeat", "break", "continue",
)
_SIMPLE = re.compile(r"(?:[abcdfghijklmpqrstuvwxyz][-+]?(?:\d+\.?\d*|\.\d+))+")
_PAIR = re.compile(r"([a-z])([-+]?(?:\d+\.?\d*|\.\d+))")
MAX_O_ARGS = 30
# A word's value beyond any machine (1000 km, 31 years of dwell), and small enough that lengths, arc
# centres and turn counts computed from it stay finite and fit their columns.
MAX_WORD_VALUE = 1e9
_DIGITS = frozenset("0123456789")  # str.isdigit() also takes '²' and other digits int() refuses


@dataclass(slots=True)
class Word:
    letter: str
    value: float | None  # the number when the value is a plain constant
    node: object  # expression node (None when `value` is a constant)
    pos: int  # position in the normalised text


@dataclass(slots=True)
class OWord:
    label: str  # "100" or "name" (from o100 / o<name>)
    keyword: str
    args: list  # expression nodes: call arguments, or the condition / count / return value
    pos: int


@dataclass(slots=True)
class Block:
    """One source line, lexed."""

    line: int
    text: str
    norm: str
    block_delete: bool = False
    words: list[Word] = field(default_factory=list)
    assignments: list = field(default_factory=list)  # (ParamRef, node, pos)
    comments: list[str] = field(default_factory=list)
    oword: OWord | None = None
    lane: object = None  # the interpreter's plain-motion lane for this block (None: not yet classified)


def column_of(raw: str, norm_pos: int) -> int:
    """1-based source column of the character at `norm_pos` in the normalised line."""
    n, in_comment = 0, False
    for col, ch in enumerate(raw, start=1):
        if in_comment:
            if ch == ")":
                in_comment = False
            continue
        if ch == "(":
            in_comment = True
            continue
        if ch == ";":
            break
        if ch in " \t":
            continue
        if n == norm_pos:
            return col
        n += 1
    return len(raw.rstrip()) + 1


def normalise(raw: str) -> tuple[str, list[str]]:
    """(text outside comments, lower-case, no blanks; comment texts). Raises on a bad comment."""
    if "(" not in raw and ";" not in raw:
        if ")" in raw:
            raise GCodeError("')' without a matching '('", code="comment", column=raw.index(")") + 1)
        return raw.replace(" ", "").replace("\t", "").lower(), []
    out, comments, i, n = [], [], 0, len(raw)
    while i < n:
        ch = raw[i]
        if ch == "(":
            j = raw.find(")", i + 1)
            if j < 0:
                raise GCodeError("comment '(' is not closed on this line", code="comment", column=i + 1)
            inner = raw.find("(", i + 1, j)
            if inner >= 0:
                raise GCodeError("nested comment: '(' inside a comment", code="comment", column=inner + 1)
            comments.append(raw[i + 1 : j])
            i = j + 1
            continue
        if ch == ";":
            comments.append(raw[i + 1 :])
            break
        if ch == ")":
            raise GCodeError("')' without a matching '('", code="comment", column=i + 1)
        if ch not in " \t":
            out.append(ch)
        i += 1
    return "".join(out).lower(), comments


def lex_line(raw: str, line: int) -> Block:
    """Lex one line; GCodeError positions are filled in (column from the source)."""
    try:
        norm, comments = normalise(raw)
    except GCodeError as err:  # columns are already source columns here
        raise err.located("<string>", line, err.column, raw)
    block = Block(line, raw, norm, comments=comments)
    if _SIMPLE.fullmatch(norm):
        block.words = [Word(m.group(1), float(m.group(2)), None, m.start()) for m in _PAIR.finditer(norm)]
        return block
    try:
        _parse(block)
    except GCodeError as err:
        err.column = column_of(raw, max(err.column - 1, 0))
        raise err.located("<string>", line, err.column, raw) from None
    return block


def _parse(block: Block) -> None:
    text, pos, n = block.norm, 0, len(block.norm)
    if pos < n and text[pos] == "/":
        block.block_delete = True
        pos += 1
    if pos < n and text[pos] == "n":
        pos = _skip_line_number(text, pos + 1)
    if pos < n and text[pos] == "o":
        block.oword = _parse_oword(text, pos)
        return
    while pos < n:
        ch = text[pos]
        if ch == "#":
            ref, p = expr.parse_parameter_ref(text, pos)
            if p >= n or text[p] != "=":
                raise GCodeError("parameter setting needs '=' after the parameter", code="parameter", column=p + 1)
            value, p2 = expr.parse_real_value(text, p + 1)
            block.assignments.append((ref, value, pos))
            pos = p2
        elif ch in WORD_LETTERS:
            value, p = expr.parse_real_value(text, pos + 1)
            const = getattr(value, "const", None)
            block.words.append(Word(ch, const, None if const is not None else value, pos))
            pos = p
        elif ch == "n":
            raise GCodeError("N line number must be the first word of a line", code="line-number", column=pos + 1)
        elif ch == "o":
            raise GCodeError("O-word must start the line", code="o-word", column=pos + 1)
        elif ch == "/":
            raise GCodeError("block delete '/' must start the line", code="syntax", column=pos + 1)
        else:
            raise GCodeError(f"bad character {ch!r} used", code="bad-character", column=pos + 1)


def _skip_line_number(text: str, pos: int) -> int:
    start = pos
    while pos < len(text) and (text[pos] in _DIGITS or text[pos] == "."):
        pos += 1
    if pos == start:
        raise GCodeError("N must be followed by a line number", code="line-number", column=start)
    return pos


def _parse_oword(text: str, pos: int) -> OWord:
    start = pos
    pos += 1
    if pos < len(text) and text[pos] == "<":
        end = text.find(">", pos)
        if end < 0:
            raise GCodeError("O-word name is missing its closing '>'", code="o-word", column=pos + 1)
        label = text[pos + 1 : end]
        if not label:
            raise GCodeError("O-word name is empty", code="o-word", column=pos + 1)
        pos = end + 1
    else:
        digits = pos
        while pos < len(text) and text[pos] in _DIGITS:
            pos += 1
        if pos == digits:
            raise GCodeError("O must be followed by a number or a <name>", code="o-word", column=pos + 1)
        label = str(int(text[digits:pos]))
    keyword = next((k for k in O_KEYWORDS if text.startswith(k, pos)), None)
    if keyword is None:
        rest = text[pos : pos + 12] or "end of line"
        raise GCodeError(f"unknown O-word keyword at {rest!r} (expected sub, call, if, while, ...)", code="o-word", column=pos + 1)
    pos += len(keyword)
    args = []
    while pos < len(text):
        if text[pos] != "[":
            raise GCodeError(f"O-word {keyword} takes bracketed expressions; found {text[pos]!r}", code="o-word", column=pos + 1)
        node, pos = expr.parse_expression(text, pos)
        args.append(node)
    if keyword == "call" and len(args) > MAX_O_ARGS:
        raise GCodeError(f"O-word call has {len(args)} arguments; at most {MAX_O_ARGS}", code="o-word", column=start + 1)
    if keyword in ("if", "elseif", "while", "repeat") and len(args) != 1:
        raise GCodeError(f"O-word {keyword} needs exactly one [condition]", code="o-word", column=pos + 1)
    if keyword in ("sub", "else", "endif", "endwhile", "do", "endrepeat", "break", "continue") and args:
        raise GCodeError(f"O-word {keyword} takes no arguments", code="o-word", column=start + 1)
    return OWord(label, keyword, args, start)
