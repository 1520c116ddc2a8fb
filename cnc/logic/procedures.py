"""Guided procedures: walk the operator through ordered steps, ticking each off as it is met.

A procedure (`[[procedure]]` in the machine file) is the paper's procedure window: a title
and a list of steps. The awaited step shows its instruction; a step completes when its
condition holds (checked every logic scan) or, for `action = "confirm"`, when the operator
confirms it. Steps are ticked off in order, several in one scan when their conditions already
hold. A step waiting longer than its `timeout_s` raises its `timeout_alarm` once and is shown
timed out, but it keeps waiting and completes when its condition comes.

The runner is pure logic: signals come in as a mapping, time as monotonic seconds, alarms go
out through the `raise_alarm(alarm_id, detail)` callable it is given. It publishes what the
operator sees as a `ProcedureState` whose `seq` grows by one at every change.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from cnc.bus.messages import ProcedureState, ProcedureStep
from cnc.bus.service import CommandRefused
from cnc.config import ProcedureConfig, ProcedureStepConfig
from cnc.logic.conditions import Condition, ConditionError, compile_condition

PENDING, AWAITED, DONE, TIMED_OUT = "pending", "awaited", "done", "timed_out"  # ProcedureStep.state
IDLE, RUNNING, STOPPED = "idle", "running", "stopped"  # ProcedureState.state, with DONE, TIMED_OUT


class _Step:
    """A configured step with its compiled condition (None for an operator action)."""

    __slots__ = ("config", "condition")

    def __init__(self, config: ProcedureStepConfig, condition: Condition | None) -> None:
        self.config, self.condition = config, condition


class ProcedureRunner:
    """Runs one guided procedure at a time and keeps the window the operator sees.

    Life of the window: idle -> `start(id)` -> running (timed_out while the awaited step is
    over its time) -> done when the last step completes, or stopped by `stop()` -> `end()`
    closes the window, back to idle. Call `scan(signals, now_s)` every logic scan.
    """

    def __init__(
        self,
        procedures: list[ProcedureConfig],
        raise_alarm: Callable[[str, str], None],
        known_signals: Iterable[str] | None = None,
        source: str = "",
    ) -> None:
        """Compile every condition now, so that a bad machine file fails at start-up with a
        `ConditionError` naming `source`, the procedure and the step."""
        self._raise_alarm = raise_alarm
        known = None if known_signals is None else frozenset(known_signals)
        self._procedures: dict[str, ProcedureConfig] = {}
        self._steps: dict[str, list[_Step]] = {}
        for k, proc in enumerate(procedures, start=1):
            where = f"{source + ': ' if source else ''}[[procedure]] #{k} ({proc.id})"
            if proc.id in self._procedures:
                raise ConditionError(where, f"procedure id {proc.id!r} is declared twice")
            if not proc.step:
                raise ConditionError(where, "a procedure needs at least one step")
            self._procedures[proc.id] = proc
            self._steps[proc.id] = [_compile_step(st, known, f"{where} step #{j}") for j, st in enumerate(proc.step, start=1)]
        self._last_run: dict[str, list[str]] = {}  # step states of each procedure's last run
        self._completed: dict[str, bool] = {}
        self._proc: ProcedureConfig | None = None  # the procedure in the window
        self._by_cycle = False  # the automatic cycle opened the window
        self._status = IDLE
        self._step_states: list[str] = []
        self._awaited = -1
        self._awaited_since_s: float | None = None  # set by the first scan that sees the step awaited
        self._seq = 0
        self._published: ProcedureState | None = None

    # -- queries ---------------------------------------------------------------------------

    @property
    def ids(self) -> tuple[str, ...]:
        """The ids of the configured procedures, in machine-file order."""
        return tuple(self._procedures)

    @property
    def running(self) -> bool:
        """Whether a procedure is being walked (also while its awaited step is timed out)."""
        return self._status in (RUNNING, TIMED_OUT)

    def done(self, procedure_id: str) -> bool:
        """Whether the last run of this procedure completed all its steps (an unknown id is refused)."""
        self._known(procedure_id)
        return self._completed.get(procedure_id, False)

    def state(self) -> ProcedureState:
        """The window as the operator sees it; a new `seq` means something changed."""
        if self._published is None:
            self._published = self._build_state()
        return self._published

    def still_holds(self, signals: Mapping[str, object], procedure_id: str | None = None) -> list[tuple[int, str]]:
        """The steps recorded done whose conditions are false now, as (index, text).

        Done steps stay done in the window (it records what was checked); the automatic cycle
        calls this as an interlock check. `procedure_id` picks the last run of that procedure;
        by default the procedure in the window (none: an empty list).
        """
        pid = procedure_id if procedure_id is not None else (self._proc.id if self._proc else None)
        if pid is None:
            return []
        self._known(pid)
        states = self._last_run.get(pid, [])
        steps = self._steps[pid]
        return [
            (i, steps[i].config.text)
            for i, st in enumerate(states)
            if st == DONE and steps[i].condition is not None and not steps[i].condition.evaluate(signals)
        ]

    # -- commands --------------------------------------------------------------------------

    def start(self, procedure_id: str, by_cycle: bool = False) -> None:
        """Open the window on this procedure, its first step awaited (`by_cycle`: the automatic
        cycle asked for it, and goes on by itself once it is done)."""
        self._known(procedure_id)
        if self.running:
            assert self._proc is not None
            running = f"procedure {self._proc.id!r} ({self._proc.title})"
            if self._proc.id == procedure_id:
                raise CommandRefused(f"{running} is already running")
            raise CommandRefused(f"cannot start procedure {procedure_id!r}: {running} is running; stop it first")
        self._proc = self._procedures[procedure_id]
        self._by_cycle = by_cycle
        self._step_states = [PENDING] * len(self._steps[procedure_id])
        self._last_run[procedure_id] = self._step_states
        self._completed[procedure_id] = False
        self._status = RUNNING
        self._await(0, None)
        self._changed()

    def scan(self, signals: Mapping[str, object], now_s: float) -> bool:
        """Advance the running procedure at time `now_s` (monotonic seconds): tick off every
        step in a row whose condition holds, then watch the awaited step's timeout.
        Returns whether the published state changed."""
        if not self.running:
            return False
        assert self._proc is not None
        steps = self._steps[self._proc.id]
        changed = False
        while self._awaited >= 0:
            cond = steps[self._awaited].condition
            if cond is None or not cond.evaluate(signals):
                break
            self._complete_awaited(now_s)
            changed = True
        if self._awaited >= 0:
            if self._awaited_since_s is None:
                self._awaited_since_s = now_s
            changed = self._watch_timeout(steps[self._awaited].config, now_s) or changed
        if changed:
            self._changed()
        return changed

    def confirm(self) -> None:
        """The operator confirms the awaited step; only for steps with `action = "confirm"`."""
        if not self.running:
            raise CommandRefused("nothing to confirm: no procedure is running")
        assert self._proc is not None
        step = self._steps[self._proc.id][self._awaited]
        if step.condition is not None:
            raise CommandRefused(
                f"step {self._awaited + 1} ({step.config.text}) of {self._proc.id!r} completes by its condition "
                f"{step.condition.text!r}, not by confirmation"
            )
        self._complete_awaited(None)
        self._changed()

    def stop(self, why: str = "stopped by the operator") -> None:
        """The operator stops the procedure (or the cycle that opened it ends: `why` says so): the
        window shows it stopped, alarm procedure_stop is raised."""
        if not self.running:
            raise CommandRefused("nothing to stop: no procedure is running")
        assert self._proc is not None
        at = self._where_awaited()
        if self._step_states[self._awaited] == AWAITED:
            self._step_states[self._awaited] = PENDING
        self._status = STOPPED
        self._awaited = -1
        self._changed()
        self._raise_alarm("procedure_stop", f"{at} {why}")

    def end(self) -> None:
        """Close the window after the procedure is done or stopped; the window goes idle."""
        if self.running:
            assert self._proc is not None
            raise CommandRefused(f"cannot end procedure {self._proc.id!r} while it runs; stop it first")
        if self._proc is None:
            raise CommandRefused("no procedure window to end")
        self._proc = None
        self._status = IDLE
        self._step_states = []
        self._awaited = -1
        self._changed()

    # -- internals -------------------------------------------------------------------------

    def _known(self, procedure_id: str) -> None:
        if procedure_id not in self._procedures:
            known = ", ".join(self._procedures) or "(none configured)"
            raise CommandRefused(f"unknown procedure {procedure_id!r}; known: {known}")

    def _await(self, index: int, now_s: float | None) -> None:
        self._awaited = index
        self._awaited_since_s = now_s
        if index >= 0:
            self._step_states[index] = AWAITED

    def _complete_awaited(self, now_s: float | None) -> None:
        """Mark the awaited step done and await the next one, or finish the procedure."""
        assert self._proc is not None
        self._step_states[self._awaited] = DONE
        self._status = RUNNING
        nxt = self._awaited + 1
        if nxt < len(self._step_states):
            self._await(nxt, now_s)
        else:
            self._await(-1, None)
            self._status = DONE
            self._completed[self._proc.id] = True

    def _watch_timeout(self, step: ProcedureStepConfig, now_s: float) -> bool:
        """Raise the step's timeout alarm once when it has waited `timeout_s`; the step keeps waiting."""
        if step.timeout_s <= 0 or self._step_states[self._awaited] == TIMED_OUT:
            return False
        assert self._awaited_since_s is not None
        if now_s - self._awaited_since_s < step.timeout_s:
            return False
        self._step_states[self._awaited] = TIMED_OUT
        self._status = TIMED_OUT
        self._raise_alarm(
            step.timeout_alarm,
            f"{self._where_awaited()} not completed after {step.timeout_s:g} s: {step.instruction or step.text}",
        )
        return True

    def _where_awaited(self) -> str:
        assert self._proc is not None
        n = len(self._step_states)
        text = self._proc.step[self._awaited].text
        return f"procedure {self._proc.id!r} ({self._proc.title}) step {self._awaited + 1}/{n} ({text})"

    def _changed(self) -> None:
        self._seq += 1
        self._published = None

    def _build_state(self) -> ProcedureState:
        if self._proc is None:
            return ProcedureState(id="", title="", state=IDLE, step=-1, steps=[], instruction="", seq=self._seq)
        steps = [
            ProcedureStep(text=s.config.text, state=st, instruction=s.config.instruction, action=s.config.action)
            for s, st in zip(self._steps[self._proc.id], self._step_states)
        ]
        instruction = ""
        if self._awaited >= 0:
            cfg = self._steps[self._proc.id][self._awaited].config
            instruction = cfg.instruction or cfg.text
        return ProcedureState(
            id=self._proc.id, title=self._proc.title, state=self._status, step=self._awaited,
            steps=steps, instruction=instruction, seq=self._seq, by_cycle=self._by_cycle,
        )


def _compile_step(step: ProcedureStepConfig, known: frozenset[str] | None, where: str) -> _Step:
    if step.action == "confirm":
        if step.condition:
            raise ConditionError(where, "give a condition or action = \"confirm\", not both")
        return _Step(step, None)
    if step.action:
        raise ConditionError(where, f"unknown action {step.action!r}; the only action is \"confirm\"")
    if not step.condition:
        raise ConditionError(where, "the step needs a condition or action = \"confirm\"")
    return _Step(step, compile_condition(step.condition, known, f"{where} condition"))
