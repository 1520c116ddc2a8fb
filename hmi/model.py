"""The operator screen's state in pure Python: what the controller last said, kept for the views."""

from __future__ import annotations

import enum
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Protocol

import msgspec

from cnc.bus.messages import (
    ActiveAlarm, AlarmEvent, AlarmList, HistoryPage, LockState, Position, ProcedureCatalogue, ProcedureInfo,
    ProcedureState, ProgramInfo, ProgramPath, SimInputs, Status,
)
from cnc.bus.states import AlarmLevel, CyclePhase, LinkState, MachineState, Mode, PlannerState, RunResult, ServoFault

from .observable import Observable

TOPICS = ("status", "position", "alarms", "history", "procedure", "catalogue", "sim", "lock", "program", "connection", "screen",
          "error")
HISTORY_KEPT = 20000  # entries of the message history held in memory (the oldest go first)
LATCHED_LEVELS = tuple(level.text for level in AlarmLevel if level.latched)  # listed, cleared, until reset (the alarm book's rule)

_FAULTED = (MachineState.FAULT.name, MachineState.ESTOP.name)  # a fault waits for the operator
_STOPS_CUT = tuple(level.text for level in AlarmLevel if level.stops_cut)


class Screen(enum.Enum):
    """The page the operator screen shows, derived from the machine state (the window structure)."""

    OFFLINE = "offline"  # no controller heard from
    MANUAL = "manual"
    AUTO = "auto"
    PROCEDURE = "procedure"  # a guided procedure runs
    FAULT = "fault"  # FAULT or ESTOP: the alarms and the reset come first


class _AxisTravel(Protocol):
    travel_min_mm: float
    travel_max_mm: float


class TravelSource(Protocol):
    """What the model reads of a machine configuration (cnc.config.MachineConfig fits): the axes'
    travel. A protocol, not an import: the HMI reaches the controller only through cnc.bus."""

    axis: Mapping[str, _AxisTravel]


@dataclass(frozen=True)
class LoadedProgram:
    """The program the controller has loaded, as the preview shows it."""

    name: str
    hash: str
    text: str
    path: ProgramPath | None  # the interpreted path, when it was asked for (?path=1)
    segments: int  # rows of the interpreted path (0 when the path is not known)


def _unstamped(msg: msgspec.Struct) -> msgspec.Struct:
    """The message without its sequence number and stamps: what a view shows of it."""
    return msgspec.structs.replace(msg, seq=0, stamp_ns=0, tick=0)


