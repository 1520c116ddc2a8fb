"""Trace ring: every tick the servo writes comes out in order; when full it drops and counts, never waits."""

from __future__ import annotations

import pytest

from cnc.data.dataserver import unique_name
from cnc.data.trace import TraceRing

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)


def write(ring: TraceRing, tick: int) -> None:
    ring.write(tick, (tick * 1.0, -tick * 1.0), (tick + 0.5, 0.0), (1.0, 2.0), (0.1, 0.2), 0x101, tick // 10, tick % 7, 3, 1000 * tick,
               7 * tick, [0.5 * tick] * ring.n_extra)


def test_records_come_out_in_order_across_the_wrap_with_every_field():
    ring = TraceRing.create(unique_name("test", "trace"), 8, 2, 3)  # 3: a control program's log variables
    try:
        got = []
        for tick in range(1, 21):
            write(ring, tick)
            if tick % 5 == 0:
                got.append(ring.drain())
        ticks = [int(t) for chunk in got for t in chunk["tick"]]
        assert ticks == list(range(1, 21))
        last = got[-1][-1]
        assert list(last["commanded"]) == [20.0, -20.0] and list(last["actual"]) == [20.5, 0.0]
        assert last["flags"] == 0x101 and last["segment"] == 2 and last["line"] == 20 % 7 and last["fifo_fill"] == 3
        assert last["latency_ns"] == 20_000 and last["control_ns"] == 140
        assert list(last["control"]) == [10.0, 10.0, 10.0]
        assert ring.dropped() == 0
    finally:
        ring.close()


def test_a_full_ring_drops_new_records_and_counts_them():
    ring = TraceRing.create(unique_name("test", "trace"), 4, 2)
    try:
        for tick in range(1, 8):
            write(ring, tick)
        assert [int(t) for t in ring.drain()["tick"]] == [1, 2, 3, 4]
        assert ring.dropped() == 3
        write(ring, 8)
        assert [int(t) for t in ring.drain()["tick"]] == [8], "room again once drained"
    finally:
        ring.close()
