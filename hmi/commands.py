"""Operator commands sent off the GUI thread, in order, with each answer reported back on the GUI thread.

A command is a round trip to the controller (the gateway checks the lock, the control logic
answers ok or refused with the reason): the screen must never freeze on it. One worker thread
sends the commands in the order the operator gave them, so a jog's stop can never overtake
its start.
"""

from __future__ import annotations

import logging
from concurrent.futures import Future, ThreadPoolExecutor
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import msgspec
from PySide6.QtCore import QObject, Qt, Signal, SignalInstance, Slot
from PySide6.QtWidgets import QWidget

from cnc.bus import messages
from cnc.bus.messages import Reply
from cnc.bus.operator import LOADS

if TYPE_CHECKING:
    from .adapter import ModelAdapter

log = logging.getLogger(__name__)


class CommandSink(Protocol):
    """What sends one command and waits for its answer (`hmi.connection.Connection` fits)."""

    def command(self, msg: msgspec.Struct) -> Reply: ...


def describe(msg: msgspec.Struct) -> str:
    """What a command does, as the operator reads it on the status line ("Take the command lock",
    "Jog Y+ 1 mm at 50 mm/s"): a sentence, never the message's repr."""
    m = messages
    if isinstance(msg, m.LockRequest):
        return "Take the command lock" if msg.take else "Release the command lock"
    if isinstance(msg, m.Jog):
        axis = f"{msg.axis.upper()}{'+' if msg.velocity_mm_s >= 0 else '-'}"
        step = f" {abs(msg.distance_mm):g} mm" if msg.distance_mm else ""
        return f"Jog {axis}{step} at {abs(msg.velocity_mm_s):g} mm/s"
    if isinstance(msg, m.GoTo):
        where = " ".join(f"{a.upper()}{v:g}" for a, v in msg.position_mm.items())
        return f"Go to {where}"
    if isinstance(msg, m.Home):
        return f"Home {', '.join(a.upper() for a in msg.axes)}" if msg.axes else "Home all axes"
    if isinstance(msg, m.Hold):
        return f"Feed hold ({msg.why})" if msg.why else "Feed hold"
    if isinstance(msg, m.CycleStart):
        return f"Cycle start, {msg.cycles} cycles" if msg.cycles > 1 else "Cycle start"
    if isinstance(msg, m.Override):
        return f"Feed override {msg.percent:g} %"
    if isinstance(msg, m.SetMode):
        return f"{msg.mode} mode"
    if isinstance(msg, (m.Drives, m.JetTest)):
        return f"{'Drives' if isinstance(msg, m.Drives) else 'Jet test'} {'on' if msg.on else 'off'}"
    if isinstance(msg, m.Pump):
        return f"Pump on at {msg.pressure_bar:g} bar" if msg.on and msg.pressure_bar else f"Pump {'on' if msg.on else 'off'}"
    if isinstance(msg, m.Acknowledge):
        return f"Acknowledge alarm {msg.code}"
    if isinstance(msg, m.LoadProgram):
        return f"Load program {msg.path}"
    if isinstance(msg, m.UploadProgram):
        return f"Load program {msg.name}"
    if isinstance(msg, m.ProcedureStart):
        return f"Start procedure {msg.id}"
    if isinstance(msg, m.Mdi):
        lines = [line.strip() for line in msg.text.splitlines() if line.strip()]
        text = " / ".join(lines)
        return f"MDI: {text if len(text) <= 60 else text[:57] + '...'}"
    if isinstance(msg, m.ControlRun):
        return f"Control run: {msg.trajectory} for {msg.duration_s:g} s"
    if isinstance(msg, m.ControlSelect):
        return f"Select control program {msg.program} (from the next start)"
    if isinstance(msg, m.Recover):
        if msg.kind == "continue":
            return "Continue the interrupted cut" + (f", {msg.overlap_mm:g} mm back" if msg.overlap_mm is not None else "")
        return f"Start at {msg.kind} {msg.number}"
    if isinstance(msg, m.DeleteProgram):
        return f"Delete program {msg.name}"
    if isinstance(msg, m.CalibrationLadder):
        return f"Speed ladder for {msg.material} {msg.thickness_mm:g} mm"
    if isinstance(msg, m.CalibrationRecord):
        return f"Record the calibration of {msg.material} {msg.thickness_mm:g} mm"
    if isinstance(msg, m.SetCut):
        if not msg.material:
            return "Cutting job: the program's own"
        how = "" if msg.mode == "quality" else ", feed as programmed"
        return f"Cutting job: {msg.material} {msg.thickness_mm:g} mm quality {msg.quality}{how}"
    if isinstance(msg, m.SimInput):
        return f"Simulator: {msg.input.replace('_', ' ')} {msg.value:g}"
    fixed = _FIXED.get(type(msg))
    if fixed is not None:
        return fixed
    words = "".join(f" {c.lower()}" if c.isupper() else c for c in type(msg).__name__).strip()
    return words[:1].upper() + words[1:]


