"""The Qt adapter: the model's changes as typed Qt signals, delivered on the GUI thread.

The model's callbacks run on whatever thread applied a message (a Zenoh callback thread, the
connection's worker). Widgets must only be touched on the GUI thread, so each callback emits a
signal of this QObject, which lives on the GUI thread: Qt queues a cross-thread emission and
delivers it there. Widgets take the adapter in their constructor and connect to its signals.
Bursts coalesce: one pending delivery per topic, so a 50 Hz position stream never piles up
behind a slow frame.
"""

from __future__ import annotations

import threading

from PySide6.QtCore import QObject, Qt, Signal, Slot

from .model import MachineModel
from .observable import Observable
from .tuning_model import TuningModel


class TopicAdapter(QObject):
    """The mechanism: subclasses declare one signal per topic of the model they adapt."""

    _deliver = Signal(str)  # internal: a topic changed, crossing to the GUI thread

    def __init__(self, model: Observable, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.model = model
        self._pending: set[str] = set()
        self._mutex = threading.Lock()
        self._deliver.connect(self._on_deliver, Qt.ConnectionType.QueuedConnection)
        self._unsubscribe = [model.subscribe(topic, lambda t=topic: self._changed(t)) for topic in model.topics]

    def _changed(self, topic: str) -> None:
        """Any thread: ask for one delivery of `topic` unless one is already on its way."""
        with self._mutex:
            if topic in self._pending:
                return
            self._pending.add(topic)
        self._deliver.emit(topic)

    @Slot(str)
    def _on_deliver(self, topic: str) -> None:
        """GUI thread: the topic's signal, once for however many changes came meanwhile."""
        with self._mutex:
            self._pending.discard(topic)
        getattr(self, topic).emit()

    def close(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe = []


class ModelAdapter(TopicAdapter):
    """Signals named after the machine model's topics; each says "this changed, read the model"."""

    status = Signal()
    position = Signal()
    alarms = Signal()
    history = Signal()
    procedure = Signal()
    catalogue = Signal()
    sim = Signal()
    lock = Signal()
    program = Signal()
    connection = Signal()
    screen = Signal()
    error = Signal()

    def __init__(self, model: MachineModel, parent: QObject | None = None) -> None:
        super().__init__(model, parent)
        self.model: MachineModel = model


class TuningAdapter(TopicAdapter):
    """Signals of the tuning model's topics (parameters, the logger's state, the live stream)."""

    params = Signal()
    logstate = Signal()
    live = Signal()

    def __init__(self, model: TuningModel, parent: QObject | None = None) -> None:
        super().__init__(model, parent)
        self.model: TuningModel = model
