"""Fast path: runs of plain motion lines interpreted in bulk with numpy.

Most of a CAM program is lines like `G1 X12.5 Y7.25` or `X13 Y8 F1200`: one motion code
(G0-G3) at most, then X/Y/Z/I/J/R/F words with plain numbers, no parameters or expressions, and
no comments but whole-line ones that do nothing (a part's name). Outside subroutines and inverse-time feed, such a run is interpreted as arrays: the words are cut out of the text by two regular expressions,
modal values (motion code, feed, coordinates) are carried forward with an index trick,
offsets and units applied, arc centres and radius checks computed for all arcs at once.
With kerf compensation on, the moves computed in bulk then pass one by one through the
compensator, exactly as the general path would hand them over.

The result is exactly what the general path gives. Anything unusual in a line (a duplicated
word, zero feed, an arc whose end is off its radius, an axis the machine lacks, an R arc
that cannot reach) ends the run before that line, and the general path interprets it and
reports the error with its exact wording and column.
"""

from __future__ import annotations

import math
import re
import warnings
from typing import TYPE_CHECKING

import numpy as np

from .canon import ARC, DWELL, LINE, RAPID, Move
from . import kerf_bulk
from .dialect import AUX_BITS
from .lexer import MAX_WORD_VALUE
from .modal import INCH_MM

if TYPE_CHECKING:
    from .interp import Interpreter
    from .source import SourceLines

# A character outside these ends a plain run; the run's structure is then checked in bulk.
_NOT_PLAIN = re.compile(r"[^ \t\n0-9.+\-nNgGxXyYzZfFiIjJrRmMpPdD]")
# A line that is only a comment, and not one that does something (MSG, DEBUG, PRINT, LOG...,
# a word and a comma): a CAM post writes one per part; it stays inside a bulk run as a blank line.
_QUIET_COMMENT = re.compile(r"[ \t]*\((?![ \t]*[A-Za-z]+[ \t]*,)[^()\n]*\)[ \t]*")
_QUIET_COMMENT_LINES = re.compile(r"(?m)^[ \t]*\((?![ \t]*[A-Za-z]+[ \t]*,)[^()\n]*\)[ \t]*$")
_LETTERS_TO_SPACES = str.maketrans({c: " " for c in "ngxyzfijrmpd\n\t"})
_KERF_CODES = (40.0, 41.0, 42.0, 41.1, 42.1)
MIN_RUN = 8  # shorter runs are not worth the set-up: the general path takes them
MAX_RUN = 20_000  # bounded arrays per run: memory stays flat, the set-up is still negligible
WINDOW0 = 64  # lines a run looks at after a line the general path took; doubled while runs fill it
_TWO_PI = 2.0 * math.pi


