"""A program's steps made as the motion reaches them, and its planned cycle time made beside it.

Making every section of a large program before the first move costs minutes (about 0.2 ms a
line) and holds every element in memory. `StepSource` makes the steps in order as they are
asked for (`sections.iter_steps`), keeps a bounded window of them (the step under way and what
has been made ahead of it), and forgets the ones the head has left behind. The planner's worker
thread makes steps ahead (`build_until`), outside the lock the refills take, so the main loop
finds the next step already made.

`ProgramTiming` walks the same steps and adds up each step's servo periods
(`SectionStream.planned_samples`: the profile's pieces, not sampled), so the cycle time and the
ETA come from exactly the profile the run streams; for a large program it runs in a process of
its own (`timing_process.py`), without delaying the load or the start or sharing the
interpreter lock with the refills.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
from array import array
from typing import Iterable, Iterator

import numpy as np

from gcode.program import Program

from ..config import MachineConfig
from ..runtime.child import die_with
from .overlap import CornerOverlap
from .programme import ProgrammeBook
from .sections import KnownRun, Pause, RunMemo, RunStart, Section, Step, iter_steps, pierce_boundaries
from .stream import SectionStream

STEPS_AHEAD = 48  # steps the worker keeps made beyond the one under way (a nest: a dozen parts)


class StepSource:
    """The steps of one run of a program, made on demand, with a bounded window kept."""

    def __init__(self, steps: Iterable[Step]) -> None:
        self._iter: Iterator[Step] | None = iter(steps)
        self._made: list[Step] = []
        self._first = 0  # index of _made[0]
        self._failure: BaseException | None = None
        self._lock = threading.Lock()  # one maker at a time (the generator cannot run twice at once)
        self.largest_window = 0  # the most steps held at once (a figure for tests and benches)

    @property
    def made(self) -> int:
        """Index one past the last step made so far."""
        return self._first + len(self._made)

    def peek(self, i: int) -> Step | None:
        """Step i when it has been made (and not forgotten), else None; never makes one."""
        k = i - self._first
        made = self._made
        return made[k] if 0 <= k < len(made) else None

    def peek_from_another_thread(self, i: int) -> Step | None:
        """`peek` for a thread that runs beside the one forgetting steps (the planner's worker):
        under the lock, so that step i is not read while the window moves."""
        with self._lock:
            return self.peek(i)

    def get(self, i: int) -> Step | None:
        """Step i, made now when needed; None past the program's end."""
        step = self.peek(i)
        if step is None and i >= self.made:
            self.build_until(i)
            step = self.peek(i)
        if step is None and i < self._first:
            raise IndexError(f"step {i} was forgotten (the window starts at step {self._first})")
        return step

    def build_until(self, i: int) -> None:
        """Make the steps up to step i (fewer at the program's end), one at a time under the lock, so
        that a `get` of the next step waits for at most one step being made. A failure while making
        one is raised here and again by every later call."""
        while self.made <= i:
            with self._lock:
                if self._failure is not None:
                    raise self._failure
                if self._iter is None:
                    return
                if self.made > i:
                    break
                try:
                    self._made.append(next(self._iter))
                except StopIteration:
                    self._iter = None
                except BaseException as exc:
                    self._failure, self._iter = exc, None
                    raise
                self.largest_window = max(self.largest_window, len(self._made))

    def forget_before(self, i: int) -> None:
        """Drop the steps before step i: the head has left them."""
        with self._lock:
            k = min(max(i - self._first, 0), len(self._made))
            if k:
                del self._made[:k]
                self._first += k


class ProgramTiming:
    """A program's cycle time at 100 % override, step by step, from the planned profile.

    `step_ticks[i]` is step i's servo periods (a section: its samples, what the runner will make
    of it; a pause: its seconds; a program stop: 0). Filled by `compute` (or `adopt`, from the
    timing process): `complete` says when every step is in, `total_mm` is then the path length.
    `overlap`: the machine's corner overlaps (`overlap.py`, `CornerOverlap.of(config)`), as the
    runner makes them; a section whose last samples the next one's first are added to counts only
    the samples before them."""

    def __init__(self, dt: float, overlap: CornerOverlap) -> None:
        self.dt = dt
        self.overlap = overlap
        self.step_ticks = array("q")
        self.total_ticks = 0
        self.total_mm = 0.0
        self.complete = False
        self.after = np.zeros(0, dtype=np.int64)  # once complete: ticks from step i to the end
        self.failure: BaseException | None = None

    @classmethod
    def of(cls, program: Program, config: MachineConfig, cut=None, workers: int = 1) -> "ProgramTiming":  # noqa: ANN001
        """A whole program's timing, its steps made as the planner streams them (`iter_steps`), under
        the cutting job's plan `cut` when there is one. With `workers` > 1 a large program is cut
        at pierces into pieces (`sections.pierce_boundaries`) timed at once by that many forked
        processes: the same steps, the same figures, sooner on a host with the cores for it."""
        timing = cls(config.timing.period_s, CornerOverlap.of(config))
        pieces = _pieces(program, workers) if workers > 1 else []
        if len(pieces) < 2:
            return timing.compute(iter_steps(program, config, cut, memo=RunMemo()))
        try:
            timed = _time_pieces(program, config, cut, pieces, workers)
        except BaseException as exc:  # kept for the caller to report, as `compute` keeps its own
            timing.failure = exc
            return timing
        timing.adopt(np.concatenate([ticks for ticks, _ in timed]), float(sum(mm for _, mm in timed)))
        return timing

    def compute(self, steps: Iterable[Step | RunStart | KnownRun]) -> "ProgramTiming":
        """Walk the steps (each made, timed and dropped) to the end. With a memo (`iter_steps`), a
        run timed before comes whole (`KnownRun`), and one announced by a `RunStart` is given to its
        memo once timed, at the pause after it."""
        try:
            ticks, total_mm = array("q"), 0.0
            last, summed = None, 0  # the stream of the section just timed (when a section), and how
            # many of its first samples are added to the one before it
            book = ProgrammeBook()  # the programmed corners (`programme.py`), solved here as the run meets them
            run: RunStart | None = None  # the run being timed for the memo, its first step and path before it
            run_from, run_mm = 0, 0.0

            def keep() -> None:
                """The run announced ends here, at a pause or the program's end: its ticks are its own."""
                run.memo.put(run.keys, tuple(ticks[run_from:]), total_mm - run_mm)

            for step in steps:
                if not isinstance(step, Section):
                    if run is not None:
                        keep()
                        run = None
                    if isinstance(step, RunStart):
                        run, run_from, run_mm = step, len(ticks), total_mm
                    elif isinstance(step, KnownRun):
                        ticks.extend(step.ticks)
                        total_mm += step.length_mm
                    else:
                        ticks.append(step_ticks(step, self.dt))
                    last = None
                    continue
                stream = SectionStream(step)
                ticks.append(stream.planned_samples())
                taken = 0
                if last is not None:
                    corner = self.overlap.plan(last, stream, summed, book)
                    ticks[-2] -= corner.saved
                    taken = corner.committed_next
                last, summed = stream, taken
                total_mm += step.length_mm
            if run is not None:
                keep()
            self.adopt(np.array(ticks, dtype=np.int64), total_mm)
        except BaseException as exc:  # kept for the planner to report; the run itself makes the same steps
            self.failure = exc
        return self

    def adopt(self, step_ticks: np.ndarray, total_mm: float) -> None:
        """Take a timing made elsewhere (`timing_process.py`): per-step ticks and the path length."""
        self.step_ticks = array("q", np.asarray(step_ticks, dtype=np.int64).tobytes())
        self.total_ticks = int(np.sum(step_ticks))
        self.total_mm = float(total_mm)
        self.after = np.cumsum(np.asarray(step_ticks, dtype=np.int64)[::-1])[::-1].copy()
        self.complete = True

    def remaining_ticks(self, index: int, left_in_step: int) -> int | None:
        """Servo periods from within step `index` (with `left_in_step` of it to go) to the end;
        None while the timing is still being made."""
        if not self.complete:
            return None
        after = int(self.after[index + 1]) if index + 1 < len(self.after) else 0
        return left_in_step + after


PIECES_PER_WORKER = 4  # pieces per process: a piece of slow sections does not hold the others up
PIECE_SEGMENTS = 2000  # at least this many segments a piece: each costs a fork's worth of start-up


def _pieces(program: Program, workers: int) -> list[tuple[int, int]]:
    """Segment ranges [first, end) of about equal size, cut at pierces, for `workers` processes."""
    n = len(program.segments)
    count = min(workers * PIECES_PER_WORKER, n // PIECE_SEGMENTS)
    if count < 2:
        return []
    at = pierce_boundaries(program)
    if not len(at):
        return []
    # the pierce nearest to each even share of the segments, each once
    want = np.arange(1, count) * n / count
    cuts = np.unique(at[np.clip(np.searchsorted(at, want), 0, len(at) - 1)])
    bounds = [0, *cuts.tolist(), n]
    return [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


_JOB: tuple | None = None  # (program, config, cut) for the forked processes (inherited, not pickled)


def _time_piece(span: tuple[int, int]) -> tuple[np.ndarray, float]:
    program, config, cut = _JOB
    timing = ProgramTiming(config.timing.period_s, CornerOverlap.of(config)).compute(
        iter_steps(program, config, cut, *span, memo=RunMemo()))
    if timing.failure is not None:
        raise timing.failure
    return np.asarray(timing.step_ticks, dtype=np.int64), timing.total_mm


def _time_pieces(program: Program, config: MachineConfig, cut, spans: list[tuple[int, int]],
                 workers: int) -> list[tuple[np.ndarray, float]]:  # noqa: ANN001 - a CutPlan
    """Each piece's step ticks and path length, in order, from `workers` forked processes. Forked
    (they inherit the program instead of being sent it): called only from processes without
    threads of their own (`waterjet check`, the timing process)."""
    global _JOB
    _JOB = (program, config, cut)
    try:
        with multiprocessing.get_context("fork").Pool(min(workers, len(spans)), die_with, (os.getpid(),)) as pool:
            return pool.map(_time_piece, spans, chunksize=1)
    finally:
        _JOB = None


def timing_workers() -> int:
    """How many processes a program's timing may use: the CPUs this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def step_ticks(step: Step, dt: float) -> int:
    """Servo periods one step takes at 100 % override (0 for a program stop: it waits for the operator)."""
    if isinstance(step, Section):
        return SectionStream(step).planned_samples()
    assert isinstance(step, Pause)
    return 0 if step.kind == "program_stop" else int(round(step.seconds / dt))

