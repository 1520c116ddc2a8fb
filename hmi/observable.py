"""Models the Qt views observe by topic, without importing Qt: `subscribe(topic, callback)`."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable

log = logging.getLogger(__name__)


class Observable:
    """Observers `subscribe(topic, callback)`; a callback runs only when what its topic shows
    changed, after the model's lock is released, on the thread that applied the change: Zenoh
    callbacks arrive on Zenoh's threads, so a Qt view must marshal to its own thread (a queued
    signal, `hmi.adapter`). All reads and writes hold one lock, so any thread may read at any time."""

    def __init__(self, topics: Iterable[str]) -> None:
        self.topics = tuple(topics)
        self._lock = threading.RLock()
        self._observers: dict[str, list[Callable[[], None]]] = {t: [] for t in self.topics}

    def subscribe(self, topic: str, callback: Callable[[], None]) -> Callable[[], None]:
        """Call `callback()` whenever `topic` changes; returns the unsubscribe."""
        if topic not in self._observers:
            raise ValueError(f"topic {topic!r} is not one of: {', '.join(self.topics)}")
        with self._lock:
            self._observers[topic].append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._observers[topic]:
                    self._observers[topic].remove(callback)
        return unsubscribe

    def _notify(self, topics: Iterable[str]) -> None:
        """Run the callbacks of the changed topics (outside the lock: a callback may read the model).
        A view's exception is logged with its traceback and does not stop the other views."""
        for topic in dict.fromkeys(topics):
            with self._lock:
                callbacks = list(self._observers[topic])
            for callback in callbacks:
                try:
                    callback()
                except Exception:
                    log.exception("the %r observer %r failed", topic, callback)