class FastPath:
    """Bulk interpretation of plain-motion runs for one `Interpreter`.

    The work is linear in the program whatever its shape: a run looks at a window of lines no
    larger than twice what the previous run took (at least WINDOW0, at most MAX_RUN), so a line
    that needs the general path costs that line and a bounded window, never a pass over the
    rest of the program (converting up to MAX_RUN lines again after every such line made a nest
    whose parts each have one quadratic: 600 parts 12 s)."""

    def __init__(self, interp: "Interpreter", lines: "SourceLines") -> None:
        self.ip = interp
        self.text = lines.text
        self.starts = lines.starts
        self.skip_until = 0  # lines before this index were judged not worth a bulk run
        self.window = WINDOW0
        self.converted = 0  # characters converted in bulk: the fast path's work, for the linearity tests
        self.taken = 0  # lines interpreted in bulk (the rest went through the general path)
        self.failed_at: int | None = None  # set by _bulk: the first line of its run the general path must take
        self.cut_short = False  # set by _bulk: the run ended at a kerf stretch still open at the window's end

    def run(self, pc: int, end: int) -> int:
        """Interpret lines pc.. in bulk if they start a long enough plain run; return how many were taken."""
        ip = self.ip
        if pc < self.skip_until or ip.inverse_time or ip.frames or ip.rotated:
            return 0
        window, shrinking = self.window, False
        while True:
            stop = min(end, pc + window)
            run_end, quiet = self._plain_until(pc, stop)
            if run_end - pc < MIN_RUN:
                if run_end < stop:  # no run starts before the line that is not plain, nor on it
                    self.skip_until = run_end + 1
                return 0
            chunk = self.text[self.starts[pc] : self.starts[run_end]]
            if quiet:  # whole-line comments that do nothing: blank lines to the bulk path
                chunk = _QUIET_COMMENT_LINES.sub("", chunk)
            if not chunk.isascii():
                self.skip_until = run_end
                return 0
            self.failed_at, self.cut_short = None, False
            self.converted += len(chunk)
            taken = self._bulk(pc, run_end - pc, chunk.lower())
            if taken:
                self.window = min(MAX_RUN, max(WINDOW0, 2 * taken))
                self.taken += taken
                return taken
            if self.cut_short and run_end == stop < end and window < MAX_RUN and not shrinking:
                window = min(MAX_RUN, 2 * window)  # a contour longer than the window: look further
                continue
            self.window = WINDOW0
            if self.failed_at is not None:  # the general path takes the lines up to that one
                self.skip_until = pc + self.failed_at + 1
            elif run_end - pc >= 2 * MIN_RUN:  # a line somewhere breaks the plain form: the first half
                window, shrinking = (run_end - pc) // 2, True
                continue
            else:
                self.skip_until = pc + 1
            return 0

    def _plain_until(self, pc: int, stop: int) -> tuple[int, bool]:
        """The first line in pc..stop that is not plain (stop when none), and whether plain
        lines before it include quiet whole-line comments."""
        text, starts = self.text, self.starts
        pos, end_pos, quiet = int(starts[pc]), int(starts[stop]), False
        while (m := _NOT_PLAIN.search(text, pos, end_pos)) is not None:
            line = int(np.searchsorted(starts, m.start(), side="right")) - 1
            line_end = int(starts[line + 1]) - 1  # its newline
            if text[m.start()] != "(" or not _QUIET_COMMENT.fullmatch(text, int(starts[line]), line_end):
                return line, quiet
            quiet, pos = True, line_end + 1
        return stop, quiet

    # -----------------------------------------------------------------------------------
    def _bulk(self, first: int, nl: int, low: str) -> int:
        ip = self.ip
        low = low.replace(" ", "")
        raw = np.frombuffer(low.encode("ascii"), dtype=np.uint8)
        letter_pos = np.flatnonzero((raw >= 97) & (raw <= 122))
        letters = raw[letter_pos]
        line_of = np.searchsorted(np.flatnonzero(raw == 10), letter_pos)
        # the shape letter-number letter-number ...: every letter is followed by a number, every
        # number follows a letter (a line such as "x1.2.3" or "12 x1" goes to the general path)
        after = raw[np.minimum(letter_pos + 1, len(raw) - 1)]
        starts_number = ((after >= 48) & (after <= 57)) | (after == 43) | (after == 45) | (after == 46)
        number_start = np.zeros(len(raw) + 1, dtype=bool)
        digitish = ((raw >= 48) & (raw <= 57)) | (raw == 43) | (raw == 45) | (raw == 46)
        number_start[1:][digitish] = True
        number_start[1:][1:][digitish[1:] & digitish[:-1]] = False  # only the first char of each number
        first_chars = np.flatnonzero(number_start[1:])
        if not starts_number.all() or len(first_chars) != len(letter_pos) or not np.array_equal(first_chars, letter_pos + 1):
            return 0
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            try:
                values = np.fromstring(low.translate(_LETTERS_TO_SPACES), dtype=np.float64, sep=" ")
            except (ValueError, DeprecationWarning):
                return 0
        if len(values) != len(letters):
            return 0
        # N (line number) must be the first word of its line
        is_n = letters == ord("n")
        if is_n.any():
            k = np.flatnonzero(is_n)
            if (k > 0).any() and (line_of[k[k > 0] - 1] == line_of[k[k > 0]]).any():
                return 0
        keep = ~is_n
        letters, line_of, values = letters[keep], line_of[keep], values[keep]
        # kerf G codes are a group of their own: one line may carry G41 and G1
        letters = letters.copy()
        letters[(letters == ord("g")) & np.isin(values, _KERF_CODES)] = ord("k")
        letters[(letters == ord("g")) & ((values == 20.0) | (values == 21.0))] = ord("u")  # units, a group too
        limit = nl  # lines [0, limit) are taken; lowered at the first line that needs the general path
        limit = _first(np.bincount(line_of[~(np.abs(values) <= MAX_WORD_VALUE)], minlength=nl) > 0, limit)  # refused there

        def column(ch: str) -> np.ndarray:
            nonlocal limit
            sel = letters == ord(ch)
            ids = line_of[sel]
            out = np.full(nl, np.nan)
            if ids.size:
                counts = np.bincount(ids, minlength=nl)
                dup = np.flatnonzero(counts > 1)
                if dup.size:
                    limit = min(limit, int(dup[0]))
                out[ids] = values[sel]
            return out

        g, f, mc, pw = column("g"), column("f"), column("m"), column("p")
        kc, dw, uc = column("k"), column("d"), column("u")
        # mm per program unit after each line's G20/G21 (the motion on that line uses it), and
        # before it: F is set before the units change (LinuxCNC's order of execution)
        units = _ffill(np.where(uc == 20.0, INCH_MM, np.where(uc == 21.0, 1.0, np.nan)), ip.units)
        units_before = np.concatenate(([ip.units], units[:-1]))
        limit = _first(~np.isnan(dw) & ~np.isin(kc, (41.0, 42.0, 41.1, 42.1)), limit)  # D only with G41/G42
        if not ip.kerf.idle:  # the per-move compensator is mid-contour: leave it alone
            limit = _first(~np.isnan(kc) | ~np.isnan(uc), limit)
        is_dwell = g == 4.0
        limit = _first(~np.isnan(g) & ~np.isin(g, (0.0, 1.0, 2.0, 3.0, 4.0)), limit)  # other G codes
        limit = _first(~np.isnan(mc) & ~np.isin(mc, list(ip.d.mcodes)), limit)  # only the machine's jet/aux M codes
        ax = [column(a) for a in "xyz"]
        wi, wj, wr = column("i"), column("j"), column("r")
        has_axis = ~(np.isnan(ax[0]) & np.isnan(ax[1]) & np.isnan(ax[2]))
        has_ij = ~(np.isnan(wi) & np.isnan(wj))
        has_r = ~np.isnan(wr)
        # G4 P<seconds> alone (with M codes at most); P anywhere else (arc turns) goes the general way
        limit = _first(is_dwell & (has_axis | has_ij | has_r | np.isnan(pw) | (pw < 0.0)), limit)
        limit = _first(~np.isnan(pw) & ~is_dwell, limit)
        if "z" not in ip.d.axes:
            limit = _first(~np.isnan(ax[2]), limit)
        motion = _ffill(np.where(is_dwell, np.nan, g), ip.motion / 10.0)
        feed = _ffill(f * units_before, ip.feed_mm)  # mm/min
        is_arc = has_axis & (motion >= 2.0)
        # words without a motion to use them, arcs without a centre, mixed forms, zero feed
        limit = _first((has_ij | has_r) & ~is_arc, limit)
        limit = _first(is_arc & (has_ij == has_r), limit)
        limit = _first(has_axis & (motion >= 1.0) & (feed <= 0.0), limit)
        stretches = None
        if limit >= MIN_RUN and not np.isnan(kc[:limit]).all():
            limit, stretches = self._stretches(limit, kc, dw, has_axis, motion, mc, is_dwell, uc, units)
        if limit < MIN_RUN:
            self.failed_at = limit
            return 0
        # end points in machine mm
        ends = np.empty((nl, 3))
        for i in range(3):
            col = ax[i] * units
            if ip.absolute:
                off = ip._offset(i)
                ends[:, i] = _ffill(col, ip.pos[i] - off) + off
            else:
                ends[:, i] = ip.pos[i] + np.cumsum(np.nan_to_num(col))
        idx = np.flatnonzero(has_axis[:limit])
        starts = np.empty((len(idx), 3))
        if len(idx):
            starts[0] = ip.pos
            starts[1:] = ends[idx[:-1]]
        e = ends[idx]
        kind = np.where(motion[idx] == 0.0, RAPID, np.where(motion[idx] == 1.0, LINE, ARC)).astype(np.uint8)
        arc = kind == ARC
        cw = motion[idx] == 2.0
        center = np.zeros((len(idx), 2))
        if arc.any():
            bad = self._arcs(idx, arc, cw, starts, e, center, wi, wj, wr, units)
            if bad is not None:
                limit = int(idx[bad])
                if limit < MIN_RUN:
                    self.failed_at = limit
                    return 0
                keep_seg = idx < limit
                idx, kind, cw, starts, e, center = idx[keep_seg], kind[keep_seg], cw[keep_seg], starts[keep_seg], e[keep_seg], center[keep_seg]
        fmm = np.where(kind == RAPID, np.nan, feed[idx])
        seg_lines = idx
        if stretches is not None and len(idx):
            comp, limit = self._compensate(stretches, limit, idx, kind, starts, e, center, cw)
            if comp is None:
                self.failed_at = limit
                return 0
            keep_seg = idx < limit
            fmm = fmm[keep_seg][comp.source]
            seg_lines = idx[keep_seg][comp.source]
            kind, starts, e, center, cw = comp.kind, comp.start, comp.end, comp.center, comp.cw
        length, lo, hi = piece_geometry(kind, starts, e, center, cw)
        dwells = np.flatnonzero(is_dwell[:limit])
        if not ip.kerf.idle:
            self._through_kerf(first, limit, mc, dwells, pw, ends, idx, kind, starts, e, center, cw, fmm)
        else:
            self._emit(first, limit, mc, dwells, pw, ends, seg_lines, kind, starts, e, center, cw, fmm, length, lo, hi)
        # modal state after the run
        last = limit - 1
        ip.motion = int(round(motion[last] * 10))
        ip.feed_mm = float(feed[last])
        ip.units = float(units[last])
        ip.kerf.inch = ip.units != 1.0
        ip.pos = [float(v) for v in ends[last]]
        return limit

    def _stretches(self, limit, kc, dw, has_axis, motion, mc, is_dwell, uc, units) -> tuple[int, list]:
        """Find the compensated stretches (G41/G42 entry line .. G40 exit line) that the bulk
        compensator can take; the run ends before the first one it cannot. Returns (limit, stretches)
        with stretches as (entry line, exit line, side, radius mm)."""
        ip = self.ip
        out, open_ = [], None
        events = np.concatenate(([0], np.cumsum(~np.isnan(mc[:limit]) | is_dwell[:limit]))).tolist()
        axis_l, motion_l, dw_l = has_axis.tolist(), motion.tolist(), dw.tolist()
        for L in np.flatnonzero(~np.isnan(kc[:limit])).tolist():
            code = kc[L]
            if code == 40.0:
                if open_ is None:
                    continue  # G40 with compensation off does nothing
                entry, side, radius = open_
                if not axis_l[L] or motion_l[L] >= 2.0:
                    return entry, out  # a bare G40 or an arc exit: the per-move compensator decides
                if events[L + 1] != events[entry]:
                    return entry, out  # events inside the contour keep their place there
                if not np.isnan(uc[entry + 1 : L + 1]).all():
                    return entry, out  # units changed inside the contour: the per-move path decides
                out.append((entry, L, side, radius))
                open_ = None
                continue
            if open_ is not None or not axis_l[L]:
                return (open_[0] if open_ is not None else L), out
            side = 1 if code in (41.0, 41.1) else -1
            d = dw_l[L]
            if code in (41.1, 42.1):
                diameter = 0.0 if d != d else d * units[L]
            else:
                tool = ip.tool if d != d else d
                if tool != int(tool) or tool < 0 or int(tool) not in ip.d.tool_diameters_mm:
                    return L, out
                diameter = ip.d.tool_diameters_mm[int(tool)]
            if diameter <= 0.0:
                return L, out  # no or negative kerf: the per-move path knows what that means
            open_ = (L, side, diameter / 2.0)
        if open_ is not None:
            self.cut_short = limit == len(kc)  # open at the window's end: a longer window may close it
            return open_[0], out
        return limit, out

    def _compensate(self, stretches, limit, idx, kind, starts, e, center, cw):
        """Kerf-compensate the stretches of the run; the run ends before one the bulk compensator cannot do."""
        while True:
            for entry, exit_line, _, _ in stretches:
                if entry < limit <= exit_line:
                    limit = entry  # a run never ends inside a contour
            if limit < MIN_RUN:
                return None, limit
            keep = idx < limit
            lines = idx[keep]
            closed = [st for st in stretches if st[1] < limit]
            entries = np.array([st[0] for st in closed], dtype=np.int64)
            exits = np.array([st[1] for st in closed], dtype=np.int64)
            k = np.searchsorted(entries, lines, side="right") - 1  # the last stretch entered at or before each line
            inside = (k >= 0) & (lines <= exits[np.maximum(k, 0)]) if len(closed) else np.zeros(len(lines), dtype=bool)
            stretch = np.where(inside, k, -1)
            side = np.where(inside, np.array([st[2] for st in closed] or [0.0])[np.maximum(k, 0)], 0.0)
            radius = np.where(inside, np.array([st[3] for st in closed] or [0.0])[np.maximum(k, 0)], 0.0)
            first_ = inside & (lines == entries[np.maximum(k, 0)]) if len(closed) else inside
            exit_ = inside & (lines == exits[np.maximum(k, 0)]) if len(closed) else inside
            comp, bad = kerf_bulk.compensate(
                kind[keep], starts[keep], e[keep], center[keep], cw[keep], stretch, side, radius, first_, exit_
            )
            if bad is None:
                return comp, limit
            limit = int(lines[bad])
            if limit < MIN_RUN:
                return None, limit

    def _outputs_by_line(self, limit: int, mc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Jet state, aux bits and jet-off events per line after each line's M codes (machine M-code map)."""
        ip = self.ip
        jet_set = np.full(limit, np.nan)
        bits = {b: np.full(limit, np.nan) for b in AUX_BITS.values()}
        for code, actions in ip.d.mcodes.items():
            at = mc[:limit] == code
            if not at.any():
                continue
            for action in actions:
                name, state = action.rsplit("_", 1)
                target = jet_set if name == "jet" else bits[AUX_BITS[name]]
                target[at] = 1.0 if state == "on" else 0.0
        jet = _ffill(jet_set, float(ip.jet)).astype(bool)
        aux = np.zeros(limit, dtype=np.uint32)
        for b, col in bits.items():
            aux |= _ffill(col, float(ip.aux >> b & 1)).astype(np.uint32) << b
        before = np.concatenate(([ip.jet], jet[:-1]))
        jet_off = (jet_set == 0.0) & before  # the general path emits an event only on a change
        return jet, aux, jet_off

    def _emit(self, first, limit, mc, dwells, pw, ends, idx, kind, starts, e, center, cw, fmm, length, lo, hi) -> None:
        """No kerf compensation: moves and dwells go to the program builder as arrays."""
        ip = self.ip
        ip.kerf.drain()  # the general path's contours still queued go first
        jet_l, aux_l, jet_off = self._outputs_by_line(limit, mc)
        order = np.argsort(np.concatenate((idx, dwells)), kind="stable")
        nm, nd = len(idx), len(dwells)
        seg_line = np.concatenate((idx, dwells))[order]
        cat = lambda a, b: np.concatenate((a, b))[order]  # noqa: E731
        pos_d = ends[dwells]
        k_all = cat(kind, np.full(nd, DWELL, dtype=np.uint8))
        st_all = cat(starts, pos_d)
        en_all = cat(e, pos_d)
        ce_all = cat(center, np.zeros((nd, 2)))
        cw_all = cat(cw, np.zeros(nd, dtype=bool))
        fe_all = cat(fmm, np.full(nd, np.nan))
        dw_all = cat(np.zeros(nm), pw[dwells])
        le_all = cat(length, np.zeros(nd))
        jet = jet_l[seg_line]
        # pierces: a cutting move with the jet on whose previous cutting move had it off, or
        # with the jet switched off in between (as ProgramBuilder counts them one by one)
        s0 = ip.builder._jet_was_on
        off_cum = np.cumsum(jet_off)
        cut = (k_all == LINE) | (k_all == ARC)
        cl, cj = seg_line[cut], jet[cut]
        if len(cl):
            prev_line = np.concatenate(([-1], cl[:-1]))
            offs_between = off_cum[cl] - np.where(prev_line >= 0, off_cum[np.maximum(prev_line, 0)], 0)
            prev_state = np.concatenate(([s0], cj[:-1])) & (offs_between == 0)
            pierces = int((cj & ~prev_state).sum())
            after = bool(cj[-1]) and off_cum[limit - 1] == off_cum[cl[-1]]
        else:
            pierces, after = 0, bool(s0) and off_cum[limit - 1] == 0
        lo_all = lo.min(axis=0) if nm else np.full(3, np.inf)
        hi_all = hi.max(axis=0) if nm else np.full(3, -np.inf)
        tol = np.where(k_all == DWELL, 0.0, ip._attrs.tolerance_mm)
        ip.builder.extend(
            k_all, st_all, en_all, ce_all, cw_all, fe_all, dw_all, jet, aux_l[seg_line], first + seg_line + 1,
            ip._attrs, tol, le_all, lo_all, hi_all, pierces, after,
        )
        moved = k_all != DWELL
        if moved.any():
            ip.kerf.moved_to(tuple(en_all[np.flatnonzero(moved)[-1]].tolist()))
        if len(mc) and not np.isnan(mc[:limit]).all():
            ip.jet, ip.aux = bool(jet_l[limit - 1]), int(aux_l[limit - 1])
            ip._refresh_attrs()

    def _through_kerf(self, first, limit, mc, dwells, pw, ends, idx, kind, starts, e, center, cw, fmm) -> None:
        """With kerf compensation on, each line's M codes, dwell and move go one by one through the
        compensator, in the general path's order (M codes, then dwell, then motion)."""
        ip = self.ip
        move = ip.kerf.move
        m_lines = np.flatnonzero(~np.isnan(mc[:limit]))
        lines = np.union1d(np.union1d(idx, dwells), m_lines).tolist()
        seg_of = dict(zip(idx.tolist(), range(len(idx))))
        dwell_set = set(dwells.tolist())
        m_set = set(m_lines.tolist())
        kind_l, st_l, en_l, ce_l, cw_l, fe_l = kind.tolist(), starts.tolist(), e.tolist(), center.tolist(), cw.tolist(), fmm.tolist()
        for L in lines:
            line_no = first + L + 1
            if L in m_set:
                ip._mcode(int(mc[L]), line_no)
            if L in dwell_set:
                ip._event("dwell", line_no, seconds=float(pw[L]), position=tuple(ends[L].tolist()), jet=ip.jet, aux=ip.aux, outputs=ip.outputs)
            k = seg_of.get(L)
            if k is not None:
                kk = kind_l[k]
                move(Move(kk, tuple(st_l[k]), tuple(en_l[k]), tuple(ce_l[k]) if kk == ARC else None, cw_l[k], 0, fe_l[k], line_no, 1, ip._attrs))

    def _arcs(self, idx, arc, cw, starts, e, center, wi, wj, wr, units) -> int | None:
        """Centres and radius checks of every arc; index of the first bad one or None."""
        from .arcs import R_FORM_SLACK_MM, RADIUS_TOLERANCE_MM, SPIRAL_RELATIVE_TOLERANCE, SPIRAL_TOLERANCE_INCH_MM, SPIRAL_TOLERANCE_MM

        ip = self.ip
        a = np.flatnonzero(arc)
        li = idx[a]
        x0, y0, x1, y1 = starts[a, 0], starts[a, 1], e[a, 0], e[a, 1]
        r_form = ~np.isnan(wr[li])
        i_ = np.nan_to_num(wi[li]) * units[li]
        j_ = np.nan_to_num(wj[li]) * units[li]
        if ip.arc_absolute:
            cx, cy = i_ + ip._offset(0), j_ + ip._offset(1)
        else:
            cx, cy = x0 + i_, y0 + j_
        bad = np.zeros(len(a), dtype=bool)
        if r_form.any():
            r = wr[li] * units[li]
            dx, dy = x1 - x0, y1 - y0
            chord = np.hypot(dx, dy)
            radius = np.abs(r)
            with np.errstate(invalid="ignore", divide="ignore"):
                half = chord / 2.0
                bad |= r_form & ((chord < 1e-9) | (half - radius > R_FORM_SLACK_MM))
                h = np.sqrt(np.maximum(radius * radius - half * half, 0.0))
                ux, uy = -dy / chord, dx / chord
                side = np.where((~cw[a]) == (r > 0), 1.0, -1.0)
                rcx = (x0 + x1) / 2.0 + side * h * ux
                rcy = (y0 + y1) / 2.0 + side * h * uy
            cx = np.where(r_form, rcx, cx)
            cy = np.where(r_form, rcy, cy)
        r0 = np.hypot(x0 - cx, y0 - cy)
        r1 = np.hypot(x1 - cx, y1 - cy)
        ij = ~r_form
        # as arcs.spiral_error, every arc at once
        err = np.abs(r1 - r0)
        tolerance = np.where(units[li] != 1.0, SPIRAL_TOLERANCE_INCH_MM, SPIRAL_TOLERANCE_MM)
        spiral = (err > 100.0 * tolerance) | ((err > tolerance) & (err > SPIRAL_RELATIVE_TOLERANCE * np.maximum(r0, r1)))
        bad |= ij & ((r0 < RADIUS_TOLERANCE_MM) | (r1 < RADIUS_TOLERANCE_MM) | spiral)
        center[a, 0], center[a, 1] = cx, cy
        if bad.any():
            return int(a[np.flatnonzero(bad)[0]])
        return None


def piece_geometry(kind, starts, ends, centers, cw) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Length and XYZ bounds of every piece, arcs' quadrant points included."""
    length = np.sqrt(((ends - starts) ** 2).sum(axis=1))
    lo, hi = np.minimum(starts, ends), np.maximum(starts, ends)
    a = np.flatnonzero(kind == ARC)
    if len(a):
        x0, y0, x1, y1 = starts[a, 0], starts[a, 1], ends[a, 0], ends[a, 1]
        cx, cy = centers[a, 0], centers[a, 1]
        r0 = np.hypot(x0 - cx, y0 - cy)
        a0, a1 = np.arctan2(y0 - cy, x0 - cx), np.arctan2(y1 - cy, x1 - cx)
        d = np.where(cw[a], a0 - a1, a1 - a0)
        d = np.where(d <= 1e-12, d + _TWO_PI, d)
        swept = np.where(cw[a], -d, d)
        length[a] = np.hypot(np.abs(r0 * swept), ends[a, 2] - starts[a, 2])
        lo_s, hi_s = np.where(swept >= 0, a0, a0 + swept), np.where(swept >= 0, a0 + swept, a0)
        for k, (px, py) in enumerate(((1, 0), (0, 1), (-1, 0), (0, -1))):
            ang = k * math.pi / 2.0
            inside = ang + _TWO_PI * np.ceil((lo_s - ang) / _TWO_PI) <= hi_s
            qx, qy = cx + px * r0, cy + py * r0
            lo[a, 0] = np.where(inside, np.minimum(lo[a, 0], qx), lo[a, 0])
            lo[a, 1] = np.where(inside, np.minimum(lo[a, 1], qy), lo[a, 1])
            hi[a, 0] = np.where(inside, np.maximum(hi[a, 0], qx), hi[a, 0])
            hi[a, 1] = np.where(inside, np.maximum(hi[a, 1], qy), hi[a, 1])
    return length, lo, hi


def _ffill(values: np.ndarray, initial: float) -> np.ndarray:
    """Carry the last non-NaN value forward; `initial` before the first one."""
    valid = ~np.isnan(values)
    pos = np.where(valid, np.arange(len(values)), -1)
    np.maximum.accumulate(pos, out=pos)
    return np.where(pos >= 0, values[np.maximum(pos, 0)], initial)


def _first(mask: np.ndarray, limit: int) -> int:
    hits = np.flatnonzero(mask[:limit])
    return int(hits[0]) if hits.size else limit
