"""The whole operator screen under a live stream: program load and the cost of each update.

Offscreen, 1600 x 1000, the window on the AUTO page with a 100k-segment nesting program:
- load: the program (text and interpreted path, as the controller's `program?path=1` answers)
  applied to the model, delivered to the window (contour tessellated and fitted, program text
  shown) and the first full render, target < 1 s;
- live updates: positions at 50 Hz walking along the program and a status every 2.5 positions
  (20 Hz), as the Zenoh callbacks apply them; each update is delivered (the adapter's queued
  signals, every view's slot) and repainted the way Qt does it (the regions that changed), at
  whole-sheet zoom and zoomed in; and, as an upper bound, with the whole window rendered again
  (`grab()`) after each. Target: within the 20 ms between two positions (50 Hz).

    QT_QPA_PLATFORM=offscreen python bench/hmi_window.py [--segments N] [--updates N] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(REPO), str(REPO / "bench")]
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

from hmi_contour import program_with_text  # noqa: E402
from PySide6.QtCore import QEvent, QObject  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

from cnc.bus.keys import Keys  # noqa: E402
from cnc.bus.messages import AxisStatus, Position, ProgramInfo, ProgramProgress, Status  # noqa: E402
from hmi.adapter import ModelAdapter  # noqa: E402
from hmi.commands import CommandRunner  # noqa: E402
from hmi.connection import Connection  # noqa: E402
from hmi.model import MachineModel, Screen  # noqa: E402
from hmi.window import MainWindow  # noqa: E402

LOAD_TARGET_S = 1.0
UPDATE_BUDGET_S = 1 / 50  # the position stream's period


def status(seq: int, segment: int, line: int, x: float, y: float, progress: float) -> Status:
    axes = [AxisStatus(name, p, p, 0.001, 0.004, 100.0, 0.1, False, False, False, True, True, True, 0.0, lim)
            for name, p, lim in (("x", x, 1600.0), ("y", y, 1200.0))]
    prog = ProgramProgress("nest.ngc", "h", 1, segment, line, progress * 1000, 1000 * (1 - progress), progress,
                           60.0 * (1 - progress), 60.0, 1, "NONE")
    return Status(machine="waterjet", seq=seq, stamp_ns=time.time_ns(), tick=seq, clock="virtual",
                  servo_state="TRACKING", fault="NONE", fault_axis="", watchdog_tripped=False, safe_state=False,
                  estop_ok=True, doors_closed=True, jet_on=True, axes=axes, overruns=0, underruns=0, late_ticks=0,
                  servo_missed_ticks=0, fifo_fill=100, planner_state="RUNNING", feed_commanded_mm_s=100.0,
                  feed_actual_mm_s=99.0, program=prog, machine_state="RUNNING", mode="AUTO", cycle_phase="CUTTING",
                  cycles_target=1, plc_link="OK", plc_inputs={"plc_running": 1.0, "mains_on": 1.0}, pump_on=True,
                  pump_pressure_bar=3600.0, pump_set_bar=3600.0, operator="bench", network_alive=True)


class PaintCounter(QObject):
    """Counts the paint events a widget receives (proof that Qt's own repaint path ran)."""

    def __init__(self, widget) -> None:  # noqa: ANN001 - any QWidget
        super().__init__()
        self.count = 0
        widget.installEventFilter(self)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:  # noqa: N802 - Qt's override
        if event.type() == QEvent.Type.Paint:
            self.count += 1
        return False


def run(segments: int, updates: int) -> dict:
    app = QApplication.instance() or QApplication([])
    text, path = program_with_text(segments)
    model = MachineModel("bench")
    connection = Connection(model, ["tcp/127.0.0.1:1"], Keys("wj", "waterjet"), "bench")  # never opened: no commands
    adapter = ModelAdapter(model)
    window = MainWindow(adapter, CommandRunner(connection))
    window.resize(1600, 1000)
    window.show()
    model.set_reachable(True)
    ex, ey = np.asarray(path.end_x), np.asarray(path.end_y)
    model.apply_status(status(1, -1, 0, float(ex[0]), float(ey[0]), 0.0))
    app.processEvents()
    window.grab()
    assert window.current_screen is Screen.AUTO

    t0 = time.perf_counter()
    model.apply_program(ProgramInfo("nest.ngc", "h", len(text), text.count("\n"), 60.0, text=text, path=path))
    app.processEvents()
    window.grab()
    load_s = time.perf_counter() - t0

    def stream(first: int, full: bool) -> np.ndarray:
        """Seconds per update: delivered and repainted as Qt does it (only what changed), or, with
        `full`, the whole window rendered again (an upper bound)."""
        out = np.empty(updates)
        for k in range(updates):
            seg = min(first + 3 * k, len(path.kind) - 1)
            x, y = float(ex[seg]), float(ey[seg])
            t = time.perf_counter()
            model.apply_position(Position(k, time.time_ns(), k, [x, y], [x, y], [100.0, 0.0], seg, path.line[seg], True))
            if k % 5 in (0, 2):  # two statuses per five positions: 20 Hz beside 50 Hz
                model.apply_status(status(k + 2, seg, path.line[seg], x, y, seg / len(path.kind)))
            app.processEvents()  # the queued signals: every view's slot, which marks what it changed
            if full:
                window.grab()
            else:
                app.processEvents()  # the update requests those slots posted: Qt repaints the dirty regions
            out[k] = time.perf_counter() - t
        return out

    paints = PaintCounter(window.contour.plot.viewport())
    whole_full = stream(len(path.kind) // 3, True)
    paints.count = 0
    whole = stream(len(path.kind) // 3 + 3 * updates, False)
    repainted = paints.count
    x0, x1, y0, y1 = window.contour.visible_range()
    cx, cy = float(ex[len(path.kind) // 2]), float(ey[len(path.kind) // 2])
    window.contour.set_visible_range(cx - (x1 - x0) / 40, cx + (x1 - x0) / 40, cy - (y1 - y0) / 40, cy + (y1 - y0) / 40)
    close_full = stream(len(path.kind) // 2, True)
    close = stream(len(path.kind) // 2 + 3 * updates, False)
    window.close()
    return {"segments": len(path.kind), "lines": text.count("\n"), "load_s": load_s,
            "update_whole_ms": _stats(whole), "update_close_ms": _stats(close),
            "full_render_whole_ms": _stats(whole_full), "full_render_close_ms": _stats(close_full),
            "contour_repaints_whole": repainted, "updates": updates}


def _stats(seconds: np.ndarray) -> dict:
    ms = seconds * 1e3
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max()),
            "mean": float(ms.mean())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, default=100_000, help="at least this many motion segments")
    ap.add_argument("--updates", type=int, default=200, help="position updates per sequence")
    ap.add_argument("--json", default=None, help="write all figures as JSON")
    args = ap.parse_args()
    r = run(args.segments, args.updates)
    budget = UPDATE_BUDGET_S * 1e3
    print(f"program: {r['segments']} segments, {r['lines']} lines; window 1600 x 1000 on the AUTO page; "
          f"the contour repainted {r['contour_repaints_whole']} times in {r['updates']} updates (whole sheet)")
    print(f"{'figure':<40}{'value':>12}{'target':>12}{'ratio':>8}")
    print(f"{'load (model -> window -> first render)':<40}{r['load_s'] * 1e3:>9.1f} ms{LOAD_TARGET_S * 1e3:>9.0f} ms"
          f"{r['load_s'] / LOAD_TARGET_S:>8.2f}")
    for key, name in (("update_whole_ms", "update, whole sheet"), ("update_close_ms", "update, zoomed in"),
                      ("full_render_whole_ms", "full window render, whole sheet"),
                      ("full_render_close_ms", "full window render, zoomed in")):
        for stat in ("median", "p95", "mean"):
            v = r[key][stat]
            print(f"{name + ' ' + stat:<40}{v:>9.2f} ms{budget:>9.1f} ms{v / budget:>8.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=2))
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
