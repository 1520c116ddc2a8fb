"""Streaming: load time, start-to-motion and the planner's memory for large programs (issue 19).

On the real controller processes (hardware server on the simulated board, servo, planner) on the
virtual clock: home, load a program, then start it twice, once from where it was loaded and once
after the head moved (a go-to, so the start shifts the interpreted program: `planner/rebase.py`),
each time running the first seconds of the cut and stopping it. Measured:

- load_s: wall time of the load command (interpretation twice, the travel check, the first steps);
- start_to_motion_s: wall time from the start command to the first setpoint in the FIFO, against
  the 1 s limit, and against what the planner did before streaming (planning every step before
  the first move: the timing's wall time below is that work);
- timing_wall_s: the cycle time planned beside the load, on its own thread, and the planning speed
  as a multiple of real time (cycle time / wall time), against the 10,000x target;
- the planner process's resident memory (VmRSS) after the load and while cutting, and its
  high-water mark (VmHWM), against the interpreted program's arrays.

    python bench/streaming.py [--programs nest60k,million] [--no-timing-wait] [--clock realtime]

Programs: `nest60k`, the 60k-line nesting program of bench/gcode_speed.py (kerf-compensated
parts, pierces, arcs); `million`, its 1M-line CAM polylines. The timing of the million-line
program takes minutes; `--no-timing-wait` reports it as not waited for.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from bench.gcode_speed import million_line_program, nesting_program  # noqa: E402
from cnc.bus.messages import GoTo, Home, LoadProgram, Start, Stop  # noqa: E402
from cnc.config import load_machine  # noqa: E402
from cnc.data.layout import PlannerState, Proc, ServoState  # noqa: E402
from cnc.runtime.supervisor import MOTION_ONLY, Supervisor  # noqa: E402
from cnc.sim.demo import free_port  # noqa: E402

PROGRAMS = {"nest60k": nesting_program, "million": million_line_program}
CUT_TICKS = 3000  # the first 3 s of the cut after each start
START_LIMIT_S = 1.0
SPEED_TARGET = 10_000.0


def ask(sup: Supervisor, command) -> None:
    reply = sup.planner.request(command)
    if not reply.ok:
        raise SystemExit(f"streaming bench: {type(command).__name__} refused: {reply.reason}")


def memory_mb(pid: int) -> dict[str, float]:
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in ("VmRSS", "VmHWM"):
            fields[key] = int(value.split()[0]) / 1024.0
    return fields


def start_and_cut(sup: Supervisor) -> tuple[float, int]:
    """Start, step the clock to the first setpoint pushed (wall time), cut CUT_TICKS, stop; the
    start-to-motion time and the servo's underruns meanwhile. On the real-time clock the cut runs
    while the program's timing is planned beside it on the planner's other thread: the refills
    must not starve."""
    pushed, underruns = sup.motion()["records_pushed"], sup.servo()["underruns"]
    if sup.clock == "realtime":
        t0 = time.perf_counter()
        ask(sup, Start())
        while sup.motion()["records_pushed"] == pushed:
            time.sleep(0.0005)
        start_s = time.perf_counter() - t0
        time.sleep(CUT_TICKS * sup.config.timing.period_s)
        ask(sup, Stop())
    else:
        sup.pause_virtual_clock()
        try:
            t0 = time.perf_counter()
            ask(sup, Start())
            while sup.motion()["records_pushed"] == pushed:
                sup.run_ticks(1)
            start_s = time.perf_counter() - t0
            sup.run_ticks(CUT_TICKS)
            ask(sup, Stop())
        finally:
            sup.resume_virtual_clock()
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE and sup.servo()["state"] == ServoState.HOLDING,
                   120.0, "the stop")
    return start_s, sup.servo()["underruns"] - underruns


def measure(sup: Supervisor, name: str, text: str, wait_timing: bool, tmp: Path) -> dict:
    path = tmp / f"{name}.ngc"
    path.write_text(text)
    pid = int(sup.area.blocks["heartbeat"].array[0]["pid"][Proc.PLANNER])
    before = memory_mb(pid)
    t0 = time.perf_counter()
    ask(sup, LoadProgram(str(path)))
    load_s = time.perf_counter() - t0
    after_load = memory_mb(pid)
    timing_s = None
    if wait_timing:  # the virtual clock stands meanwhile: its ticks would take the CPU the timing runs on
        if sup.clock == "virtual":
            sup.pause_virtual_clock()
        try:
            sup.wait_until(lambda: sup.motion()["planned_s"] >= 0.0, 3600.0, "the cycle time")
        finally:
            if sup.clock == "virtual":
                sup.resume_virtual_clock()
        timing_s = time.perf_counter() - t0 - load_s
    planned = sup.motion()["planned_s"]
    start_here, under_here = start_and_cut(sup)
    cutting = memory_mb(pid)
    ask(sup, GoTo({"x": 30.0, "y": 20.0}))
    sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE, 120.0, "the go-to")
    start_moved, under_moved = start_and_cut(sup)
    lines = text.count("\n")
    return {
        "program": name, "lines": lines, "load_s": load_s, "start_here_s": start_here, "start_moved_s": start_moved,
        "underruns": under_here + under_moved, "planned_s": planned, "timing_wall_s": timing_s,
        "rss_before_mb": before["VmRSS"], "rss_loaded_mb": after_load["VmRSS"], "rss_cutting_mb": cutting["VmRSS"],
        "hwm_mb": memory_mb(pid)["VmHWM"],
    }


def render(rows: list[dict]) -> str:
    out = ["| program | lines | load | start (same place) | start (head moved) | limit | worst / limit | "
           "underruns | cycle time | timing wall | x real time (target 10,000) | planner RSS idle / loaded / cutting, peak |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        worst = max(r["start_here_s"], r["start_moved_s"])
        timing = f"{r['timing_wall_s']:.1f} s" if r["timing_wall_s"] is not None else "not waited for"
        speed = f"{r['planned_s'] / r['timing_wall_s']:.0f}x" if r["timing_wall_s"] else "-"
        planned = f"{r['planned_s']:.0f} s" if r["planned_s"] >= 0 else "being planned"
        out.append(
            f"| {r['program']} | {r['lines']} | {r['load_s']:.2f} s | {r['start_here_s'] * 1000:.0f} ms | "
            f"{r['start_moved_s'] * 1000:.0f} ms | {START_LIMIT_S:g} s | {worst / START_LIMIT_S:.2f} | {r['underruns']} | "
            f"{planned} | {timing} | {speed} | {r['rss_before_mb']:.0f} / {r['rss_loaded_mb']:.0f} / "
            f"{r['rss_cutting_mb']:.0f}, {r['hwm_mb']:.0f} MB |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--programs", default="nest60k,million")
    parser.add_argument("--no-timing-wait", action="store_true", help="do not wait for the cycle time to be planned")
    parser.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    parser.add_argument("--clock", choices=("virtual", "realtime"), default="virtual",
                        help="realtime: the cut runs in real time, its underruns counted (default virtual)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="streaming_") as tmp:
        config = load_machine(args.machine, {"zenoh.listen": [f"tcp/127.0.0.1:{free_port()}"]})
        rows = []
        with Supervisor(config, clock=args.clock, processes=MOTION_ONLY) as sup:
            sup.enable()
            sup.wait_until(lambda: sup.servo()["state"] == ServoState.HOLDING, 30.0, "the servo")
            ask(sup, Home([]))
            sup.wait_until(lambda: sup.motion()["state"] == PlannerState.IDLE, 300.0, "homing")
            for name in args.programs.split(","):
                rows.append(measure(sup, name, PROGRAMS[name](), not args.no_timing_wait, Path(tmp)))
                print(f"  {name}: done", file=sys.stderr, flush=True)
    print(render(rows))
    bad = [r["program"] for r in rows if max(r["start_here_s"], r["start_moved_s"]) >= START_LIMIT_S or r["underruns"]]
    if bad:
        print(f"streaming bench: over the 1 s start limit or underruns: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
