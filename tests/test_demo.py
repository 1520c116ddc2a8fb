"""`waterjet demo` runs the simulated machine end to end, headless, and exits 0."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from .conftest import REPO


@pytest.mark.alone  # the shipped PLC link's 100 ms answers, on the virtual clock (tests/lanes.py)
def test_demo_runs_automatic_cycles_handles_a_door_fault_and_exits_0():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    try:  # about 30 s on an idle host; the limit is for a hang, and says where it hung
        res = subprocess.run(
            [sys.executable, "-m", "cnc.cli", "demo", "--clock", "virtual"],
            cwd=REPO, capture_output=True, text=True, timeout=600, env=env,
        )
    except subprocess.TimeoutExpired as exc:
        tail = lambda b: (b or b"").decode(errors="replace")[-3000:] if isinstance(b, bytes) else (b or "")[-3000:]  # noqa: E731
        raise AssertionError(f"the demo hung; it printed:\n{tail(exc.stdout)}\n{tail(exc.stderr)}") from None
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    out = res.stdout
    assert "demo: homed" in out and "demo: cycles ended (DONE)" in out
    assert "CUTTING" in out and "jet ON" in out and "PLC OK" in out, "the subscriber saw the cut under way"
    assert "procedure TRANSPORT PHASE: step 11/11 'Button pressed'" in out
    assert "raised     2292 error   Safety door open" in out
    assert "demo: OK: homed, automatic cycles cut, the door fault handled and reset" in out


def test_the_example_program_for_trying_it_is_the_demos_nest():
    """README "Try it" loads machines/programs/leather_nest.ngc: the demo's own nest, kept in step."""
    from cnc.sim.demo import demo_program

    from .conftest import REPO

    assert (REPO / "machines" / "programs" / "leather_nest.ngc").read_text() == demo_program()
