"""Benchmark: PLC-link exchange time at the machine's baud rate against the simulator on a pty.

Runs the real master (`plc_link.line` over pyserial) against the simulator's server, which paces its
answers like the serial line, for N cycles at the machine's cycle period, with the control
logic's heartbeat forwarded every 0.25 s as the link process does (one write request every
fifth cycle). Prints p50/p99/max of the exchange time per kind of cycle beside its
theoretical minimum from frame sizes and character timing, and the cycle target.

    .venv/bin/python bench/plc_exchange.py [--cycles 400] [--machine M] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from cnc.config import load_machine  # noqa: E402
from plc_link.master import PlcMaster  # noqa: E402
from plc_link.process import HEARTBEAT_PERIOD_S  # noqa: E402
from plc_link.pty_pair import PtyPair  # noqa: E402
from plc_link.sim_model import PlcModel  # noqa: E402
from plc_link.sim_server import PlcSimServer  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def measure(machine: str, cycles: int) -> dict:
    plc = load_machine(machine).plc
    with PtyPair() as pair:
        server = PlcSimServer(plc, PlcModel(plc), pair.server_fd)
        server.start()
        master = PlcMaster(plc, pair.device)
        image = master.image
        outputs = [0.0] * len(image.outputs)
        beat_slot = image.output_index.get("cnc_heartbeat")
        period = plc.cycle_ms / 1000.0
        every = max(1, round(HEARTBEAT_PERIOD_S / period))
        master.exchange(outputs)
        master.exchange(outputs)  # port open, every output confirmed
        reads, writes, failed = [], [], 0
        deadline = time.monotonic()
        for k in range(cycles):
            wrote = beat_slot is not None and k % every == 0
            if wrote:
                outputs[beat_slot] = float((k // every + 1) & 0xFFFF)
            t0 = time.perf_counter()
            ok = master.cycle(outputs)
            dt = time.perf_counter() - t0
            if not ok:
                failed += 1
            (writes if wrote else reads).append(dt)
            deadline += period
            time.sleep(max(0.0, deadline - time.monotonic()))
        master.close()
        server.stop()
    heartbeat_write = image.write_span(len(image.write_groups) - 1, [0] * len(image.outputs), 1, 1)
    theory = {
        "reads": image.read_time_s(),
        "reads+heartbeat": image.read_time_s() + image.write_time_s(heartbeat_write),
        "full image": image.full_exchange_time_s(),
    }
    rows = {}
    for name, data in (("reads", reads), ("reads+heartbeat", writes), ("all", reads + writes)):
        if not data:
            continue
        a = np.array(data) * 1000
        t = theory.get(name, theory["reads"]) * 1000
        rows[name] = {
            "n": len(data), "p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)),
            "max_ms": float(a.max()), "theory_ms": t, "p50_over_theory": float(np.percentile(a, 50)) / t,
        }
    return {
        "machine": machine, "baud": plc.baud, "format": f"8{plc.parity}{plc.stop_bits}", "cycles": cycles,
        "failed": failed, "cycle_target_ms": plc.cycle_ms, "full_image_theory_ms": theory["full image"] * 1000,
        "rows": rows,
    }


def report(r: dict) -> str:
    lines = [
        f"PLC exchange at {r['baud']} baud {r['format']}, {r['cycles']} cycles, target {r['cycle_target_ms']:g} ms, failed {r['failed']}",
        f"{'cycle':<16}{'n':>5}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}{'min theory':>12}{'p50/theory':>12}",
    ]
    for name, row in r["rows"].items():
        lines.append(
            f"{name:<16}{row['n']:>5}{row['p50_ms']:>9.1f}{row['p99_ms']:>9.1f}{row['max_ms']:>9.1f}"
            f"{row['theory_ms']:>12.1f}{row['p50_over_theory']:>12.2f}"
        )
    lines.append(
        f"(the whole image, all four requests every cycle, would need {r['full_image_theory_ms']:.1f} ms on the line: "
        f"{'over' if r['full_image_theory_ms'] > r['cycle_target_ms'] else 'within'} the {r['cycle_target_ms']:g} ms target;"
        " outputs are written on change)"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cycles", type=int, default=400)
    p.add_argument("--machine", default=str(REPO / "machines" / "waterjet.toml"))
    p.add_argument("--json", metavar="OUT", help="also write the results as JSON")
    args = p.parse_args(argv)
    result = measure(args.machine, args.cycles)
    print(report(result))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
