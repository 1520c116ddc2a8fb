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


class _SlowUploads:
    """A command sink whose program uploads take until `release` is set (a million-line program)."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.order: list[str] = []

    def command(self, msg):
        from cnc.bus.messages import Reply, UploadProgram

        if isinstance(msg, UploadProgram):
            self.release.wait(30.0)
        self.order.append(type(msg).__name__)
        return Reply(True)


def test_a_long_program_upload_does_not_hold_up_the_operators_other_commands(qtbot):
    from cnc.bus.messages import Hold, Reset, UploadProgram
    from hmi.commands import CommandRunner

    sink = _SlowUploads()
    runner = CommandRunner(sink)
    upload = runner.send(UploadProgram("big.ngc", "G0 X1\n"))
    hold, reset = runner.send(Hold()), runner.send(Reset())
    assert hold.result(10.0).ok and reset.result(10.0).ok, "hold and reset answered while the upload runs"
    assert sink.order == ["Hold", "Reset"] and not upload.done()
    sink.release.set()
    assert upload.result(10.0).ok and sink.order[-1] == "UploadProgram"
    runner.close()
