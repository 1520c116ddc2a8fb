#!/usr/bin/env python3
"""Tracking on the paper's test contour (Fig. 10): contour error against 10 um, beside the paper's +-100 um.

Runs `cnc/control/fig10_contour.ngc` (a closed tangent contour in X 340-460, Y 100-200 at up to
500 mm/s, G64 P0.005) on the controller's real processes on the virtual clock (`waterjet
simulate`: hardware server with the simulated board, servo, planner), from a homed machine,
and compares the largest contour error (actual position against the programmed geometry,
on the cut) with the target of 10 um; the paper's Figs. 11-12 show following errors of
about +-100 um, which is the peer figure. It also draws Figs. 10-12 of the run.

    python bench/tracking.py [--plot OUT.png] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from cnc.config import load_machine
from cnc.sim.demo import free_port
from cnc.sim.simulate import simulate

REPO = Path(__file__).resolve().parent.parent
PROGRAM = REPO / "cnc" / "control" / "fig10_contour.ngc"
TARGET_UM = 10.0
PAPER_FOLLOWING_ERROR_UM = 100.0  # Figs. 11-12 of the paper: about +-100 um


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--plot", metavar="OUT.png", default=str(REPO / "bench" / "out" / "fig10_12.png"))
    parser.add_argument("--json", metavar="OUT", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    config = load_machine(args.machine, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"]})
    result = simulate(str(PROGRAM), config)
    m = result.metrics
    um = lambda mm: mm * 1000.0  # noqa: E731
    fe = max(m["following_error_max_mm"].values())
    rows = [
        ("contour error on the cut (max)", um(m["contour_error_max_mm"]), TARGET_UM, "target"),
        ("following error, worst axis (max)", um(fe), PAPER_FOLLOWING_ERROR_UM, "the paper's"),
        ("tracking error normal to the path (max)", um(m["tracking_error_max_mm"]), TARGET_UM, "target"),
        ("path deviation of the setpoints (max)", um(m["path_deviation_max_mm"]), 5.0, "G64 P"),
    ]
    print(f"tracking on {PROGRAM.name}: cycle time {m['cycle_time_s']:.3f} s (planned {m['planned_cycle_time_s']:.3f} s), "
          f"peak speed {max(m['peak_velocity_mm_s'].values()):.0f} mm/s, underruns {m['underruns']}")
    print(f"{'':<42}{'ours um':>9}   {'compared with':<21}{'ratio':>7}")
    for label, ours, peer, what in rows:
        print(f"{label:<42}{ours:>9.2f}   {f'{peer:g} um ({what})':<21}{ours / peer:>6.2f}x")
    print(f"tracking error rms {um(m['tracking_error_rms_mm']):.2f} um; rapids' contour error {um(m['contour_error_rapid_max_mm']):.1f} um")
    if args.plot:
        from cnc.logger.plots import plot_run

        r = result.trace
        Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
        plot_run(args.plot, t_s=(r["tick"] - r["tick"][0]) * result.dt,
                 commanded_mm=r["commanded"], actual_mm=r["actual"], velocity_mm_s=r["velocity"],
                 speed_command_v=r["speed_cmd"], programmed_xy=result.programmed_xy,
                 title="paper's test contour, simulated (cnc/control/fig10_contour.ngc)")
        print(f"figures: {args.plot}")
    if args.json:
        Path(args.json).write_text(json.dumps({"program": PROGRAM.name, **m}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
