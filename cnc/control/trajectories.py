"""The test trajectories of the control programs (QMotor's experiments): hold, a position step, a
ramp, a circle and the paper's Fig. 10 contour. `run_text` is their G-code for a timed control
run on the machine (`ControlRun`, run by the control logic as an MDI); `cnc.control.trial`
follows the same trajectories on the simulated plant."""

from __future__ import annotations

import math
from pathlib import Path

from ..config import MachineConfig

TRAJECTORIES = ("hold", "step", "ramp", "circle", "fig10")
FIG10 = Path(__file__).with_name("fig10_contour.ngc")
STEP_MM = 0.2  # the position step
RAMP_MM_S = 50.0  # the ramp's speed
CIRCLE_RADIUS_MM, CIRCLE_MM_MIN = 20.0, 12000.0


# one pass of each trajectory on the machine (`run_text`): its G-code and about how long it takes
STEP_PASS = ("G91 G1 X{step} F{fast}\nG4 P0.25\nG1 X-{step}\nG4 P0.25\n", 0.5)
RAMP_PASS = ("G91 G1 X20 F{ramp}\nG1 X-20\n", 0.8)
CIRCLE_PASS = ("G91 G2 X0 Y0 I-{r} J0 F{circle}\n", 2.0 * math.pi * CIRCLE_RADIUS_MM / (CIRCLE_MM_MIN / 60.0))
FIG10_PASS_S = 4.7
MAX_PASSES = 100000


def run_text(kind: str, duration_s: float, config: MachineConfig) -> str:
    """The G-code of a timed control run on the machine (`ControlRun`): `kind` from where the head
    stands (hold; step, ramp and circle on X and Y; fig10 at the contour's own place), repeated
    (an O-word repeat) for at least `duration_s`; the commander stops it on the path when the
    time is up. No jet: a control run cuts nothing. ValueError names what is wrong."""
    if kind not in TRAJECTORIES:
        raise ValueError(f"trajectory {kind!r} is not one of: {', '.join(TRAJECTORIES)}")
    if not (math.isfinite(duration_s) and 0.1 <= duration_s <= 3600.0):
        raise ValueError(f"duration_s {duration_s!r} is out of range: 0.1 to 3600 s")
    head = "(control run: {kind} for {d:g} s)\nG21 G17 G40 G64 P0.005\n".format(kind=kind, d=duration_s)
    if kind == "hold":
        return head + f"G4 P{duration_s:.3f}\nM2\n"
    fast = min(a.max_velocity_mm_s for a in config.axes) * 60.0
    if kind == "fig10":
        body = "\n".join(line for line in FIG10.read_text().splitlines()
                          if line.strip() and not line.lstrip().startswith(("M2", "M30", "%")))
        body, one = "G90\n" + body + "\n", FIG10_PASS_S
    else:
        text, one = {"step": STEP_PASS, "ramp": RAMP_PASS, "circle": CIRCLE_PASS}[kind]
        body = text.format(step=STEP_MM, fast=f"{fast:.0f}", ramp=f"{RAMP_MM_S * 60.0:.0f}", r=f"{CIRCLE_RADIUS_MM:g}",
                           circle=f"{CIRCLE_MM_MIN:.0f}")
    passes = min(MAX_PASSES, int(math.ceil(duration_s / one)) + 1)
    return head + f"o100 repeat [{passes}]\n{body}o100 endrepeat\nG90\nM2\n"
