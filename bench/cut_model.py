"""The cutting model on a CAM nest: speeds along the path, cycle times, and the speed plot by quality.

A nest of `bench/nests.py` (rounded rectangles with G41 lead-ins, a pierce per part) is cut on the
real controller processes (virtual clock, `waterjet simulate`) under a cutting job, and checked:

- the simulated cycle time against the planned one (the ETA's and the job record's figure);
- the cycle time under the model against the same program at its programmed F (`waterjet check`);
- per quality, the highest setpoint speed against the quality's straight speed (at most 1.0: the
  model is never exceeded), and the share of the cut slower than 95 % of it (corners, arcs,
  lead-ins, accelerations);
- `docs/figures/cut_model_speed.png`: the speed along the path coloured by quality.

The material is the tests' calibrated chart (`tests/test_cut_model.py` `HIDE`, as a speed-ladder
calibration would write it), not a shipped material: the controller ships no numbers it cannot cite.

    python bench/cut_model.py [--parts 12] [--quality 3] [--plot docs/figures/cut_model_speed.png]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.nests import cam_nest  # noqa: E402
from cnc.check import program_timing  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.logger.plots import plot_speed_by_quality  # noqa: E402
from cnc.machine_dialect import dialect_for  # noqa: E402
from cnc.planner.quality import cut_plan_for  # noqa: E402
from cnc.sim.demo import free_port  # noqa: E402
from cnc.sim.simulate import simulate, speed_along_path  # noqa: E402
from gcode.interp import Interpreter  # noqa: E402
from tests.test_cut_model import HIDE  # noqa: E402



def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--parts", type=int, default=12)
    ap.add_argument("--quality", type=int, default=3, choices=(1, 2, 3, 4, 5))
    ap.add_argument("--plot", default=str(REPO / "docs" / "figures" / "cut_model_speed.png"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="wj-cutmodel-") as tmp:
        d = Path(tmp)
        shutil.copy(REPO / "machines" / "waterjet.toml", d / "waterjet.toml")
        (d / "materials").mkdir()
        (d / "materials" / "hide.toml").write_text(HIDE)
        # written at F6000, the separation speed: in "machine uses quality" mode F is only an upper bound
        text = cam_nest(args.parts).replace("F2400.0", "F6000.0").replace(
            "%\n", "%\n" + f"(MATERIAL, hide, THICKNESS=2, QUALITY={args.quality})\n", 1)
        program_path = d / "nest.ngc"
        program_path.write_text(text)
        config = load_machine(d / "waterjet.toml", {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"]})
        program = Interpreter(dialect_for(config), "nest.ngc").run(text.encode())
        plan, job = cut_plan_for(program, None, config, "nest.ngc")
        at_f = program_timing(program, config).total_ticks * config.timing.period_s
        result = simulate(str(program_path), config)
    m = result.metrics
    distance, speed, quality, straight = speed_along_path(result.trace, result.cut, result.dt)
    step = np.diff(distance, prepend=0.0)
    print(f"cutting model on a CAM nest of {args.parts} parts ({len(text.splitlines())} lines): {job}")
    print(f"{'figure':<44} {'value':>12} {'peer':>12} {'ratio':>7}")
    print(f"{'simulated cycle time (s) / planned':<44} {m['cycle_time_s']:12.2f} {m['planned_cycle_time_s']:12.2f} "
          f"{m['cycle_time_s'] / m['planned_cycle_time_s']:7.4f}")
    print(f"{'cycle time with the model (s) / at F':<44} {m['planned_cycle_time_s']:12.2f} {at_f:12.2f} "
          f"{m['planned_cycle_time_s'] / at_f:7.3f}")
    for q in sorted(set(quality[quality > 0].tolist())):
        at = quality == q
        v_q = float(straight[at][0])
        slow = float(step[at & (speed < 0.95 * v_q)].sum() / max(step[at].sum(), 1e-9))
        print(f"{f'quality {q}: peak speed (mm/min) / straight':<44} {speed[at].max() * 60:12.0f} {v_q * 60:12.0f} "
              f"{speed[at].max() / v_q:7.4f}")
        print(f"{f'quality {q}: cut below 95 % of straight':<44} {slow * 100:11.1f}% {step[at].sum():10.0f}mm")
    plot_speed_by_quality(args.plot, distance, speed, quality, straight, title=f"CAM nest, {job}")
    print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
