"""`waterjet demo` runs the simulated machine end to end, headless, and exits 0."""

from __future__ import annotations

import os
import subprocess
import sys

from .conftest import REPO


def test_demo_homes_cuts_a_nest_through_the_planner_shows_status_over_zenoh_and_exits_0():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    res = subprocess.run(
        [sys.executable, "-m", "cnc.cli", "demo", "--clock", "virtual"],
        cwd=REPO, capture_output=True, text=True, timeout=240, env=env,
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    out = res.stdout
    assert "demo: homed" in out and "demo: program ended (DONE)" in out
    assert "RUNNING" in out and "jet ON" in out, "the subscriber saw the cut under way"
    assert "demo: OK: homed, the nest cut to its end, status seen over Zenoh, shared memory freed" in out
