"""The RS274/NGC interpreter: blocks to a canonical stream of moves and events, LinuxCNC semantics.

Each block is checked completely (modal-group conflicts, missing or duplicated words, words
the machine lacks) before anything of it executes, then executed in RS274/NGC's order:
comments and messages, feed mode, feed, S, T, M6, jet (M3/M5 through the machine's M-code
map), auxiliary outputs, M62-M65, dwell, plane, units, kerf compensation, coordinate system,
path control, distance modes, G10/G92, motion, stops. Program units are converted to mm
and mm/min here, at the edge, once. O-word control flow (subroutines, if, while, do,
repeat) moves a program counter over the lines; the first error stops interpretation.
"""

from __future__ import annotations

import bisect
import contextlib
import gc
import math
import threading
import re
import weakref
import time

import numpy as np
from dataclasses import dataclass
from typing import Callable

from . import modal
from .arcs import RADIUS_TOLERANCE_MM, centre_from_radius, spiral_error
from .canon import ARC, LINE, RAPID, Event, Move
from .cutcomments import cut_comment_kind, parse_cut_comment
from .dialect import AUX_BITS, Dialect
from .errors import GCodeError
from .fastpath import FastPath
from .kerf_batch import BatchedKerfCompensator
from .lexer import MAX_WORD_VALUE, Block, OWord, column_of, lex_line
from .modal import INCH_MM
from .params import Parameters
from .program import Attrs, Program, ProgramBuilder
from .source import SourceLines, decode, split_lines

SHORT_LINE = 24  # lines up to this long are lexed once per text (`Interpreter._lex`)
SHORT_LINES_KEPT = 4096
_OLINE = re.compile(r"[ \t]*(?:/[ \t]*)?(?:[nN][\d. \t]*)?[oO]")
_MOTION_CODES = (0, 10, 20, 30, 800)
_AXIS_GROUP0 = (100, 920, 530)  # non-modal codes that take axis words (G53 modifies motion)

# 5211-5219: G92 offsets; 5210: G92 enabled; 5220: current coordinate system; 5221+20k: G54.. origins
P_G92_ENABLED, P_G92, P_CS, P_CS_BASE = 5210, 5211, 5220, 5221


@dataclass
class _Frame:
    label: str
    return_pc: int
    repeat: dict  # repeat line index -> remaining count


def interpret(source: str | bytes, dialect: Dialect | None = None, file: str = "<string>") -> Program:
    """Interpret a whole program; raises GCodeError at the first error."""
    return Interpreter(dialect or Dialect(), file).run(source)


def interpret_file(path: str, dialect: Dialect | None = None) -> Program:
    with open(path, "rb") as f:
        data = f.read()
    return interpret(data, dialect, file=str(path))


