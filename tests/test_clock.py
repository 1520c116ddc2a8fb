"""Clocks and real-time setup: late ticks are counted, refusal of real-time falls back cleanly, virtual time is deterministic."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from cnc.hw.clock import RealtimeClock, VirtualClock, make_clock
from cnc.ptp import move_setpoints
from cnc.runtime.supervisor import DIRECT_FEED, Supervisor

from .conftest import REPO, enable_and_hold, feed, machine_config


def test_realtime_clock_counts_a_late_wake_and_skips_ahead_instead_of_bursting():
    clock = RealtimeClock(0.001)
    clock.start()
    time.sleep(0.012)  # the loop was held up for 12 periods
    deadline, woke = clock.wait()
    assert woke - deadline >= 11_000_000 and clock.late_ticks >= 11
    deadline2, _ = clock.wait()
    assert deadline2 > woke, "the next deadline lies in the future: no burst of catch-up ticks"
    assert (deadline2 - deadline) % clock.period_ns == 0, "deadlines stay on the period grid"


def test_virtual_clock_time_is_tick_count_times_period():
    clock = make_clock("virtual", 0.00025)
    clock.start()
    stamps = [clock.wait()[0] for _ in range(4)]
    assert stamps == [250_000, 500_000, 750_000, 1_000_000] and isinstance(clock, VirtualClock)
    with pytest.raises(ValueError, match="'atomic' is not one of: realtime, virtual"):
        make_clock("atomic", 0.001)


def _python(code: str) -> subprocess.CompletedProcess:
    """Run `code` in a fresh interpreter of its own: scheduling and collector settings are per process."""
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60,
                          env={**os.environ, "PYTHONPATH": str(REPO)})


@pytest.mark.skipif(os.geteuid() != 0, reason="dropping privileges to provoke a refusal needs root")
def test_refused_realtime_scheduling_warns_and_falls_back_cleanly():
    code = (
        "import logging, os, resource\n"
        "from cnc.runtime.rt import enter_realtime\n"
        "resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))\n"
        "resource.setrlimit(resource.RLIMIT_MEMLOCK, (0, 0))\n"
        "os.setgid(65534); os.setuid(65534)\n"
        "logging.basicConfig(level=logging.WARNING)\n"
        "s = enter_realtime(80, 'servo')\n"
        "print(s.fifo, s.mlocked, s.granted)\n"
    )
    res = _python(code)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["False", "False", "False"]
    assert "servo: running without full real-time guarantees: SCHED_FIFO refused" in res.stderr
    assert "mlockall refused" in res.stderr


def test_a_long_computation_started_by_a_realtime_thread_runs_under_the_normal_scheduler():
    # the planner checks and plans a program on a thread its real-time loop starts: minutes
    # of work for a large program, which at SCHED_FIFO held a CPU and tripped the drive watchdog
    code = (
        "import os, threading\n"
        "from cnc.runtime.rt import leave_realtime\n"
        "os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))\n"
        "seen = []\n"
        "def work():\n"
        "    seen.append(os.sched_getscheduler(0))\n"
        "    leave_realtime()\n"
        "    seen.append(os.sched_getscheduler(0))\n"
        "t = threading.Thread(target=work); t.start(); t.join()\n"
        "print(seen == [os.SCHED_FIFO, os.SCHED_OTHER], os.sched_getscheduler(0) == os.SCHED_FIFO)\n"
    )
    res = _python(code)
    if "PermissionError" in res.stderr:
        pytest.skip("SCHED_FIFO is not permitted here")
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["True", "True"], "the thread left real time, its creator stayed"


def _run_move(ticks: int) -> tuple:
    config = machine_config()
    with Supervisor(config, clock="virtual", processes=DIRECT_FEED) as sup:
        start = enable_and_hold(sup)
        sup.pause_virtual_clock()
        paused_at = sup.hw()["tick"]
        feed(sup, move_setpoints(config, start, [start[0] + 300.0, start[1] + 200.0]))
        assert sup.hw()["tick"] == paused_at, "time stands still while paused"
        sup.run_ticks(ticks)
        s = sup.servo()
        return s["max_following_error_mm"], s["actual_mm"], s["following_error_mm"], s["speed_cmd_v"], sup.fifo.fill()


def test_virtual_clock_simulation_is_deterministic_tick_for_tick():
    first = _run_move(400)  # mid-move: the table is still moving
    assert first[4] > 0 and first == _run_move(400)


def test_a_structure_built_with_the_collector_paused_is_left_out_of_later_collections():
    # a million-line program's objects held the planner in one collector pass longer than its
    # heartbeat timeout; built under collector_paused they are never passed over again
    code = (
        "import gc\n"
        "from cnc.runtime.rt import collector_paused\n"
        "gc.collect(); before = gc.get_freeze_count()\n"
        "with collector_paused():\n"
        "    inside = gc.isenabled()\n"
        "    big = [[i] for i in range(200_000)]\n"
        "    young = gc.get_count()[0]\n"
        "frozen = gc.get_freeze_count() - before\n"
        "print(inside, young >= 200_000, frozen >= 200_000, gc.isenabled(), gc.get_count()[0] < 1000)\n"
        "del big\n"
    )
    res = _python(code)
    assert res.returncode == 0, res.stderr
    inside, built_without_passes, frozen, enabled_after, young_after = res.stdout.split()
    assert inside == "False" and built_without_passes == "True", "no automatic collection while building"
    assert frozen == "True" and young_after == "True", "what was built is in the permanent generation"
    assert enabled_after == "True", "automatic collection is back on"
