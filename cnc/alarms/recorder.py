"""Off the scan: alarm entries are stored and published, in order, by a worker thread of their own.

The control logic scans every few milliseconds and the tick watches its heartbeat: it must never
wait for an fsync or a Zenoh put. The alarm book hands each entry (already numbered, already in
the active list) to a `Recorder`, whose thread commits it to the history and only then publishes
it, so a subscriber still never hears of an entry the file could lose, and entries keep their
order. Other slow output of the logic (its procedure publications) queues on the same thread.
An entry queued but not yet committed when the process is killed is lost: the tick has already
made the machine safe by then; the history says what it could.
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import Callable

log = logging.getLogger(__name__)


class Recorder:
    """A worker thread that runs queued work in order; `close()` runs what is queued, then ends."""

    def __init__(self, name: str = "recorder") -> None:
        self.work: queue.SimpleQueue = queue.SimpleQueue()
        self.committed_seq = 0  # the newest alarm entry stored and published
        self.failures = 0
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def submit(self, job: Callable[[], None]) -> None:
        self.work.put(job)

    def _run(self) -> None:
        while (job := self.work.get()) is not None:
            try:
                job()
            except Exception:  # a broken disk or bus: said in the log, and the next entries still go
                self.failures += 1
                log.exception("recorder: storing or publishing failed")

    def drain(self, timeout_s: float = 5.0) -> bool:
        """Wait until everything queued so far has run; False when it did not within `timeout_s`."""
        done = threading.Event()
        self.work.put(done.set)
        return done.wait(timeout_s)

    def close(self, timeout_s: float = 5.0) -> None:
        self.work.put(None)
        self.thread.join(timeout_s)
