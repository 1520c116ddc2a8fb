"""The Qt adapter delivers the model's changes on the GUI thread, coalescing bursts."""

from __future__ import annotations

import threading

from PySide6.QtCore import QThread

from cnc.bus.messages import Position
from hmi.adapter import ModelAdapter
from hmi.model import MachineModel


def position(seq: int, segment: int) -> Position:
    return Position(seq=seq, stamp_ns=seq, tick=seq, position_mm=[float(segment), 0.0], commanded_mm=[0.0, 0.0],
                    velocity_mm_s=[0.0, 0.0], segment=segment, line=segment, jet_on=False)


def test_changes_made_on_another_thread_arrive_on_the_gui_thread_once_per_burst(qtbot):
    model = MachineModel("panel")
    adapter = ModelAdapter(model)
    seen: list[tuple[int, bool]] = []
    gui = QThread.currentThread()
    adapter.position.connect(lambda: seen.append((model.position.segment, QThread.currentThread() is gui)))

    def burst() -> None:
        for k in range(1, 201):
            model.apply_position(position(k, k))

    worker = threading.Thread(target=burst)
    with qtbot.waitSignal(adapter.position, timeout=5000):
        worker.start()
        worker.join()
    qtbot.wait(50)
    assert seen and all(on_gui for _, on_gui in seen), "delivered on the GUI thread"
    assert len(seen) < 200, "a burst coalesces"
    assert seen[-1][0] == 200, "the last delivery shows the latest state"
    adapter.close()
    model.apply_position(position(201, 201))
    qtbot.wait(50)
    assert seen[-1][0] == 200, "nothing after close"