_FIXED: dict[type, str] = {
    messages.Resume: "Resume", messages.Stop: "Stop", messages.Reset: "Reset", messages.JogStop: "Stop jogging",
    messages.StopAll: "Stop all",
    messages.JogRefresh: "Jog held", messages.ProcedureConfirm: "Confirm the procedure step",
    messages.ProcedureStop: "Stop the procedure", messages.ProcedureEnd: "End the procedure",
}
JOG_HELD = _FIXED[messages.JogRefresh]  # ten a second while a jog key is held: not shown on the status line


class CommandRunner(QObject):
    """`send(msg)` queues a command; `replied(label, reply)` follows on the GUI thread."""

    replied = Signal(str, object)  # label, Reply
    _done = Signal(str, object)  # from the worker thread

    def __init__(self, sink: CommandSink, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.sink = sink
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hmi-command")
        # a program upload is answered when the planner has it (minutes for a large one): on its
        # own worker, so that hold, stop, reset and the rest go out meanwhile, in their order
        self._loads = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hmi-upload")
        self._done.connect(self._on_done, Qt.ConnectionType.QueuedConnection)
        self.last: tuple[str, Reply] | None = None  # the latest answer, for the status line and tests

    def send(self, msg: msgspec.Struct, label: str | None = None) -> Future:
        """Queue `msg`; the returned future resolves to its Reply (never raises)."""
        text = label or describe(msg)
        executor = self._loads if isinstance(msg, LOADS) else self._executor
        return executor.submit(self._run, msg, text)

    def call(self, request: Callable[[], Reply], label: str) -> Future:
        """Queue any blocking request that answers with a Reply (a parameter change, a log run)."""
        return self._executor.submit(self._run, request, label)

    def _run(self, msg: msgspec.Struct | Callable[[], Reply], label: str) -> Reply:
        try:
            reply = msg() if callable(msg) else self.sink.command(msg)
        except Exception as exc:  # a bug or a dead session: logged, and the operator sees it refused
            log.exception("command %s failed", label)
            reply = Reply(False, f"{label}: not sent: {exc}")
        self._done.emit(label, reply)
        return reply

    @Slot(str, object)
    def _on_done(self, label: str, reply: Reply) -> None:
        self.last = (label, reply)
        self.replied.emit(label, reply)

    def close(self) -> None:
        """Send what is queued, then stop the workers."""
        self._executor.shutdown(wait=True)
        self._loads.shutdown(wait=True)


class BackgroundQuery:
    """Blocking queries of one panel on a worker thread of its own: `ask(call, deliver)` runs
    `call` there and emits its answer, or the exception it raised (no answer, an error the
    controller sent: shown, never raised), with `deliver`, a signal connected queued, so the answer
    is taken on the GUI thread. `close()` waits for a query under way and takes no more."""

    def __init__(self, name: str) -> None:
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
        self._closed = False

    def ask(self, call: Callable[[], object], deliver: SignalInstance) -> None:
        if self._closed:
            return

        def run() -> None:
            try:
                answer: object = call()
            except Exception as exc:  # noqa: BLE001 - whatever the query met is the answer to show
                answer = exc
            deliver.emit(answer)
        self._worker.submit(run)

    def close(self) -> None:
        self._closed = True
        self._worker.shutdown(wait=True)


def enable_while_commanding(adapter: ModelAdapter, widgets: list[QWidget], extra: Callable[[], bool] | None = None
                            ) -> Callable[[], None]:
    """Keep `widgets` enabled only while this station holds the lock on a reachable controller (and
    `extra()` allows); returns the refresh function, connected to the lock and connection signals."""
    def refresh() -> None:
        m = adapter.model
        can = m.holds_lock and m.reachable and (extra is None or extra())
        for w in widgets:
            w.setEnabled(can)
    adapter.lock.connect(refresh)
    adapter.connection.connect(refresh)
    refresh()
    return refresh