class Interpreter:
    """One interpretation of one program."""

    def __init__(self, dialect: Dialect, file: str = "<string>", fast: bool = True) -> None:
        self.d = dialect
        self.file = file
        self.use_fast_path = fast  # off: every line through the general path (for equivalence tests)
        self.builder = ProgramBuilder()
        self.kerf = BatchedKerfCompensator(self.builder, batching=fast)
        self.params = Parameters(_weakly(self._predefined))  # no cycle through the parameters: see `_let_go`
        # modal state
        self.units = 1.0  # mm per program unit
        self.absolute = True
        self.arc_absolute = False
        self.inverse_time = False
        self.motion = 0  # G-code x10 of the modal motion (G0 at start, as LinuxCNC)
        self.cs = 1  # coordinate system 1..9 (G54..G59.3)
        self.cs_origin = [[0.0, 0.0, 0.0] for _ in range(10)]  # mm, index 1..9
        self.cs_rotation = [0.0] * 10  # degrees CCW about the system's origin (G10 L2 R)
        self.g92 = [0.0, 0.0, 0.0]
        self.g92_on = False
        self.pos = list(dialect.start_position_mm)  # machine mm
        self.feed_mm = 0.0  # mm/min: feed is a physical speed, kept across unit changes as LinuxCNC does
        self.speed = 0.0
        self.tool = 0  # loaded tool
        self.next_tool = 0
        self.tolerance = dialect.default_tolerance_mm
        self.jet = False
        self.aux = 0
        self.outputs = 0
        self._attrs = Attrs(self.tolerance, False, 0, 0)
        self.line_no = 0
        self.ended = False
        self.blocks_run = 0
        self.frames: list[_Frame] = []  # subroutine calls in progress
        self._main_repeats: dict[int, int] = {}  # repeat counters outside any subroutine

    # -- driver --------------------------------------------------------------------------
    def run(self, source: str | bytes, progress: Callable[[int, int], None] | None = None) -> Program:
        """Interpret the program; `progress(line, total)` is called now and then on long files."""
        self.progress = progress
        self.lines, self.end = SourceLines(""), 0
        text = decode(source, self.file) if isinstance(source, (bytes, bytearray)) else source
        with _collector_paused():
            return self._run(text)

    def _run(self, text: str) -> Program:
        try:
            self.lines, self.end = split_lines(text, self.file)
            nonblank = re.search(r"\S", self.lines.text)
            self.tape_start = int(np.searchsorted(self.lines.starts, nonblank.start(), side="right")) - 1 if nonblank else -1
            self.tape_marked = self.tape_start >= 0 and self.lines[self.tape_start].strip() == "%"
            if not self.tape_marked:
                self.tape_start = -1
            self.fast = FastPath(self, self.lines)
            self._scan_owords()
            self._execute_lines()
            self.kerf.flush()
        except GCodeError as err:
            err = self.kerf.earlier_error() or err  # a contour still queued comes from earlier lines
            n = err.line or self.line_no
            raise err.located(self.file, n, err.column or 1, self.lines[n - 1] if 0 < n <= len(self.lines) else None) from None
        except RecursionError:
            raise GCodeError("expression or call nesting too deep", code="nesting", file=self.file, line=self.line_no) from None
        finally:
            self._let_go()
        return self.builder.build(self.file, len(self.lines))

    def _let_go(self) -> None:
        """Break the reference cycle through the fast path (it points back here), so that the
        interpreter, its source and its builder's columns (hundreds of MB for a million lines) go by
        reference counting when it is dropped: the planner runs with the cyclic collector frozen
        after a load, and a cycle would keep them for ever."""
        fast = getattr(self, "fast", None)
        if fast is not None:
            fast.ip = None

    def _execute_lines(self) -> None:
        pc, end, lines = 0, self.end, self.lines
        self._next_progress = 16384
        self._next_clock_check, started = 4096, time.monotonic()
        self._cache: dict[int, Block] = {}
        self._by_text: dict[str, Block] = {}
        while pc < end and not self.ended:
            self.line_no = pc + 1
            self.blocks_run += 1
            if self.progress is not None and self.blocks_run >= self._next_progress:
                self.progress(pc + 1, end)
                self._next_progress = self.blocks_run + 16384
            if self.blocks_run > self.d.max_blocks:
                raise GCodeError(
                    f"program executed more than {self.d.max_blocks} blocks: an endless loop?", code="runaway", line=pc + 1, column=1
                )
            if self.blocks_run >= self._next_clock_check:
                self._next_clock_check = self.blocks_run + 4096
                if self.d.max_seconds and time.monotonic() - started > self.d.max_seconds:
                    raise GCodeError(f"program still running after {self.d.max_seconds:g} s of interpretation "
                                     f"({self.blocks_run} blocks): an endless loop?", code="runaway", line=pc + 1, column=1)
            if self.use_fast_path and not self.frames and pc not in self._olines:
                taken = self.fast.run(pc, end)
                if taken:
                    pc += taken
                    self.blocks_run += taken - 1
                    continue
            block = self._cache.get(pc)
            if block is None:
                raw = lines[pc]
                if raw.strip() == "%":
                    if pc != self.tape_start:
                        raise GCodeError("'%' is allowed only as the first and the last line (tape markers)", code="bad-character", line=pc + 1, column=raw.index("%") + 1)
                    pc += 1
                    continue
                block = self._lex(raw, pc + 1)
                if pc in self._olines or self.frames:
                    self._cache[pc] = block
            if block.block_delete and self.d.block_delete:
                pc += 1
                continue
            if block.oword is not None:
                pc = self._oword(block.oword, pc)
                continue
            lane = block.lane
            if lane is None:
                lane = block.lane = self._plain_lane(block)
            if lane:
                self._execute_plain(block, lane)
            else:
                self._execute(block)
            pc += 1
        if self.frames and not self.ended:
            f = self.frames[-1]
            raise GCodeError(f"subroutine o<{f.label}> has no endsub", code="o-word", line=self.line_no, column=1)
        if not self.ended and not self.tape_marked and self.lines:
            body = lines.text[: int(lines.starts[min(end, len(lines))])].rstrip()
            last = max(int(np.searchsorted(lines.starts, len(body) - 1, side="right")) - 1, 0) if body else 0
            raise GCodeError(
                "file ended with no program end (M2 or M30) and no closing '%'", code="program-end", line=last + 1, column=1
            )

    def _lex(self, raw: str, line: int) -> Block:
        """`lex_line`, with short lines a program repeats (M3, M5, G4 P0.3, G40) lexed once: a
        block's words, expressions and plain lane depend on its text alone."""
        if len(raw) > SHORT_LINE:
            return lex_line(raw, line)
        seen = self._by_text.get(raw)
        if seen is None:
            seen = lex_line(raw, line)
            if len(self._by_text) >= SHORT_LINES_KEPT:
                self._by_text.clear()
            self._by_text[raw] = seen
            return seen
        return Block(line, seen.text, seen.norm, seen.block_delete, seen.words, seen.assignments, seen.comments,
                     seen.oword, seen.lane)

    # -- O-words -------------------------------------------------------------------------
    def _scan_owords(self) -> None:
        """Find every O-word line once: subroutine bodies and the partners of if/while/do/repeat."""
        self._olines: dict[int, OWord] = {}
        self._by_label: dict[str, list[tuple[int, str]]] = {}
        self._subs: dict[str, tuple[int, int]] = {}
        starts, text = self.fast.starts, self.fast.text
        stop = int(starts[min(self.end, len(self.lines))])
        found = []  # every o and O before the end (str.find: a scan at memory speed, not a regular expression's)
        for letter in "oO":
            at = text.find(letter, 0, stop)
            while at >= 0:
                found.append(at)
                at = text.find(letter, at + 1, stop)
        for i in sorted(set((np.searchsorted(starts, np.array(found, dtype=np.int64), side="right") - 1).tolist())):
            raw = self.lines[i]
            if not _OLINE.match(raw):
                continue
            self.line_no = i + 1
            ow = lex_line(raw, i + 1).oword
            if ow is None:
                continue
            self._olines[i] = ow
            self._by_label.setdefault(ow.label, []).append((i, ow.keyword))
        self._do_end: dict[int, int] = {}  # `while` closing a `do` -> that `do`
        self._do_close: dict[int, int] = {}  # and back: `do` -> its closing `while`
        # the lines of each label's O-words, sorted: a search from a line starts by bisection, so
        # a label used once per part (o100 if ... in a nest) costs no pass over all its uses
        self._label_lines = {label: [i for i, _ in entries] for label, entries in self._by_label.items()}
        self.oword_steps = 0  # O-word entries looked at by the searches (the linearity tests count them)
        for label, entries in self._by_label.items():
            loops: list[tuple[str, int]] = []
            for i, kw in entries:
                if kw in ("do", "repeat"):
                    loops.append((kw, i))
                elif kw == "while":
                    if loops and loops[-1][0] == "do":
                        self._do_end[i] = loops.pop()[1]
                        self._do_close[self._do_end[i]] = i
                    else:
                        loops.append(("while", i))
                elif kw in ("endwhile", "endrepeat") and loops:
                    loops.pop()
            open_sub = None
            for i, kw in entries:
                if kw == "sub":
                    if open_sub is not None:
                        raise GCodeError(f"o<{label}> sub inside o<{label}> sub", code="o-word", line=i + 1, column=1)
                    if label in self._subs:
                        raise GCodeError(f"subroutine o<{label}> is defined twice (first at line {self._subs[label][0] + 1})", code="o-word", line=i + 1, column=1)
                    open_sub = i
                elif kw == "endsub":
                    if open_sub is None:
                        raise GCodeError(f"o<{label}> endsub without a sub", code="o-word", line=i + 1, column=1)
                    self._subs[label] = (open_sub, i)
                    open_sub = None
            if open_sub is not None:
                raise GCodeError(f"subroutine o<{label}> has no endsub", code="o-word", line=open_sub + 1, column=1)

    def _find(self, label: str, after: int, keywords: tuple[str, ...], what: str) -> tuple[int, str]:
        """The first O-word of `label` after line index `after` whose keyword is in `keywords`."""
        entries = self._by_label.get(label, ())
        for k in range(bisect.bisect_right(self._label_lines.get(label, ()), after), len(entries)):
            i, kw = entries[k]
            self.oword_steps += 1
            if kw in keywords:
                return i, kw
        raise GCodeError(f"o<{label}>: no matching {what}", code="o-word", line=after + 1, column=1)

    def _cond(self, ow: OWord) -> float:
        return ow.args[0].evaluate(self.params)

    def _oword(self, ow: OWord, pc: int) -> int:
        kw, label = ow.keyword, ow.label
        if kw == "sub":
            return self._subs[label][1] + 1  # a definition met in the flow is skipped
        if kw == "call":
            if label not in self._subs:
                raise GCodeError(f"o<{label}> call: no subroutine o<{label}> in this program", code="o-word", line=pc + 1, column=1)
            if len(self.frames) >= self.d.max_call_depth:
                raise GCodeError(f"subroutine calls nested deeper than {self.d.max_call_depth}", code="o-word", line=pc + 1, column=1)
            args = [a.evaluate(self.params) for a in ow.args]
            self.params.push_scope(args)
            self.frames.append(_Frame(label, pc + 1, {}))
            return self._subs[label][0] + 1
        if kw in ("endsub", "return"):
            if not self.frames or self.frames[-1].label != label:
                raise GCodeError(f"o<{label}> {kw} outside subroutine o<{label}>", code="o-word", line=pc + 1, column=1)
            value = ow.args[0].evaluate(self.params) if ow.args else None
            frame = self.frames.pop()
            self.params.pop_scope()
            if value is not None:
                self.params.set_named("_value", value)
                self.params.set_named("_value_returned", 1.0)
            return frame.return_pc
        if kw == "if":
            return self._if_chain(label, pc, ow)
        if kw in ("elseif", "else"):
            return self._find(label, pc, ("endif",), "endif")[0] + 1  # a branch before was taken
        if kw == "endif":
            return pc + 1
        if kw == "do":
            return pc + 1
        if kw == "while":
            if pc in self._do_end:
                return self._do_end[pc] + 1 if self._cond(ow) else pc + 1
            if self._cond(ow):
                return pc + 1
            return self._find(label, pc, ("endwhile",), "endwhile")[0] + 1
        if kw == "endwhile":
            return self._find_back(label, pc, "while")
        if kw == "repeat":
            frame_rep = self._repeats()
            count = int(self._cond(ow))
            if count <= 0:
                return self._find(label, pc, ("endrepeat",), "endrepeat")[0] + 1
            frame_rep[pc] = count
            return pc + 1
        if kw == "endrepeat":
            start = self._find_back(label, pc, "repeat")
            reps = self._repeats()
            remaining = reps.get(start, 1) - 1
            if remaining > 0:
                reps[start] = remaining
                return start + 1
            reps.pop(start, None)
            return pc + 1
        if kw in ("break", "continue"):
            return self._break_continue(label, pc, kw)
        raise GCodeError(f"O-word keyword {kw} is not handled", code="o-word", line=pc + 1, column=1)

    def _if_chain(self, label: str, pc: int, ow: OWord) -> int:
        cur, cond_ow = pc, ow
        while True:
            if cond_ow.args[0].evaluate(self.params):
                return cur + 1
            nxt, kw = self._find(label, cur, ("elseif", "else", "endif"), "elseif, else or endif")
            if kw == "endif":
                return nxt + 1
            if kw == "else":
                return nxt + 1
            cur, cond_ow = nxt, self._olines[nxt]

    def _find_back(self, label: str, pc: int, keyword: str) -> int:
        entries = self._by_label.get(label, ())
        for k in range(bisect.bisect_left(self._label_lines.get(label, ()), pc) - 1, -1, -1):
            self.oword_steps += 1
            if entries[k][1] == keyword:
                return entries[k][0]
        raise GCodeError(f"o<{label}> end{keyword} without {keyword}", code="o-word", line=pc + 1, column=1)

    def _repeats(self) -> dict:
        return self.frames[-1].repeat if self.frames else self._main_repeats

    def _break_continue(self, label: str, pc: int, kw: str) -> int:
        entries = self._by_label.get(label, ())
        start, skw = next(((entries[k][0], entries[k][1])
                           for k in range(bisect.bisect_left(self._label_lines.get(label, ()), pc) - 1, -1, -1)
                           if entries[k][1] in ("while", "do", "repeat") and entries[k][0] not in self._do_end), (-1, ""))
        if start < 0:
            raise GCodeError(f"o<{label}> {kw} outside a loop o<{label}>", code="o-word", line=pc + 1, column=1)
        if skw == "repeat":
            end = self._find(label, pc, ("endrepeat",), "endrepeat")[0]
            if kw == "break":
                self._repeats().pop(start, None)
                return end + 1
            return end  # endrepeat decides about the next round
        if skw == "do":
            end = self._do_close.get(start)
            if end is None:
                raise GCodeError(f"o<{label}> do without its closing while", code="o-word", line=start + 1, column=1)
            return end + 1 if kw == "break" else end
        end = self._find(label, pc, ("endwhile",), "endwhile")[0]
        return end + 1 if kw == "break" else start

    # -- one block -----------------------------------------------------------------------
    def _execute(self, b: Block) -> None:
        params = self.params
        g_codes: list[tuple[int, int]] = []
        m_codes: list[tuple[int, int]] = []
        w: dict[str, float] = {}
        wpos: dict[str, int] = {}
        for word in b.words:
            letter = word.letter
            value = word.value if word.value is not None else word.node.evaluate(params)
            if not -MAX_WORD_VALUE <= value <= MAX_WORD_VALUE:  # also NaN
                raise GCodeError(
                    f"{letter.upper()} word {value:g} is out of range: word values are limited to +-{MAX_WORD_VALUE:g}",
                    code="overflow", column=self._col(b, word.pos),
                )
            if letter == "g":
                code = modal.code_number(value)
                if code is None or code not in modal.G_GROUP:
                    raise GCodeError(f"unknown G code G{value:g}", code="unknown-code", column=self._col(b, word.pos))
                g_codes.append((code, word.pos))
            elif letter == "m":
                if value != int(value) or (int(value) not in modal.M_GROUP and int(value) not in self.d.mcodes):
                    raise GCodeError(f"unknown M code M{value:g}", code="unknown-code", column=self._col(b, word.pos))
                m_codes.append((int(value), word.pos))
            else:
                if letter in w:
                    raise GCodeError(f"multiple {letter.upper()} words on one line", code="duplicate-word", column=self._col(b, word.pos))
                w[letter] = value
                wpos[letter] = word.pos
        if b.assignments:
            targets = [ref.target(params) for ref, _, _ in b.assignments]
            for t in targets:
                if isinstance(t, str) and not params.exists(t):
                    params.declare(t)  # LinuxCNC creates a named parameter when it reads `#<name>=`
            params.apply([(t, node.evaluate(params)) for t, (_, node, _) in zip(targets, b.assignments)])
        self._block, self._wpos = b, wpos
        gg, mm = self._check_groups(b, g_codes, m_codes) if g_codes or m_codes else ({}, {})
        self._check_words(b, w, gg, mm)
        self._run_block(b, w, gg, mm)

    def _plain_lane(self, b: Block) -> tuple | bool:
        """A block that is only a motion: at most one constant G0/G1/G2/G3, axis words of this
        machine, F, and for an arc with its G code on the line I, J, R, P; no comments, no
        assignments, no letter twice. Such a block needs none of the group and word checks
        (they cannot fail on it) and none of the other steps of a block, so `_execute_plain`
        runs it directly: a subroutine's body runs through here once per call.
        Returns (motion code or None, [(letter, word)], {letter: position}) or False."""
        if b.comments or b.assignments or b.block_delete:
            return False
        motion, words, wpos = None, [], {}
        for word in b.words:
            letter = word.letter
            if letter == "g":
                if motion is not None or word.value is None:
                    return False
                motion = modal.code_number(word.value)
                if motion not in (0, 10, 20, 30):
                    return False
                continue
            if letter in wpos or not (letter in self.d.axes or letter in "fijrp"):
                return False
            words.append((letter, word))
            wpos[letter] = word.pos
        if not any(a in wpos for a in modal.AXIS_LETTERS):
            return False
        if any(k in wpos for k in "ijrp") and motion not in (20, 30):
            return False
        return motion, words, wpos

    def _execute_plain(self, b: Block, lane: tuple) -> None:
        """A block `_plain_lane` accepted: its words evaluated, F, the motion mode, the move;
        the same result and the same errors as `_execute`."""
        motion, words, wpos = lane
        params = self.params
        w: dict[str, float] = {}
        for letter, word in words:
            value = word.value if word.value is not None else word.node.evaluate(params)
            if not -MAX_WORD_VALUE <= value <= MAX_WORD_VALUE:  # also NaN
                raise GCodeError(
                    f"{letter.upper()} word {value:g} is out of range: word values are limited to +-{MAX_WORD_VALUE:g}",
                    code="overflow", column=self._col(b, word.pos),
                )
            w[letter] = value
        self._block, self._wpos = b, wpos
        if "f" in w:
            if w["f"] < 0:
                raise self._err(f"negative feed rate F{w['f']:g}", "feed", "f")
            self.feed_mm = w["f"] * self.units
        if motion is not None:
            self.motion = motion
        self._motion(self.motion, w, False)

    def _col(self, b: Block, norm_pos: int) -> int:
        return column_of(b.text, norm_pos)

    def _err(self, message: str, code: str, letter: str | None = None) -> GCodeError:
        b = self._block
        pos = self._wpos.get(letter) if letter else None
        col = self._col(b, pos) if pos is not None else 1
        return GCodeError(message, code=code, line=b.line, column=col)

    def _check_groups(self, b: Block, g_codes, m_codes) -> tuple[dict, dict]:
        """One code per modal group (group 0, the non-modal codes, included): {group: code} for G and M."""
        gg: dict[int, int] = {}
        for code, pos in g_codes:
            if code not in modal.G_SUPPORTED:
                why = modal.G_WHY_NOT.get(code, f"{modal.code_text('g', code)} is not available on this machine")
                if why is not None:
                    raise GCodeError(why, code="unsupported", column=self._col(b, pos))
                continue
            grp = modal.G_GROUP[code]
            if grp in gg:
                raise GCodeError(
                    f"two G codes from the same modal group: {modal.code_text('g', gg[grp])} and {modal.code_text('g', code)}",
                    code="modal-group", column=self._col(b, pos),
                )
            gg[grp] = code
        mm: dict[int, int] = {}
        if len(m_codes) > 5:
            raise GCodeError("too many M codes on one line (at most 5)", code="modal-group", column=self._col(b, m_codes[5][1]))
        for code, pos in m_codes:
            actions = self.d.mcodes.get(code)
            grp = (7 if any(a.startswith("jet") for a in actions) else 8) if actions else modal.M_GROUP[code]
            if grp in mm:
                raise GCodeError(f"two M codes from the same modal group: M{mm[grp]} and M{code}", code="modal-group", column=self._col(b, pos))
            if code not in modal.M_ALWAYS and code not in self.d.mcodes and code != 4:
                raise GCodeError(f"M{code} is not used on this machine", code="unsupported", column=self._col(b, pos))
            if code == 4 and 4 not in self.d.mcodes:
                raise GCodeError("M4 (spindle counter-clockwise) has no meaning on this machine: the jet is M3/M5", code="unsupported", column=self._col(b, pos))
            mm[grp] = code
        return gg, mm

    def _check_words(self, b: Block, w: dict, gg: dict, mm: dict) -> None:
        for letter in w:
            if letter in modal.UNSUPPORTED_AXES or (letter in modal.AXIS_LETTERS and letter not in self.d.axes):
                have = ", ".join(a.upper() for a in self.d.axes)
                raise self._err(f"{letter.upper()} word: the machine has no {letter.upper()} axis (axes: {have})", "axis", letter)
        g0, g1 = gg.get(0), gg.get(1)
        has_axes = any(a in w for a in modal.AXIS_LETTERS)
        if g0 in (100, 920) and g1 is not None and g1 != 800:
            raise self._err(
                f"{modal.code_text('g', g0)} and {modal.code_text('g', g1)} both use axis words: put them on separate lines",
                "modal-group",
            )
        if g1 == 800 and has_axes and g0 not in (100, 920):
            raise self._err("G80 cancels motion: axis words cannot be used with it", "words", next(a for a in modal.AXIS_LETTERS if a in w))
        if len(w) > sum(1 for a in modal.AXIS_LETTERS if a in w) + ("f" in w) + ("s" in w) + ("t" in w):
            self._check_unused(w, gg, mm, has_axes, g0, g1)

    def _check_unused(self, w: dict, gg: dict, mm: dict, has_axes: bool, g0, g1) -> None:
        """A word nothing on the line uses is an error, as in LinuxCNC (`G1 X3 R2` is a typo, not a line)."""
        motion = g1 if g1 is not None else self.motion
        arc = motion in (20, 30) and (has_axes or g1 in (20, 30))
        g7, g13, m5 = gg.get(7), gg.get(13), mm.get(5)
        users = {
            "i": arc, "j": arc, "k": arc, "r": arc or g0 == 100,
            "p": arc or g0 in (40, 100) or g13 == 640 or m5 is not None,
            "q": g13 == 640,
            "l": g0 == 100,
            "d": g7 in (410, 420, 411, 421),
            "h": False,
        }
        for letter, used in users.items():
            if letter in w and not used:
                raise self._err(f"{letter.upper()} word with no G or M code on the line that uses it", "words", letter)

    # -- execution in RS274/NGC order -----------------------------------------------------
    def _run_block(self, b: Block, w: dict, gg: dict, mm: dict) -> None:
        g, m = gg.get, mm.get
        for text in b.comments:
            self._comment(text, b.line, b.text.find(text) + 1 if text else 1)
        fm = g(5)
        if fm is not None:
            self.inverse_time = fm == 930
        # LinuxCNC's order of execution within a block (its documentation, "G-code Order of
        # Execution"): comment, feed mode, F, S, T, M6, the M codes, dwell, plane, units, cutter
        # compensation, coordinate system, path mode, distance modes, G10/G28/G92, motion, stop.
        # So F on a G20/G21 line is still in the old units: `G20 F60` is 60 mm/min after G21.
        if "f" in w:
            if w["f"] < 0:
                raise self._err(f"negative feed rate F{w['f']:g}", "feed", "f")
            self.feed_mm = w["f"] * self.units
        if "s" in w:
            if w["s"] < 0:
                raise self._err(f"negative spindle speed S{w['s']:g}", "words", "s")
            self.speed = w["s"]
        if "t" in w:
            t = w["t"]
            if t != int(t) or t < 0:
                raise self._err(f"tool number T{t:g} must be a whole number >= 0", "tool", "t")
            self.next_tool = int(t)
        if m(6) == 6:
            self.tool = self.next_tool
            self._event("tool", b.line, text=f"nozzle change to T{self.tool}", tool=self.tool)
        elif m(6) == 61:
            raise self._err("M61 is not available: use T and M6", "unsupported")
        if m(7) is not None:
            self._mcode(m(7), b.line)
        if m(8) is not None:
            self._mcode(m(8), b.line)
        for grp_m in (10,):
            if m(grp_m) is not None:
                self._mcode(m(grp_m), b.line)
        if m(5) is not None:
            self._outputs(m(5), w, b.line)
        if g(0) == 40:
            self._dwell(w, b.line)
        if g(6) is not None:
            self.units = INCH_MM if g(6) == 200 else 1.0
            self.kerf.inch = self.units != 1.0
        if g(7) is not None:
            self._kerf(g(7), w, b)
        if g(12) is not None:
            if self.kerf.active:
                raise self._err("cannot change coordinate system with kerf compensation on", "kerf-state")
            self.cs = (540, 550, 560, 570, 580, 590, 591, 592, 593).index(g(12)) + 1
            self.params.set(P_CS, float(self.cs))
        if g(13) is not None:
            self._path_mode(g(13), w)
        if g(3) is not None:
            self.absolute = g(3) == 900
        if g(4) is not None:
            self.arc_absolute = g(4) == 901
        g0 = g(0)
        if g0 == 100:
            self._g10(w)
        elif g0 in (920, 921, 922, 923):
            self._g92(g0, w)
        motion = g(1)
        if motion is not None:
            self.motion = motion
        has_axes = any(a in w for a in modal.AXIS_LETTERS)
        arc_words = [k for k in ("i", "j", "k", "r") if k in w and not (k == "r" and g0 == 100)]
        if g0 not in (100, 920) and has_axes:
            self._motion(self.motion, w, g0 == 530)
        elif arc_words and self.motion in (20, 30):
            self._arc(self.motion == 20, w, tuple(self.pos), tuple(self.pos), b.line)  # reports the missing end point
        elif arc_words:
            letter = arc_words[0]
            raise self._err(f"{letter.upper()} word with no arc motion to use it", "words", letter)
        stop = m(4)
        if stop is not None:
            self._stop(stop, b.line)

    # -- comments, M codes, outputs --------------------------------------------------------
    def _comment(self, text: str, line: int, column: int = 1) -> None:
        head = text.lstrip()[:6].lower()
        if cut_comment_kind(text):
            kind, data = parse_cut_comment(text, self.units, line, max(column, 1))
            self._event(kind, line, text=text.strip(), **data)
        elif head.startswith("msg,"):
            self._event("message", line, text=text.lstrip()[4:])
        elif head.startswith("debug,"):
            self._event("message", line, text=self._substitute(text.lstrip()[6:]))

    def _substitute(self, text: str) -> str:
        from . import expr

        def value(m: re.Match) -> str:
            try:
                ref, _ = expr.parse_parameter_ref(m.group(0).lower().replace(" ", ""), 0)
                return f"{ref.evaluate(self.params):.6f}"
            except GCodeError:
                return m.group(0)

        return re.sub(r"#(?:<[^>]*>|\d+)", value, text)

    def _mcode(self, code: int, line: int) -> None:
        actions = self.d.mcodes.get(code, ())
        if code == 4 and not actions:
            return
        for action in actions:
            name, state = action.rsplit("_", 1)
            on = state == "on"
            if name == "jet":
                if self.jet != on:
                    self.jet = on
                    self._event("jet", line, on=on)
            else:
                bit = 1 << AUX_BITS[name]
                self.aux = (self.aux | bit) if on else (self.aux & ~bit)
        self._refresh_attrs()

    def _outputs(self, code: int, w: dict, line: int) -> None:
        if code in (66, 67, 68):
            raise self._err(f"M{code} (analog/wait on input) is not available on this machine", "unsupported")
        if "p" not in w:
            raise self._err(f"M{code} needs a P word: the output number", "words")
        p = w["p"]
        if p != int(p) or not 0 <= p < self.d.outputs:
            raise self._err(f"M{code} output number P{p:g} must be a whole number 0 to {self.d.outputs - 1}", "words", "p")
        bit = 1 << int(p)
        on = code in (62, 64)
        self.outputs = (self.outputs | bit) if on else (self.outputs & ~bit)
        if code in (64, 65):
            self._event("output", line, text=f"output {int(p)} {'on' if on else 'off'}", output=int(p), on=on)
        self._refresh_attrs()

    def _event(self, kind: str, line: int, **data) -> None:
        self.kerf.event(Event(kind, line, data))

    def _refresh_attrs(self) -> None:
        self._attrs = Attrs(self.tolerance, self.jet, self.aux, self.outputs)

    def _stop(self, code: int, line: int) -> None:
        if code in (2, 30):
            self.kerf.flush()
            self.ended = True
            return
        kind = {0: "stop", 1: "optional_stop", 60: "pallet"}[code]
        self._event(kind, line, text=f"M{code}")

    # -- modes ---------------------------------------------------------------------------
    def _dwell(self, w: dict, line: int) -> None:
        if "p" not in w:
            raise self._err("G4 needs a P word: the dwell time in seconds", "words")
        if w["p"] < 0:
            raise self._err(f"negative dwell time P{w['p']:g}", "words", "p")
        self._event("dwell", line, seconds=w["p"], position=tuple(self.pos), jet=self.jet, aux=self.aux, outputs=self.outputs)

    def _path_mode(self, code: int, w: dict) -> None:
        if code in (610, 611):
            self.tolerance = 0.0
        else:
            p = w.get("p")
            if p is not None and p < 0:
                raise self._err(f"G64 P{p:g}: the tolerance must be >= 0", "words", "p")
            if "q" in w and w["q"] < 0:
                raise self._err(f"G64 Q{w['q']:g}: the tolerance must be >= 0", "words", "q")
            self.tolerance = p * self.units if p else self.d.default_tolerance_mm
        self._refresh_attrs()

    def _kerf(self, code: int, w: dict, b: Block) -> None:
        if code == 400:
            if self.kerf.active:
                self.kerf.stop(b.line, 1)
            return
        if self.kerf.active:
            raise self._err("kerf compensation is already on: turn it off with G40 first", "kerf-state")
        side = 1 if code in (410, 411) else -1
        if code in (411, 421):
            if "d" not in w:
                diameter = 0.0
            else:
                diameter = w["d"] * self.units
                if diameter < 0:
                    raise self._err(f"{modal.code_text('g', code)} D{w['d']:g}: the diameter must be >= 0", "kerf-state", "d")
        else:
            tool = self.tool
            if "d" in w:
                d = w["d"]
                if d != int(d) or d < 0:
                    raise self._err(f"D{d:g}: the nozzle number must be a whole number >= 0", "kerf-state", "d")
                tool = int(d)
            if tool not in self.d.tool_diameters_mm and tool != 0:
                raise self._err(f"D{tool}: nozzle {tool} is not in the nozzle table", "kerf-state", "d" if "d" in w else None)
            diameter = self.d.tool_diameters_mm.get(tool, 0.0)
        self.kerf.start(side, diameter / 2.0, b.line, 1)

    # -- coordinate systems --------------------------------------------------------------
    # machine XY = R(rotation) . (work XY + G92 XY) + origin XY, as LinuxCNC applies them
    def _offset(self, axis: int) -> float:
        """Translation from work to machine coordinates along one axis (valid while unrotated)."""
        off = self.cs_origin[self.cs][axis]
        if self.g92_on:
            off += self.g92[axis]
        return off

    @property
    def rotated(self) -> bool:
        return self.cs_rotation[self.cs] != 0.0

    def _g92v(self) -> list[float]:
        return self.g92 if self.g92_on else [0.0, 0.0, 0.0]

    def _to_machine(self, work: list[float], cs: int | None = None) -> list[float]:
        cs = self.cs if cs is None else cs
        g, o = self._g92v(), self.cs_origin[cs]
        x, y = work[0] + g[0], work[1] + g[1]
        a = math.radians(self.cs_rotation[cs])
        if a:
            c, s_ = math.cos(a), math.sin(a)
            x, y = c * x - s_ * y, s_ * x + c * y
        return [x + o[0], y + o[1], work[2] + g[2] + o[2]]

    def _to_work(self, machine: list[float], cs: int | None = None) -> list[float]:
        cs = self.cs if cs is None else cs
        g, o = self._g92v(), self.cs_origin[cs]
        x, y = machine[0] - o[0], machine[1] - o[1]
        a = math.radians(self.cs_rotation[cs])
        if a:
            c, s_ = math.cos(a), math.sin(a)
            x, y = c * x + s_ * y, -s_ * x + c * y
        return [x - g[0], y - g[1], machine[2] - o[2] - g[2]]

    def _rotate(self, vx: float, vy: float) -> tuple[float, float]:
        """A work-frame vector (I/J increments) in machine orientation."""
        a = math.radians(self.cs_rotation[self.cs])
        if not a:
            return vx, vy
        c, s_ = math.cos(a), math.sin(a)
        return c * vx - s_ * vy, s_ * vx + c * vy

    def _axis_values(self, w: dict) -> list[float | None]:
        return [w[a] * self.units if a in w else None for a in modal.AXIS_LETTERS]

    def _g10(self, w: dict) -> None:
        l_word = w.get("l")
        if l_word not in (2.0, 20.0):
            raise self._err("G10 needs L2 or L20 (L1/L10/L11 tool-table editing is not available)", "words", "l" if "l" in w else None)
        p = w.get("p")
        if p is None or p != int(p) or not 0 <= p <= 9:
            raise self._err("G10 needs P0 to P9: the coordinate system (0 = the current one)", "words", "p" if "p" in w else None)
        cs = int(p) or self.cs
        vals = self._axis_values(w)
        if l_word == 2.0:
            for i, v in enumerate(vals):
                if v is not None:
                    self.cs_origin[cs][i] = v
            if "r" in w:
                self.cs_rotation[cs] = w["r"]
        else:  # L20: the current point gets the given coordinates in system cs
            if "r" in w:
                self.cs_rotation[cs] = w["r"]
            work = self._to_work(self.pos, cs)
            for i, v in enumerate(vals):
                if v is not None:
                    work[i] = v
            g = self._g92v()
            x, y = work[0] + g[0], work[1] + g[1]
            a = math.radians(self.cs_rotation[cs])
            c, s_ = math.cos(a), math.sin(a)
            origin = self.cs_origin[cs]
            if vals[0] is not None or vals[1] is not None or "r" in w:
                origin[0] = self.pos[0] - (c * x - s_ * y)
                origin[1] = self.pos[1] - (s_ * x + c * y)
            if vals[2] is not None:
                origin[2] = self.pos[2] - work[2] - g[2]
        for i in range(3):
            self.params.set(P_CS_BASE + 20 * (cs - 1) + i, self.cs_origin[cs][i] / self.units)
        self.params.set(P_CS_BASE + 20 * (cs - 1) + 9, self.cs_rotation[cs])

    def _g92(self, code: int, w: dict) -> None:
        if code == 920:
            vals = self._axis_values(w)
            if all(v is None for v in vals):
                raise self._err("G92 needs at least one axis word", "words")
            if not self.g92_on:
                self.g92 = [0.0, 0.0, 0.0]
                self.g92_on = True
            rel = self._to_work(self.pos)  # work coordinates without G92 are rel + g92
            base = [rel[i] + self.g92[i] for i in range(3)]
            for i, v in enumerate(vals):
                if v is not None:
                    self.g92[i] = base[i] - v
        elif code == 921:
            self.g92, self.g92_on = [0.0, 0.0, 0.0], False
        elif code == 922:
            self.g92_on = False
        else:  # G92.3: restore from the parameters
            self.g92 = [self.params.get(P_G92 + i) * self.units for i in range(3)]
            self.g92_on = True
        if code != 922:
            for i in range(3):
                self.params.set(P_G92 + i, self.g92[i] / self.units)
        self.params.set(P_G92_ENABLED, 1.0 if self.g92_on else 0.0)

    # -- motion --------------------------------------------------------------------------
    def _target(self, w: dict, machine: bool) -> list[float]:
        if machine:
            return [w[a] * self.units if a in w else self.pos[i] for i, a in enumerate(modal.AXIS_LETTERS)]
        if not self.cs_rotation[self.cs]:
            target = list(self.pos)
            units, absolute = self.units, self.absolute
            origin, g92 = self.cs_origin[self.cs], self.g92 if self.g92_on else None
            for i, a in enumerate(modal.AXIS_LETTERS):
                v = w.get(a)
                if v is not None:
                    v *= units
                    if not absolute:
                        target[i] += v
                    else:  # the translation summed first, as `_offset` does
                        target[i] = v + (origin[i] if g92 is None else origin[i] + g92[i])
            return target
        work = self._to_work(self.pos)
        for i, a in enumerate(modal.AXIS_LETTERS):
            if a in w:
                v = w[a] * self.units
                work[i] = v if self.absolute else work[i] + v
        return self._to_machine(work)

    def _motion(self, motion: int, w: dict, g53: bool) -> None:
        if motion == 800:
            return
        if g53:
            if motion not in (0, 10):
                raise self._err("G53 needs G0 or G1 motion", "modal-group")
            if not self.absolute:
                raise self._err("G53 cannot be used in incremental distance mode (G91)", "modal-group")
            if self.kerf.active:
                raise self._err("G53 cannot be used with kerf compensation on", "kerf-state")
        target = self._target(w, g53)
        start = tuple(self.pos)
        end = tuple(target)
        line = self._block.line
        if motion == 0:
            self.kerf.move(Move(RAPID, start, end, None, False, 0, math.nan, line, 1, self._attrs))
        elif motion == 10:
            feed = self.feed_mm if self.feed_mm > 0 and not self.inverse_time else self._feed_for(w, math.dist(start, end), "G1")
            self.kerf.move(Move(LINE, start, end, None, False, 0, feed, line, 1, self._attrs))
        else:
            self._arc(motion == 20, w, start, end, line)
        self.pos = target

    def _feed_for(self, w: dict, length_mm: float, what: str) -> float:
        if self.inverse_time:
            if "f" not in w:
                raise self._err(f"{what} in inverse-time mode (G93) needs an F word on the same line", "feed")
            if w["f"] <= 0:
                raise self._err(f"{what} in inverse-time mode (G93) with zero F", "feed", "f")
            return length_mm * w["f"]
        if self.feed_mm <= 0:
            raise self._err(f"{what} with zero feed rate: program an F word", "feed", "f" if "f" in w else None)
        return self.feed_mm

    def _arc(self, cw: bool, w: dict, start: tuple, end: tuple, line: int) -> None:
        what = "G2" if cw else "G3"
        if "k" in w:
            raise self._err(f"K word in an XY-plane arc ({what}): use I and J", "words", "k")
        turns = 0
        if "p" in w:
            p = w["p"]
            if p != int(p) or p < 1:
                raise self._err(f"{what} P{p:g}: the number of turns must be a whole number >= 1", "words", "p")
            turns = int(p) - 1
        x0, y0 = start[0], start[1]
        x1, y1 = end[0], end[1]
        if "r" in w:
            if "i" in w or "j" in w:
                raise self._err(f"{what} with both R and I/J: use one form", "words", "r")
            r = w["r"] * self.units
            try:
                cx, cy = centre_from_radius(x0, y0, x1, y1, r, cw)
            except GCodeError as err:
                raise self._err(err.message, err.code, "r") from None
        else:
            if "i" not in w and "j" not in w:
                raise self._err(f"{what} needs I and J (the centre) or R (the radius)", "words")
            i, j = w.get("i", 0.0) * self.units, w.get("j", 0.0) * self.units
            if self.arc_absolute:
                cx, cy, _ = self._to_machine([i, j, 0.0])
            else:
                di, dj = self._rotate(i, j)
                cx, cy = x0 + di, y0 + dj
            r0 = math.hypot(x0 - cx, y0 - cy)
            r1 = math.hypot(x1 - cx, y1 - cy)
            if r0 < RADIUS_TOLERANCE_MM or r1 < RADIUS_TOLERANCE_MM:
                where = "start" if r0 < RADIUS_TOLERANCE_MM else "end"
                raise self._err(f"{what}: the centre is on the {where} point (zero radius arc)", "arc-radius",
                                "i" if "i" in w else "j")
            if spiral_error(r0, r1, self.units != 1.0):
                u = self.units
                raise self._err(
                    f"{what}: radius to the end point {r1 / u:.4f} differs from radius to the start {r0 / u:.4f} "
                    f"(centre {cx / u:.4f}, {cy / u:.4f})",
                    "arc-radius",
                    "x" if "x" in w else "y",
                )
        feed = self._feed_for(w, self._arc_len(x0, y0, x1, y1, cx, cy, cw, turns, end[2] - start[2]), what)
        self.kerf.move(Move(ARC, start, end, (cx, cy), cw, turns, feed, line, 1, self._attrs))

    @staticmethod
    def _arc_len(x0, y0, x1, y1, cx, cy, cw, turns, dz) -> float:
        from .arcs import arc_length, sweep

        return arc_length(math.hypot(x0 - cx, y0 - cy), sweep(x0, y0, x1, y1, cx, cy, cw, turns), dz)

    # -- predefined named parameters -----------------------------------------------------
    def _predefined(self, name: str) -> float | None:
        axis = {"_x": 0, "_y": 1, "_z": 2}.get(name)
        if axis is not None:
            return self._to_work(self.pos)[axis] / self.units
        return {
            "_metric": 1.0 if self.units == 1.0 else 0.0,
            "_imperial": 1.0 if self.units != 1.0 else 0.0,
            "_absolute": 1.0 if self.absolute else 0.0,
            "_incremental": 0.0 if self.absolute else 1.0,
            "_feed": self.feed_mm / self.units,
            "_rpm": self.speed,
            "_motion_mode": self.motion / 10.0,
            "_plane": 17.0,
            "_coord_system": (540, 550, 560, 570, 580, 590, 591, 592, 593)[self.cs - 1] / 10.0,
            "_current_tool": float(self.tool),
            "_selected_tool": float(self.next_tool),
            "_line": float(self.line_no),
            "_call_level": float(len(self.frames)),
        }.get(name)


