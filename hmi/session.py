"""One operator screen assembled: model, Zenoh connection, Qt adapter, command runner and window."""

from __future__ import annotations

import gc
import sys
import time
from pathlib import Path

from PySide6.QtCore import QCoreApplication, QEvent, QTimer
from PySide6.QtWidgets import QApplication

from cnc.bus.keys import Keys
from cnc.bus.messages import LockRequest

from .adapter import ModelAdapter, TuningAdapter
from .commands import CommandRunner
from .connection import Connection
from .model import MachineModel
from .tuning import EngineeringWindow
from .tuning_model import TuningModel
from .window import MainWindow


SCREENSHOT_LOOK_MS = 50  # how often a screenshot waiting for the screen to catch up looks again
SCREENSHOT_SETTLE_MS = 300  # from caught up to the grab: the queued updates drawn, the plots' next refresh


class OperatorScreen:
    """The parts of a running screen, in the order they depend on each other; `close()` takes
    them down in reverse (the station's token goes last, so the lock is released cleanly)."""

    def __init__(self, endpoints: list[str], prefix: str, machine: str, station: str,
                 credentials: tuple[str, str] | None = None, tls=None) -> None:
        self.app = QApplication.instance() or QApplication(sys.argv[:1])
        self.model = MachineModel(station)
        self.tuning = TuningModel()
        self.connection = Connection(self.model, endpoints, Keys(prefix, machine), station, credentials,
                                     tuning=self.tuning, tls=tls)
        self.adapter = ModelAdapter(self.model)
        self.tuning_adapter = TuningAdapter(self.tuning)
        self.commands = CommandRunner(self.connection)
        self.window = MainWindow(
            self.adapter, self.commands, ", ".join(endpoints), open_error=lambda: self.connection.last_open_error,
            search_history=self.connection.search_history, library=self.connection,
            engineering=lambda parent: EngineeringWindow(self.adapter, self.tuning_adapter, self.commands,
                                                         self.connection, parent),
        )
        self.connection.start()

    def __enter__(self) -> OperatorScreen:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the commands, the signals and the session, then delete the Qt objects here, on the
        GUI thread: left to Python's garbage collector they could be destroyed on whatever thread
        it runs on (a Zenoh callback's), which Qt does not survive."""
        self.window.close()
        self.commands.close()
        self.adapter.close()
        self.tuning_adapter.close()
        self.connection.close()
        for obj in (self.window, self.commands, self.adapter, self.tuning_adapter):
            obj.deleteLater()
        QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
        gc.collect()

    def take_lock_when_connected(self) -> None:
        """Take the command lock as soon as the controller is reachable (once)."""
        def attempt() -> None:
            if self.model.reachable:
                self.adapter.connection.disconnect(attempt)
                self.commands.send(LockRequest(take=True))
        self.adapter.connection.connect(attempt)
        attempt()

    def screenshot_after(self, seconds: float, out: Path) -> int:
        """Show the window and render it to `out` once it has caught up with the controller (its
        status, position, history and program in, and the window drawn from them), or after
        `seconds` at the latest (an unreachable controller: the screen says so); return 0 (1 when
        it cannot be written)."""
        result = {"code": 1}
        latest = time.monotonic() + seconds

        def grab() -> None:
            out.parent.mkdir(parents=True, exist_ok=True)
            if self.window.grab().save(str(out)):
                result["code"] = 0
                print(f"waterjet hmi: screen written to {out} ({self.model.screen.value}, "
                      f"{'reachable' if self.model.reachable else 'controller unreachable'})", flush=True)
            else:
                print(f"waterjet hmi: cannot write {out}", file=sys.stderr)
            self.app.quit()

        def look() -> None:
            if self.model.caught_up or time.monotonic() >= latest:
                # the model's changes reach the widgets through queued signals: let them land first
                QTimer.singleShot(SCREENSHOT_SETTLE_MS, grab)
            else:
                QTimer.singleShot(SCREENSHOT_LOOK_MS, look)

        self.window.show()
        look()
        self.app.exec()
        return result["code"]
