"""Frame-time benchmark of the operator screen's contour field on a 100k-segment nesting program.

Offscreen: interprets a nesting program (lines, I/J and R arcs, rapids; bench/gcode_speed.py's
generator) grown to at least 100k motion segments, then measures
- load: `set_path` + `fit` + the first full render (`QWidget.grab()`), target < 1 s;
- pan and zoom frames: a view-range change followed by a forced render, 100 each, target 16.7 ms (60 fps);
- progress frames: `set_progress` a few segments further followed by a forced render, same target.

    QT_QPA_PLATFORM=offscreen python bench/hmi_contour.py [--segments N] [--frames N] [--json FILE]
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

from gcode_speed import nesting_program  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

from cnc.bus.messages import ProgramPath  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.gateway.door import program_path  # noqa: E402
from cnc.machine_dialect import dialect_for  # noqa: E402
from gcode.interp import Interpreter  # noqa: E402
from hmi.contour import ContourView  # noqa: E402

FRAME_TARGET_S = 1 / 60
LOAD_TARGET_S = 1.0


def program(segments: int) -> ProgramPath:
    """A nesting program's path with at least `segments` motions."""
    return program_with_text(segments)[1]


def program_with_text(segments: int) -> tuple[str, ProgramPath]:
    """A nesting program with at least `segments` motions (about 0.93 motions per generated line):
    its text and its interpreted path."""
    config = load_machine(REPO / "machines" / "waterjet.toml")
    lines = int(segments / 0.9)
    while True:
        text = nesting_program(lines)
        path = program_path(Interpreter(dialect_for(config), "nest.ngc").run(text))
        if len(path.kind) >= segments:
            return text, path
        lines = int(lines * 1.1)


def frames(view: ContourView, steps: list) -> np.ndarray:
    """Seconds per frame: each step changes the view, then `grab()` forces a full render."""
    out = np.empty(len(steps))
    for k, step in enumerate(steps):
        t0 = time.perf_counter()
        step()
        view.grab()
        out[k] = time.perf_counter() - t0
    return out


def run(segments: int, n_frames: int) -> dict:
    """Load, pan, zoom and progress timings for one program on a 1280 x 800 view."""
    app = QApplication.instance() or QApplication([])
    path = program(segments)
    kinds = np.bincount(np.asarray(path.kind), minlength=3)
    view = ContourView()
    view.resize(1280, 800)
    view.set_travel(0.0, 1600.0, 0.0, 1200.0)
    view.show()
    app.processEvents()
    t0 = time.perf_counter()
    view.set_path(path)
    view.fit()
    view.grab()
    load_s = time.perf_counter() - t0

    x0, x1, y0, y1 = view.visible_range()
    cx, cy, w, h = (x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0
    # zoom from the whole sheet down to ~1/200 of it and back out, about the centre (wheel-like steps)
    scales = np.concatenate([np.geomspace(1, 1 / 200, n_frames // 2), np.geomspace(1 / 200, 1, n_frames - n_frames // 2)])
    zoom = [lambda s=s: view.set_visible_range(cx - w * s / 2, cx + w * s / 2, cy - h * s / 2, cy + h * s / 2) for s in scales]
    zoom_s = frames(view, zoom)

    def pan_steps(scale: float) -> list:
        dx = np.linspace(-0.4, 0.4, n_frames) * w
        return [lambda d=d: view.set_visible_range(cx + d - w * scale / 2, cx + d + w * scale / 2,
                                                   cy - h * scale / 2, cy + h * scale / 2) for d in dx]

    pan_whole_s = frames(view, pan_steps(1.0))
    pan_close_s = frames(view, pan_steps(0.1))
    view.fit()
    start = len(path.kind) // 3
    progress_s = frames(view, [lambda i=i: view.set_progress(i) for i in range(start, start + 5 * n_frames, 5)])
    view.close()
    return {
        "segments": len(path.kind), "rapids": int(kinds[0]), "lines": int(kinds[1]), "arcs": int(kinds[2]),
        "fine_vertices": int(np.isfinite(view._fine.feed.x).sum()),
        "overview_vertices": int(np.isfinite(view._overview.feed.x).sum()),
        "load_s": load_s,
        "zoom_frame_ms": _stats(zoom_s), "pan_whole_frame_ms": _stats(pan_whole_s),
        "pan_close_frame_ms": _stats(pan_close_s), "progress_frame_ms": _stats(progress_s),
    }


def _stats(seconds: np.ndarray) -> dict:
    ms = seconds * 1e3
    return {"median": float(np.median(ms)), "p95": float(np.percentile(ms, 95)), "max": float(ms.max())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, default=100_000, help="at least this many motion segments")
    ap.add_argument("--frames", type=int, default=100, help="frames per pan / zoom / progress sequence")
    ap.add_argument("--json", default=None, help="write all figures as JSON")
    args = ap.parse_args()
    r = run(args.segments, args.frames)
    print(f"program: {r['segments']} segments ({r['lines']} lines, {r['arcs']} arcs, {r['rapids']} rapids); "
          f"{r['fine_vertices']} vertices fine, {r['overview_vertices']} overview")
    print(f"{'figure':<28}{'value':>12}{'target':>12}{'ratio':>8}")
    print(f"{'load (set_path+fit+render)':<28}{r['load_s'] * 1e3:>9.1f} ms{LOAD_TARGET_S * 1e3:>9.0f} ms"
          f"{r['load_s'] / LOAD_TARGET_S:>8.2f}")
    for key in ("zoom_frame_ms", "pan_whole_frame_ms", "pan_close_frame_ms", "progress_frame_ms"):
        for stat in ("median", "p95"):
            v = r[key][stat]
            print(f"{key[:-9] + ' frame ' + stat:<28}{v:>9.2f} ms{FRAME_TARGET_S * 1e3:>9.1f} ms{v / (FRAME_TARGET_S * 1e3):>8.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=2))
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
