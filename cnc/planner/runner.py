"""A program's setpoints, made on demand: sections and pauses in order, under the operator's controls.

`take(n)` gives the next setpoint records for the FIFO (positions of the machine's axes,
velocities, output flags, segment and source line) and the program position of each, for
progress. The operator's controls act from the next record made:

- feed override (0 to 2; rapids follow it up to 1) replans the motion under way; 0 % while the
  jet is open, or about to open, is a hold (below), never a standstill with the jet open;
- hold decelerates along the path to a stop; resume continues from exactly there;
- stop is a hold that ends the program once at rest;
- a program stop (M0, M1, M60) waits at its point for `resume` (cycle start).

Standing still with the jet open drills the material, so while held or paused the jet (and
abrasive) close when the machine file says so, and on resume the jet re-pierces (on delay
and pierce dwell) before motion continues. Velocities are central differences of the
positions (exact at each sample for the servo's feed-forward), so records leave one sample
late; the last record before the FIFO may run dry has IN_MOTION cleared.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from gcode.program import Program

from ..config import MachineConfig
from ..data.fifo import SetpointFlag, setpoint_dtype
from .connection import STOP, CornerPlan
from .overlap import CornerOverlap
from .programme import ProgrammeBook
from .sections import Section, Step, iter_steps
from .steps import STEPS_AHEAD, ProgramTiming, StepSource
from .stream import SectionStream, WindowJob

_IN_MOTION = int(SetpointFlag.IN_MOTION)
_SEGMENT_START = int(SetpointFlag.SEGMENT_START)
_JET_BITS = int(SetpointFlag.JET_ON | SetpointFlag.ABRASIVE)
_JET_OFF_MASK = ~_JET_BITS
_AXES = ("x", "y", "z")


class RunState(enum.IntEnum):
    RUNNING = 0
    HOLDING = 1  # decelerating to a hold
    HELD = 2
    PAUSED = 3  # at a program stop, waiting for cycle start
    STOPPING = 4  # decelerating, then the program ends
    DONE = 5  # the program ran to its end
    ABORTED = 6  # stopped by the operator


@dataclass
class Event:
    """Something the program reached: a message, a program stop."""

    kind: str
    text: str
    line: int


class ProgramRunner:
    """Setpoints of one program from its first record to its last."""

    def __init__(self, program: Program | None, config: MachineConfig, steps: list[Step] | StepSource | None = None,
                 timing: ProgramTiming | None = None, pierce_s: float | None = None) -> None:
        self.config = config
        self.pierce_s = config.jet.pierce_dwell_s if pierce_s is None else pierce_s  # the dwell of a re-pierce
        self.dt = config.timing.period_s
        if steps is None:
            self._again = lambda: iter_steps(program, config)  # the steps once more, for the timing
        elif isinstance(steps, StepSource):
            self._again = None
        else:
            steps = list(steps)
            self._again = lambda: steps
        self.steps = steps if isinstance(steps, StepSource) else StepSource(self._again())
        self.timing = timing  # the cycle time step by step, for the ETA (`remaining_s`); made when missing
        self.axes = [_AXES.index(a) for a in config.axis_names]
        self.dtype = setpoint_dtype(len(self.axes))
        self.close_on_hold = config.jet.close_on_hold
        self.corners = CornerOverlap.of(config)
        self._overlap: tuple | None = None  # ((step, its plan's generation), next section's stream, corner plan) decided
        self._queued: tuple | None = None  # a corner's samples still to give (`_start_corner`)
        self._queued_connection = False  # the queued samples are a connection's
        self._summed_head = 0  # how many of the current section's first samples a corner took (added or replaced)
        self.book = ProgrammeBook()  # programmed connections solved ahead (`solve_ahead`)
        self.state = RunState.RUNNING
        self.override = 1.0
        self.events: list[Event] = []
        self.index = -1  # step being run
        self.stream: SectionStream | None = None
        self._ready: dict[int, SectionStream] = {}  # streams of steps ahead, planned early (`prepare`)
        self.pause_left = 0
        self.repierce = 0  # samples of re-pierce still to make before motion continues
        self.flags_now = 0  # output bits of the last record made
        self.segment_now = 0
        self._released_segment = -1  # segment of the last record released (its next marks SEGMENT_START on a change)
        self.line_now = 0
        self.jet_closed = False
        self._pending: tuple | None = None  # (position, flags, segment, line, s_program) of the last sample made
        self._before: np.ndarray | None = None  # position of the record released before it
        self._newest: np.ndarray | None = None  # position of the newest sample made
        self._message_index = 0
        self.s_program = 0.0
        self.made = 0  # records released
        self._next_step()

    # -- the operator's controls ------------------------------------------------------------
    def set_override(self, ratio: float) -> None:
        self.override = ratio
        self._ready.clear()  # planned under the old override
        if ratio <= 0.0 and self.state == RunState.RUNNING and (self.flags_now | self._flags_ahead()) & _JET_BITS:
            self.hold()  # standing still with the jet open drills through: a hold, which only a resume ends
            return
        if self.stream is not None and self.state in (RunState.RUNNING,):
            self.stream.set_override(ratio, min(ratio, 1.0))

    def hold(self) -> None:
        if self.state != RunState.RUNNING:
            return
        if self._moving:
            self.stream.hold()
            self.state = RunState.HOLDING
        else:
            # standing still (a pierce, a dwell, the re-pierce before the motion goes on): held at
            # once, the jet closed; a resume pierces again
            self.repierce = 0
            self.state = RunState.HELD
            self._close_jet()

    def resume(self) -> None:
        if self.state not in (RunState.HOLDING, RunState.HELD, RunState.PAUSED):
            return
        was = self.state
        self.state = RunState.RUNNING
        if self.jet_closed and self._flags_ahead() & int(SetpointFlag.JET_ON):
            self.repierce = self._ticks(self.config.jet.on_delay_s + self.pierce_s)
        self.jet_closed = False
        if self.stream is not None and was in (RunState.HOLDING, RunState.HELD):
            self.stream.set_override(self.override, min(self.override, 1.0))
            self.stream.resume()
        if was == RunState.PAUSED:
            self._next_step()

    def stop(self) -> None:
        if self.state in (RunState.DONE, RunState.ABORTED, RunState.STOPPING):
            return  # a second stop changes nothing (ending the stream early would starve the servo)
        if self._moving and self.state in (RunState.RUNNING, RunState.HOLDING) and not self.stream.at_rest:
            self.stream.hold()
            self.state = RunState.STOPPING
        else:  # standing still (a re-pierce included): ended at once
            self.repierce = 0
            self.state = RunState.ABORTED
            self._close_jet()
            if self.flags_now & ~_JET_OFF_MASK and self._pending is None:
                # standing with the jet open (left open on hold): one more record, at rest, to close it
                self._pending = (self._position_now(), self.flags_now & _JET_OFF_MASK, self.segment_now, self.line_now, self.s_program)

    @property
    def _moving(self) -> bool:
        """A section's motion is under way (not a pierce, a dwell or the re-pierce before it goes on)."""
        return self.stream is not None and not self.repierce

    @property
    def overlap_left(self) -> int:
        """Samples of a corner's overlap or connection still to give (`overlap.py`,
        `connection.py`; 0: none under way): the operator's controls act after them."""
        return len(self._queued[0]) if self._queued is not None else 0

    @property
    def connecting(self) -> bool:
        """The corner's samples under way are a connection's (`connection.py`), not an overlap's."""
        return self._queued is not None and self._queued_connection

    @property
    def finished(self) -> bool:
        return self.state in (RunState.DONE, RunState.ABORTED)

    @property
    def idle(self) -> bool:
        """Nothing more will be made until the operator acts (held, paused, finished, override at 0)."""
        stalled = self.stream is not None and self.stream.at_rest and not self.stream.holding
        return stalled or self.state in (RunState.HELD, RunState.PAUSED, RunState.DONE, RunState.ABORTED)

    # -- making records ---------------------------------------------------------------------
    def take(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Up to n records and the program position (mm of path done) of each."""
        pos, flags, seg, line, prog = [], [], [], [], []
        made = 0
        while made < n and not self.idle:
            p, f, g, ln, s = self._make(n - made)
            if not len(p):
                continue
            pos.append(p), flags.append(f), seg.append(g), line.append(ln), prog.append(s)
            made += len(p)
            self._newest = p[-1]
        if made:
            return self._release(np.concatenate(pos), np.concatenate(flags), np.concatenate(seg),
                                 np.concatenate(line), np.concatenate(prog), final=self.idle)
        if self.idle and self._pending is not None:
            return self._release(np.zeros((0, len(self.axes))), *(np.zeros(0, dtype=t) for t in (np.uint32, np.int64, np.int64)),
                                 np.zeros(0), final=True)
        return np.zeros(0, dtype=self.dtype), np.zeros(0)

    def _make(self, n: int):
        """The next samples of whatever runs now (or a step change, returning nothing)."""
        if self.override <= 0.0 and self._opens_jet_now():
            self.hold()  # at 0 % nothing may open the jet: it would stand still open
            return self._nothing()
        if self._queued is not None:
            return self._from_queue(n)
        if self.repierce:
            k = min(n, self.repierce)
            self.repierce -= k
            return self._still(k, self._flags_ahead())
        if self.stream is not None:
            return self._from_stream(n)
        if self.pause_left:
            k = min(n, self.pause_left)
            self.pause_left -= k
            step = self.steps.peek(self.index)
            self.segment_now, self.line_now = step.segment, step.line
            return self._still(k, step.flags)
        self._next_step()
        return self._nothing()

    def _from_stream(self, n: int):
        stream = self.stream
        section = stream.section
        # what the take commits anyway, and as far as a corner may reach back: its end known in time
        stream.plan_until(stream.k + n + self.corners.connection_reach)
        corner = STOP if self._waits_for_programme(stream, n) else self._corner_plan(stream)
        if corner.saved:
            left = stream.k_end - stream.k
            if left == corner.last_samples:
                self._start_corner(corner)
                return self._nothing()
            if left > corner.last_samples:
                n = min(n, left - corner.last_samples)  # up to where the corner's samples begin
            # (fewer left: the samples to add to were made before the overlap was known: a stop there)
        y, s = stream.take(n)
        if len(y):
            k = section.path.index_at(s)
            self._messages(section, s)
            self.s_program = section.offset_mm + float(s[-1])
            return (y[:, self.axes], section.flags[k], section.segment[k], section.line[k], section.offset_mm + s)
        if stream.done:
            self.stream = None
            if self.state == RunState.STOPPING:
                self.state = RunState.ABORTED
                self._close_jet()
            elif self.state == RunState.HOLDING:
                self.state = RunState.HELD
                self._close_jet()
            else:
                self._next_step()
        elif stream.at_rest and stream.holding:
            self.state = RunState.ABORTED if self.state == RunState.STOPPING else RunState.HELD
            self._close_jet()
        return self._nothing()

    @property
    def solves_ahead(self) -> bool:
        """Whether a worker solves the programmed corners ahead (`solve_ahead`, the planner
        process's): then a corner it has not solved is decided as late as the refill can, and if
        still unsolved passed by the planner's own plan, never solved in the refill."""
        return not self.book.solves_late

    @solves_ahead.setter
    def solves_ahead(self, on: bool) -> None:
        self.book.solves_late = not on

    def _waits_for_programme(self, stream: SectionStream, n: int) -> bool:
        """Whether the corner at the section's end is left undecided for now: the worker has yet to
        solve its programme (`solve_ahead`) and these n samples stop short of wherever any corner's
        samples may begin, so that the refill need not solve it itself."""
        if not self.solves_ahead or self.corners.programme_samples < 1 or not stream.final:
            return False
        if self._overlap is not None and self._overlap[0] == (self.index, stream.generation):
            return False  # decided
        reach_back = max(self.corners.max_samples, self.corners.connection_reach)
        return stream.k_end - stream.k - n > reach_back and not self.book.solved(self.index, self.override)

    def solve_ahead(self, most: int = 1) -> int:
        """Solve up to `most` programmed connections of the corners ahead (`programme.py`) that
        the book lacks, on sections of their own, at the override now: the planner's worker does
        it, away from the refills, so that a refill finds them solved. How many it solved."""
        if self.corners.programme_samples < 1 or self.state != RunState.RUNNING or self.override <= 0.0:
            return 0  # (at 0 % nothing moves: a section planned at it would never end)
        done, override = 0, self.override
        i = max(self.index, 0)
        while done < most and i + 1 < self.steps.made:
            if not self.book.solved(i, override):
                a, b = self.steps.peek_from_another_thread(i), self.steps.peek_from_another_thread(i + 1)
                if a is None or b is None:  # forgotten meanwhile: the head moved on
                    return done
                if isinstance(a, Section) and isinstance(b, Section):
                    done += self.book.solve_ahead(self.corners, i, a, b, override)
                else:
                    self.book.mark(i, override)  # a pause on either side: no corner
            i += 1
        return done

    def _corner_plan(self, stream: SectionStream) -> CornerPlan:
        """How the corner at the section's end is passed (`CornerOverlap.plan`: a stop, an overlap
        or a connection), decided once the section is planned to its end and again after every
        replan of it."""
        if (self.state != RunState.RUNNING or stream.stopping or not stream.final
                or max(self.corners.max_samples, self.corners.connection_samples) < 1):
            return STOP
        key = (self.index, stream.generation)
        if self._overlap is not None and self._overlap[0] == key:
            return self._overlap[2]
        following = self.steps.get(self.index + 1)
        nxt, plan = None, STOP
        if isinstance(following, Section):  # (`plan` says a stop at once where the corner does not qualify)
            nxt = self._ready.setdefault(self.index + 1, SectionStream(following, self.override, min(self.override, 1.0)))
            plan = self.corners.plan(stream, nxt, self._summed_head, self.book, self.index)
        self._overlap = (key, nxt, plan)
        return plan

    def _start_corner(self, plan: CornerPlan) -> None:
        """Take the section's last samples and the next one's first, and queue what the corner makes
        of them: the two added (an overlap) or the connection's own samples in their place. Then go
        on with the next section: its stream takes the operator's controls from now on, acting after
        the queued samples."""
        last, (_, nxt, _) = self.stream, self._overlap
        # the corner's samples are committed as planned: a raise over 100 % still to take a step in
        # them acts from the next section on, which starts with it (as any override change made
        # during a corner; its step would replan the samples the corner adds to or replaces)
        last.leave_raise()
        y_last, s_last = last.take(plan.last_samples)
        y_next, s_next = nxt.take(plan.next_samples)
        self._messages(last.section, s_last)
        self._ready.pop(self.index + 1, None)
        self._overlap = None
        self.index += 1
        self.steps.forget_before(self.index)
        self.book.forget_before(self.index)
        self.stream, self._message_index, self._summed_head = nxt, 0, plan.committed_next
        self._queued_connection = plan.is_connection
        section = nxt.section
        self._messages(section, s_next)
        if len(s_next):
            self.s_program = section.offset_mm + float(s_next[-1])
        if not plan.is_connection:
            summed = y_last + y_next - np.asarray(last.section.end, dtype=float)
            k = section.path.index_at(s_next)
            self._queued = (summed[:, self.axes], section.flags[k], section.segment[k], section.line[k], section.offset_mm + s_next)
            return
        # a connection: each of its samples tagged as the replaced sample at the same share of the way
        # (segment, line, outputs, program position), so that they advance as the head does; then
        # the next section's own samples committed with it (`CornerPlan.committed_next`)
        ka, kb = last.section.path.index_at(s_last), section.path.index_at(s_next)
        tags = [np.concatenate((last.section.flags[ka], section.flags[kb])),
                np.concatenate((last.section.segment[ka], section.segment[kb])),
                np.concatenate((last.section.line[ka], section.line[kb])),
                np.concatenate((last.section.offset_mm + s_last, section.offset_mm + s_next))]
        m = len(plan.path) + 1
        replaced = plan.last_samples + plan.next_samples
        which = np.clip(np.arange(1, m) * (replaced + 1) // m - 1, 0, replaced - 1)
        y_own, s_own = nxt.take(plan.committed_next - plan.next_samples)
        k = section.path.index_at(s_own)
        self._messages(section, s_own)
        if len(s_own):
            self.s_program = section.offset_mm + float(s_own[-1])
        self._queued = (np.concatenate((plan.path[:, self.axes], y_own[:, self.axes])),
                        *(np.concatenate((t[which], own)) for t, own in zip(
                            tags, (section.flags[k], section.segment[k], section.line[k], section.offset_mm + s_own))))

    def _from_queue(self, n: int):
        """The next of a corner's queued samples (an overlap's sums, a connection's own)."""
        m = min(n, len(self._queued[0]))
        out = tuple(x[:m] for x in self._queued)
        self._queued = tuple(x[m:] for x in self._queued) if m < len(self._queued[0]) else None
        return out

    def _next_step(self) -> None:
        """Start the step after the current one."""
        self.index += 1
        step = self.steps.get(self.index)
        self.steps.forget_before(self.index)  # what the head has left
        self.book.forget_before(self.index)
        if step is None:
            self.state = RunState.DONE
            return
        if isinstance(step, Section):
            self.stream = self._ready.pop(self.index, None) or SectionStream(step, self.override, min(self.override, 1.0))
            self._message_index = self._summed_head = 0
        elif step.kind == "program_stop":
            self.events.append(Event("program_stop", step.text, step.line))
            self.state = RunState.PAUSED
            self._close_jet()
        else:
            self.pause_left = self._ticks(step.seconds)
            if step.kind == "dwell":
                self.events.append(Event("dwell", step.text, step.line))

    def _still(self, k: int, flags: int):
        p = self._position_now()
        return (np.repeat(p[None, :], k, axis=0), np.full(k, flags, dtype=np.uint32),
                np.full(k, self.segment_now), np.full(k, self.line_now), np.full(k, self.s_program))

    def _nothing(self):
        return (np.zeros((0, len(self.axes))), np.zeros(0, dtype=np.uint32), np.zeros(0, dtype=np.int64),
                np.zeros(0, dtype=np.int64), np.zeros(0))

    def _release(self, pos, flags, seg, line, prog, final: bool) -> tuple[np.ndarray, np.ndarray]:
        """Records for every sample made but the newest (whose velocity needs the next one);
        with `final`, that one too, at rest."""
        if self._pending is not None:
            p0, f0, g0, l0, s0 = self._pending
            pos = np.concatenate((p0[None, :], pos))
            flags, seg = np.concatenate(([f0], flags)), np.concatenate(([g0], seg))
            line, prog = np.concatenate(([l0], line)), np.concatenate(([s0], prog))
        if not len(pos):
            return np.zeros(0, dtype=self.dtype), np.zeros(0)
        count = len(pos) if final else len(pos) - 1
        if not count:  # only the newest sample (a take of one at a run's start or after a hold): it waits for the next
            self._pending = (pos[-1], flags[-1], seg[-1], line[-1], prog[-1])
            return np.zeros(0, dtype=self.dtype), np.zeros(0)
        before = self._before if self._before is not None else pos[0]
        ext = np.concatenate((before[None, :], pos, pos[-1:] if final else np.zeros((0, pos.shape[1]))))
        out = np.zeros(count, dtype=self.dtype)
        out["position"] = pos[:count]
        out["velocity"] = (ext[2:count + 2] - ext[:count]) / (2.0 * self.dt)
        f = flags[:count].astype(np.int64) | _IN_MOTION
        starts = np.concatenate(([seg[0] != self._released_segment], seg[1:count] != seg[: count - 1]))
        f[starts] |= _SEGMENT_START
        if final:
            f[-1] &= ~_IN_MOTION
            if self.jet_closed:
                f[-1] &= _JET_OFF_MASK
        if self.close_on_hold and self.state in (RunState.HOLDING, RunState.STOPPING):
            # the hold's last samples settle at rest while the smoothing runs out: the jet closes with
            # the first one the head stands still at, not after them (it would drill there meanwhile)
            still = np.all(np.abs(out["velocity"]) < 1e-6, axis=1)
            if still.any():
                f[int(np.argmax(still)):] &= _JET_OFF_MASK
                self.jet_closed = self.jet_closed or bool(self.flags_now & ~_JET_OFF_MASK or flags[:count].any())
        out["flags"] = f
        out["segment"], out["line"] = seg[:count], line[:count]
        self.flags_now, self.segment_now, self.line_now = int(f[-1]), int(seg[count - 1]), int(line[count - 1])
        self._released_segment = self.segment_now
        self._before = pos[count - 1]
        self._pending = None if final else (pos[-1], flags[-1], seg[-1], line[-1], prog[-1])
        self.made += count
        return out, prog[:count]

    # -- helpers ----------------------------------------------------------------------------
    def _close_jet(self) -> None:
        if self.close_on_hold and self.flags_now & int(SetpointFlag.JET_ON | SetpointFlag.ABRASIVE):
            self.jet_closed = True
        if self.state == RunState.ABORTED and self.flags_now & int(SetpointFlag.JET_ON | SetpointFlag.ABRASIVE):
            self.jet_closed = True  # an aborted program always leaves the jet closed

    def _opens_jet_now(self) -> bool:
        """Whether the samples about to be made stand still with the jet open (a pierce, a dwell)."""
        if self.repierce:
            return bool(self._flags_ahead() & _JET_BITS)
        if self.stream is None and self.pause_left:
            return bool(self.steps.peek(self.index).flags & _JET_BITS)
        return False

    def _flags_ahead(self) -> int:
        """Output bits of what runs next (the element under way, or the step after a pause)."""
        if self.stream is not None:
            section = self.stream.section
            return int(section.flags[section.path.index_at(np.array([self.s_program - section.offset_mm]))[0]])
        step = self.steps.get(self.index + 1)
        if step is None:
            return 0
        return int(step.flags[0]) if isinstance(step, Section) else int(step.flags)

    def _position_now(self) -> np.ndarray:
        if self._newest is not None:
            return self._newest
        step = self.steps.get(max(self.index, 0))
        if step is None:
            return np.zeros(len(self.axes))
        where = step.start if isinstance(step, Section) else step.position
        return np.array(where)[self.axes]

    def _messages(self, section: Section, s: np.ndarray) -> None:
        msgs = section.messages
        while self._message_index < len(msgs) and msgs[self._message_index][0] <= s[-1]:
            _, text, line = msgs[self._message_index]
            self.events.append(Event("message", text, line))
            self._message_index += 1

    def _ticks(self, seconds: float) -> int:
        return int(round(seconds / self.dt))

    def plan_job(self, lead_s: float) -> WindowJob | None:
        """The next window to plan ahead (`SectionStream.window_job`): of the motion under way,
        or of the next section when the step under way ends within the lead."""
        if self.state != RunState.RUNNING:
            return None
        left = lead_s
        if self.stream is not None:
            job = self.stream.window_job(lead_s)
            if job is not None or not self.stream.final:
                return job
            left -= (self.stream.k_end - self.stream.k) * self.dt
        else:
            left -= self.pause_left * self.dt
        i = self.index
        while left > 0.0:
            i += 1
            step = self.steps.peek(i)  # made ahead by the worker (`build_ahead`), never here under the lock
            if step is None:
                return None
            if isinstance(step, Section):
                ready = self._ready.setdefault(i, SectionStream(step, self.override, min(self.override, 1.0)))
                return ready.window_job(left)
            if step.kind == "program_stop":
                return None
            left -= step.seconds
        return None

    def decide_corner(self) -> None:
        """Decide now how the corner at the end of the section under way is passed, once it is
        planned to its end (`_corner_plan`: a connection's search takes milliseconds). The planner's
        worker does it after each refill, with the FIFO full, so that the next refill, when it
        reaches the corner, finds the decision made."""
        if self.stream is not None and not self.repierce:
            self._corner_plan(self.stream)

    def build_ahead(self) -> None:
        """Make the steps after the one under way (`STEPS_AHEAD`), away from the refills."""
        if not self.finished:
            self.steps.build_until(self.index + STEPS_AHEAD)

    def prepare(self, lead_s: float) -> None:
        """Plan one window ahead, here and now (what the planner's worker thread does away from the refills)."""
        self.build_ahead()
        job = self.plan_job(lead_s)
        if job is not None:
            job.compute()
            job.stream.accept(job)

    def planned_ticks(self) -> int:
        """Servo periods the whole program takes at 100 % override, from its first record to its last
        (program stops not counted): its timing (`ProgramTiming`), made now if it was not given."""
        return self._timing().total_ticks

    def _timing(self) -> ProgramTiming:
        if self.timing is None:
            if self._again is None:
                raise RuntimeError("a runner of a step source is given its timing (ProgramTiming) with it")
            self.timing = ProgramTiming(self.dt, self.corners).compute(self._again())
        if self.timing.failure is not None:
            raise self.timing.failure
        return self.timing

    def remaining_s(self) -> float:
        """Time the records still to be made take, from the planned profile: exact at 100 % override;
        below it, the time stretched by 1 / override (feeds and rapids slow alike); above it, unchanged
        (the axis limits, not the feed, then decide where the time goes). Infinite at 0 %; NaN while
        the program's timing is still being made."""
        if self.finished:
            return 0.0
        if self.override <= 0.0:
            return float("inf")
        timing = self._timing() if self.timing is None else self.timing
        i = max(self.index, 0)
        if not timing.complete or i >= len(timing.step_ticks):
            return float("nan")
        now = timing.step_ticks[i] - (self.stream.k if self.stream is not None else timing.step_ticks[i] - self.pause_left)
        now += self.overlap_left
        ticks = timing.remaining_ticks(i, max(now, 0)) + self.repierce
        seconds = ticks * self.dt
        return seconds / self.override if self.override < 1.0 else seconds