_pause_lock = threading.Lock()
_pauses = 0  # interpretations running with the collector paused
_resume = False  # the collector was on when the first of them began


@contextlib.contextmanager
def _collector_paused():
    """The cyclic garbage collector off while a program is interpreted.

    An interpretation allocates many small objects that live a while (the moves of contours
    waiting to be offset, lexed blocks, parameters), and each full pass of the collector walks
    every object of the process: a third of a subroutine nest's interpretation time. The
    interpreter makes no reference cycles (the ones it had are broken: `_let_go`, `_weakly`;
    `tests/test_gcode_linear.py` checks that a run leaves nothing for the collector), so nothing
    waits for it meanwhile. Counted, so that interpretations on several threads resume it once,
    after the last one."""
    global _pauses, _resume
    with _pause_lock:
        if _pauses == 0:
            _resume = gc.isenabled()
            gc.disable()
        _pauses += 1
    try:
        yield
    finally:
        with _pause_lock:
            _pauses -= 1
            if _pauses == 0 and _resume:
                gc.enable()


def _weakly(method: Callable) -> Callable:
    """`method`, called through a weak reference to its object (None once that is gone)."""
    ref = weakref.WeakMethod(method)

    def call(*args):
        bound = ref()
        return None if bound is None else bound(*args)
    return call