class MachineModel(Observable):
    """Everything an operator screen shows, updated by `apply_*` from bus messages (observers:
    see `Observable`; topics: TOPICS)."""

    def __init__(self, station: str, config: TravelSource | None = None) -> None:
        super().__init__(TOPICS)
        self.station = station
        self.travel_mm: dict[str, tuple[float, float]] = (
            {} if config is None else {name: (a.travel_min_mm, a.travel_max_mm) for name, a in config.axis.items()}
        )
        self._status: Status | None = None
        self._position: Position | None = None
        self._active: dict[tuple[str, str], ActiveAlarm] = {}
        self._history: dict[int, AlarmEvent] = {}
        self._procedure: ProcedureState | None = None
        self._catalogue: list[ProcedureInfo] = []
        self._sim: SimInputs | None = None  # the simulated machine's inputs; None: not a simulated machine
        self._holder = ""
        self._stations: list[str] = []
        self._program: LoadedProgram | None = None
        self._reachable = False
        self._error = ""

    def _update(self, change: Callable[[], Iterable[str]]) -> None:
        """Apply `change` under the lock; it returns the topics it changed. The screen topic
        follows whenever the derived screen name moves."""
        with self._lock:
            screen = self._screen()
            changed = list(change())
            if self._screen() != screen:
                changed.append("screen")
        self._notify(changed)

    # -- applying what the controller says -----------------------------------------------------

    def apply_status(self, status: Status) -> None:
        """The cyclic status; also names the lock holder (a missed lock message is corrected here)."""
        def change() -> list[str]:
            changed = []
            if self._status is None or _unstamped(self._status) != _unstamped(status):
                changed.append("status")
            self._status = status
            travel = {a.name: (a.travel_min_mm, a.travel_max_mm) for a in status.axes if a.travel_max_mm > a.travel_min_mm}
            if travel and travel != self.travel_mm:
                self.travel_mm = travel  # the controller's word on its travel replaces any local file's
            if status.operator != self._holder:
                self._holder = status.operator
                changed.append("lock")
            return changed
        self._update(change)

    def apply_position(self, position: Position) -> None:
        def change() -> list[str]:
            old, self._position = self._position, position
            return ["position"] if old is None or _unstamped(old) != _unstamped(position) else []
        self._update(change)

    def apply_alarm(self, event: AlarmEvent) -> None:
        """One live alarm event: into the history, and its effect on the active list (the alarm
        book's rules: an alarm is its id and detail; warnings and worse stay listed, cleared, until
        reset). Info-level entries are one-shot messages or prompts: they leave the list when
        cleared and enter it only through `apply_active` (an event cannot tell the two apart)."""
        def change() -> list[str]:
            changed = self._add_history([event])
            if self._apply_to_active(event):
                changed.append("alarms")
            return changed
        self._update(change)

    def _apply_to_active(self, e: AlarmEvent) -> bool:
        key = (e.id, e.detail)
        old = self._active.get(key)
        if e.action == "raised":
            if e.level not in LATCHED_LEVELS:
                return False
            self._active[key] = ActiveAlarm(e.code, e.id, e.level, e.text, e.detail, e.source, e.seq, e.stamp_ns,
                                            active=True, acknowledged=False)
        elif old is None:
            return False
        elif e.action == "reset" or (e.action == "cleared" and old.level not in LATCHED_LEVELS):
            del self._active[key]
        elif e.action == "cleared":
            self._active[key] = msgspec.structs.replace(old, active=False)
        elif e.action == "acknowledged":
            self._active[key] = msgspec.structs.replace(old, acknowledged=True)
        return self._active.get(key) != old

    def apply_active(self, alarms: AlarmList) -> None:
        """The controller's active list (a query's answer): it replaces what the events built."""
        def change() -> list[str]:
            new = {(a.id, a.detail): a for a in alarms.alarms}
            old, self._active = self._active, new
            return ["alarms"] if new != old else []
        self._update(change)

    def apply_history(self, page: HistoryPage) -> None:
        """History entries (a query's page): merged by sequence number, repeats ignored."""
        self._update(lambda: self._add_history(page.entries))

    def _add_history(self, entries: Iterable[AlarmEvent]) -> list[str]:
        new = [e for e in entries if e.seq not in self._history]
        for e in new:
            self._history[e.seq] = e
        if len(self._history) > HISTORY_KEPT:
            for seq in sorted(self._history)[: len(self._history) - HISTORY_KEPT]:
                del self._history[seq]
        return ["history"] if new else []

    def apply_procedure(self, procedure: ProcedureState) -> None:
        def change() -> list[str]:
            old, self._procedure = self._procedure, procedure
            return ["procedure"] if old != procedure else []
        self._update(change)

    def apply_catalogue(self, catalogue: ProcedureCatalogue) -> None:
        """The guided procedures the operator may start."""
        def change() -> list[str]:
            old, self._catalogue = self._catalogue, list(catalogue.procedures)
            return ["catalogue"] if old != self._catalogue else []
        self._update(change)

    def apply_sim_inputs(self, inputs: SimInputs | None) -> None:
        """The simulated machine's inputs and their values (None: the machine is not simulated)."""
        def change() -> list[str]:
            old, self._sim = self._sim, inputs
            return ["sim"] if old != inputs else []
        self._update(change)

    def apply_lock(self, lock: LockState) -> None:
        def change() -> list[str]:
            old = (self._holder, self._stations)
            self._holder, self._stations = lock.holder, list(lock.stations)
            return ["lock"] if old != (self._holder, self._stations) else []
        self._update(change)

    def apply_program(self, info: ProgramInfo) -> None:
        """The loaded program (name, hash, text, and the interpreted path when it came with it)."""
        def change() -> list[str]:
            segments = len(info.path.kind) if info.path is not None else 0
            new = LoadedProgram(info.name, info.hash, info.text, info.path, segments)
            old, self._program = self._program, new
            return ["program"] if old != new else []
        self._update(change)

    def set_reachable(self, reachable: bool) -> None:
        """Whether the controller is heard from (the connection's watchdog decides)."""
        def change() -> list[str]:
            old, self._reachable = self._reachable, reachable
            return ["connection"] if old != reachable else []
        self._update(change)

    def set_error(self, text: str) -> None:
        """A problem the operator must see that is not an alarm (a message this HMI cannot read)."""
        def change() -> list[str]:
            old, self._error = self._error, text
            return ["error"] if old != text else []
        self._update(change)

    # -- reading -------------------------------------------------------------------------------

    @property
    def status(self) -> Status | None:
        with self._lock:
            return self._status

    @property
    def position(self) -> Position | None:
        with self._lock:
            return self._position

    @property
    def active_alarms(self) -> list[ActiveAlarm]:
        """The alarms raised and not reset, oldest first."""
        with self._lock:
            return sorted(self._active.values(), key=lambda a: a.raised_seq)

    @property
    def last_seq(self) -> int:
        """The newest history entry held (0 when none): where a catch-up query starts."""
        with self._lock:
            return max(self._history, default=0)

    @property
    def procedure(self) -> ProcedureState | None:
        with self._lock:
            return self._procedure

    @property
    def sim_inputs(self) -> SimInputs | None:
        with self._lock:
            return self._sim

    @property
    def catalogue(self) -> list[ProcedureInfo]:
        with self._lock:
            return list(self._catalogue)

    @property
    def lock_holder(self) -> str:
        """The station holding the command lock ("" nobody)."""
        with self._lock:
            return self._holder

    @property
    def stations(self) -> list[str]:
        with self._lock:
            return list(self._stations)

    @property
    def holds_lock(self) -> bool:
        with self._lock:
            return self._holder == self.station

    @property
    def read_only(self) -> bool:
        """This station only watches: another station, or nobody, holds the command lock."""
        return not self.holds_lock

    @property
    def program(self) -> LoadedProgram | None:
        with self._lock:
            return self._program

    @property
    def program_outdated(self) -> bool:
        """The status names a program other than the one held: the connection fetches it."""
        with self._lock:
            running = self._status.program if self._status is not None else None
            if running is None or not running.hash:
                return False
            return self._program is None or self._program.hash != running.hash

    @property
    def reachable(self) -> bool:
        with self._lock:
            return self._reachable

    @property
    def caught_up(self) -> bool:
        """The screen shows what the controller says: reachable, its status and position in, the
        history up to the status's newest entry, and the program the status names."""
        with self._lock:  # re-entrant: the properties below take it too
            st = self._status
            return (self._reachable and st is not None and self._position is not None and self.last_seq >= st.alarm_seq
                    and not self.program_outdated)

    @property
    def error(self) -> str:
        """The last problem that is not an alarm ("" none), e.g. a schema version mismatch."""
        with self._lock:
            return self._error

    @property
    def screen(self) -> Screen:
        with self._lock:
            return self._screen()

    def _screen(self) -> Screen:
        st = self._status
        if st is None or not self._reachable:
            return Screen.OFFLINE
        if st.machine_state in _FAULTED:
            return Screen.FAULT
        if self._procedure_shown(st):
            return Screen.PROCEDURE
        return Screen.AUTO if st.mode == Mode.AUTO.name else Screen.MANUAL

    def _procedure_shown(self, st: Status) -> bool:
        """A procedure takes the screen while it runs, and afterwards until the operator ends it,
        unless the automatic cycle started it and carries on by itself once it is done."""
        p = self._procedure
        if p is None or not p.id:
            return False
        if p.state == "running":
            return True
        return bool(st.procedure) and not (p.by_cycle and p.state == "done")

    def segment_states(self) -> int:
        """The index of the segment being cut: [0, index) are cut, index is being cut, the rest
        are to cut. -1 before the first segment; the segment count once the run ended DONE and the
        planner is idle (the position may still name the last segment). The latest position's
        segment is used (50 Hz), else the status's."""
        with self._lock:
            segments = self._program.segments if self._program is not None else 0
            progress = self._status.program if self._status is not None else None
            if self._position is not None:
                current = self._position.segment
            elif progress is not None:
                current = progress.segment
            else:
                return -1
            if progress is not None and progress.result == RunResult.DONE.name and (
                    current < 0 or self._status.planner_state == PlannerState.IDLE.name):
                return segments
            return min(current, segments) if segments else current

    def history_view(
        self, text: str = "", levels: Iterable[str] | None = None, codes: Iterable[int] | None = None
    ) -> list[AlarmEvent]:
        """The message history, newest first, filtered: `text` (any case) in the text, detail, id
        or code; `levels` and `codes` restrict to those (None: all)."""
        needle = text.strip().lower()
        level_set = None if levels is None else {lv.lower() for lv in levels}
        code_set = None if codes is None else set(codes)
        with self._lock:
            entries = [self._history[s] for s in sorted(self._history, reverse=True)]
        return [
            e for e in entries
            if (level_set is None or e.level in level_set)
            and (code_set is None or e.code in code_set)
            and (not needle or needle in f"{e.text}\n{e.detail}\n{e.id}\n{e.code}".lower())
        ]

    # -- what the status panels derive --------------------------------------------------------

    def plc_state(self) -> PlcState:
        """The external PLC's automatic operation as the paper's screen names it: STOPPED (link
        down or the PLC not in automatic operation), STARTED (automatic operation, idle) or
        RUNNING (its transport sequence, or the automatic cycle, is under way)."""
        with self._lock:
            st = self._status
            if st is None or st.plc_link != LinkState.OK.name or not st.plc_inputs.get("plc_running", 0.0):
                return PlcState.STOPPED
            busy = st.plc_inputs.get("transport_step", 0.0) > 0 or st.cycle_phase not in (CyclePhase.NONE.name, CyclePhase.PROCEDURE.name)
            return PlcState.RUNNING if busy else PlcState.STARTED

    def needs_reset(self) -> bool:
        """A fault waits for the operator's reset: the machine is in FAULT or ESTOP, the servo
        tripped, or an alarm is latched (its condition gone, the reset still owed)."""
        with self._lock:
            st = self._status
            if st is not None and (st.machine_state in _FAULTED or st.fault != ServoFault.NONE.name):
                return True
            return any(a.level in LATCHED_LEVELS for a in self._active.values())

    def faults(self) -> list[str]:
        """What is wrong right now, one line each: the conditions the status shows (e-stop, doors,
        servo fault, drives, limits, PLC link and alarms, pump) and the error alarms still active.
        Unlike the alarm list, a fault leaves this list as soon as its cause is gone."""
        with self._lock:
            st = self._status
            found: list[str] = []
            if st is not None:
                found += _status_faults(st)
            found += [f"{a.code} {a.text}" + (f": {a.detail}" if a.detail else "")
                      for a in sorted(self._active.values(), key=lambda a: a.raised_seq)
                      if a.active and a.level in _STOPS_CUT]
            return found


