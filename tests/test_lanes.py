"""`make test`'s computes lane (tests/lanes.py): idle priority, its own shared-memory prefix, no
wall-clock limits of Hypothesis's, and a clear refusal of a test there that would wait on
something other than its own computation."""

from __future__ import annotations

import json
import subprocess
import sys

from .conftest import REPO
from .tickrig import dead_pid

PROBE = """
import json, os, threading, subprocess
import numpy  # its BLAS starts a worker thread at import, before the lane is entered
from tests import lanes
from cnc.data.dataserver import unique_name
os.environ[lanes.LANE_ENV] = lanes.MARK
lanes.enter_computes_lane()
lanes.refuse_waiting()
from hypothesis import HealthCheck, settings
threads = [int(t) for t in os.listdir("/proc/self/task")]
found = {"threads": len(threads),
         "every_thread_idle": all(os.sched_getscheduler(t) == os.SCHED_IDLE or os.getpriority(os.PRIO_PROCESS, t) == 19
                                  for t in threads),
         "segment": unique_name("waterjet", "data"), "refused": {},
         "hypothesis_untimed": settings.default.deadline is None
                               and HealthCheck.too_slow in settings.default.suppress_health_check}
for what, act in (("thread", lambda: threading.Thread(target=print).start()),
                  ("program", lambda: subprocess.run(["true"])),
                  ("zenoh", lambda: __import__("zenoh").open(None))):
    try:
        act()
    except lanes.LaneError as exc:
        found["refused"][what] = str(exc)
print(json.dumps(found))
"""


def test_the_computes_lane_runs_idle_with_its_own_segments_and_refuses_what_would_wait():
    done = subprocess.run([sys.executable, "-c", PROBE], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout.splitlines()[-1])
    assert found["every_thread_idle"], f"only a CPU nobody else wants, for all {found['threads']} threads"
    assert found["segment"].startswith("wjcomp_waterjet_"), "neither lane counts the other's segments"
    assert found["hypothesis_untimed"], "no wall-clock deadline for an example that waited for a CPU"
    refused = found["refused"]
    assert set(refused) == {"thread", "program", "zenoh"}, refused
    assert "started a thread" in refused["thread"] and "marked `computes`" in refused["thread"]
    assert "started a program" in refused["program"] and "take the mark off" in refused["program"]
    assert "opened a Zenoh session" in refused["zenoh"]


def test_each_lane_counts_only_its_own_segments(monkeypatch):
    from . import lanes

    monkeypatch.delenv(lanes.LANE_ENV, raising=False)
    assert lanes.other_lanes_segment("wjcomp_waterjet_0a1b2c3d_data")
    assert not lanes.other_lanes_segment("wjcnc_waterjet_0a1b2c3d_data")
    monkeypatch.setenv(lanes.LANE_ENV, lanes.MARK)
    assert not lanes.other_lanes_segment("wjcomp_waterjet_0a1b2c3d_data")
    assert lanes.other_lanes_segment("wjcnc_waterjet_0a1b2c3d_data")


def test_the_alone_tests_run_last_and_once_the_computes_lane_has_ended(monkeypatch):
    """The demo needs the host to itself: it runs after every other test of the main lane, and
    starts once the computes lane's process is gone."""
    from . import lanes

    class Item:
        def __init__(self, name: str, alone: bool) -> None:
            self.name, self.alone = name, alone

        def get_closest_marker(self, name: str):
            return object() if name == lanes.ALONE and self.alone else None

    items = [Item("a", False), Item("demo", True), Item("b", False), Item("c", False)]
    lanes.last_the_alone(items)
    assert [i.name for i in items] == ["a", "b", "c", "demo"], "the others keep their order"
    monkeypatch.setenv(lanes.LANE_PID_ENV, str(dead_pid()))
    lanes.await_the_computes_lane()  # returns: that process has ended
    monkeypatch.setenv(lanes.LANE_PID_ENV, "")
    lanes.await_the_computes_lane()  # no lane (plain pytest): at once