class PlcState(enum.Enum):
    """The external PLC's automatic operation (the paper's PLC state field)."""

    STOPPED = "stopped"
    STARTED = "started"
    RUNNING = "running"


def plc_link_text(st: Status) -> str:
    """The PLC link lamp's text: its state, and since the link process started the exchanges
    that got no valid answer and the answers dropped as late, when there were any (a link that
    stays OK while it loses exchanges is a line to look at)."""
    told = []
    if st.plc_failed:
        told.append(f"{st.plc_failed} of {st.plc_exchanges + st.plc_failed} exchanges failed")
    if st.plc_dropped:
        told.append(f"{st.plc_dropped} late answer{'s' if st.plc_dropped != 1 else ''} dropped")
    return st.plc_link + (f" ({', '.join(told)} since start)" if told else "")


def _status_faults(st: Status) -> list[str]:
    found = []
    if not st.estop_ok:
        found.append("Emergency stop pressed (or the safety circuit is open)")
    if not st.doors_closed:
        found.append("Safety door open")
    if st.fault != ServoFault.NONE.name:
        found.append(f"Servo fault {st.fault}" + (f" on axis {st.fault_axis.upper()}" if st.fault_axis else ""))
    if st.watchdog_tripped:
        found.append("Drive watchdog tripped")
    for a in st.axes:
        if not a.drive_ready:
            found.append(f"Axis {a.name.upper()}: drive not ready")
        if a.limit_min or a.limit_max:
            found.append(f"Axis {a.name.upper()}: {'minimum' if a.limit_min else 'maximum'} limit switch")
    if st.plc_link != LinkState.OK.name:
        found.append(f"PLC link {st.plc_link}")
    else:
        if st.plc_inputs.get("plc_alarm", 0.0):
            found.append(f"PLC alarm {int(st.plc_inputs['plc_alarm'])}")
        if st.plc_inputs.get("pump_fault", 0.0):
            found.append("High-pressure pump fault")
        if "safety_circuit_ok" in st.plc_inputs and not st.plc_inputs["safety_circuit_ok"]:
            found.append("Safety circuit open (PLC)")
    return found
