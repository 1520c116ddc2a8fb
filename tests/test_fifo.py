"""Setpoint FIFO: lock-free SPSC ring that loses, duplicates and reorders nothing across processes."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from cnc.data.dataserver import unique_name
from cnc.data.fifo import SetpointFifo, SetpointFlag, setpoint_dtype

N_RECORDS = 1_000_000


def _produce(name: str, total: int, seed: int) -> None:
    fifo = SetpointFifo.attach(name)
    rng = np.random.default_rng(seed)
    sent = 0
    while sent < total:
        n = int(min(rng.integers(1, 700), total - sent))
        burst = np.zeros(n, dtype=fifo.dtype)
        k = np.arange(sent, sent + n)
        burst["position"][:, 0] = k * 0.001
        burst["position"][:, 1] = -k * 0.002
        burst["velocity"][:, 0] = k
        burst["flags"] = SetpointFlag.IN_MOTION
        burst["segment"] = k % 2**32
        burst["line"] = (k % 100_000).astype(np.int32)
        off = 0
        while off < n:
            off += fifo.push(burst[off:])
        sent += n
    fifo.close()


def _consume(name: str, total: int, result) -> None:
    """Pop one record at a time, as the servo does, and check every one."""
    fifo = SetpointFifo.attach(name)
    expected, bad = 0, 0
    while expected < total:
        rec = fifo.pop()
        if rec is None:
            continue
        x, y, vx, vy, flags, segment, line, _epoch = rec
        ok = (
            segment == expected % 2**32
            and x == expected * 0.001
            and y == -expected * 0.002
            and vx == expected
            and line == expected % 100_000
            and flags == SetpointFlag.IN_MOTION
        )
        bad += not ok
        expected += 1
    result.put((expected, bad, fifo.pop() is None))
    fifo.close()


def test_concurrent_producer_and_consumer_lose_duplicate_and_reorder_nothing():
    fifo = SetpointFifo.create(unique_name("test", "fifo"), 1024, 2)
    try:
        ctx = multiprocessing.get_context("spawn")
        result = ctx.Queue()
        consumer = ctx.Process(target=_consume, args=(fifo.shm.name, N_RECORDS, result))
        producer = ctx.Process(target=_produce, args=(fifo.shm.name, N_RECORDS, 7))
        consumer.start()
        producer.start()
        producer.join(300)
        count, bad, empty_after = result.get(timeout=300)
        consumer.join(30)
        assert (producer.exitcode, consumer.exitcode) == (0, 0)
        assert count == N_RECORDS and bad == 0 and empty_after
        assert fifo.head() == fifo.tail() == N_RECORDS
    finally:
        fifo.close()


def test_full_ring_takes_only_what_fits_and_wraps_in_order():
    fifo = SetpointFifo.create(unique_name("test", "wrap"), 8, 2)
    try:
        recs = np.zeros(20, dtype=setpoint_dtype(2))
        recs["segment"] = np.arange(20)
        assert fifo.push(recs[:5]) == 5
        assert [fifo.pop()[5] for _ in range(3)] == [0, 1, 2]
        assert fifo.push(recs[5:]) == 6  # 2 waiting + 6 = capacity 8
        assert fifo.push(recs[11:]) == 0
        assert fifo.fill() == 8 and fifo.free() == 0
        assert list(fifo.pop_many(100)["segment"]) == [3, 4, 5, 6, 7, 8, 9, 10]
        assert fifo.pop() is None
        assert fifo.push_one((1.0, 2.0), (3.0, 4.0), SetpointFlag.JET_ON, 42, 7)
        sp = fifo.pop_setpoint()
        assert sp.position == (1.0, 2.0) and sp.velocity == (3.0, 4.0) and sp.segment == 42 and sp.line == 7
        assert sp.flags == SetpointFlag.JET_ON
    finally:
        fifo.close()


def test_flush_drops_everything_waiting():
    fifo = SetpointFifo.create(unique_name("test", "flush"), 16, 2)
    try:
        fifo.push(np.zeros(10, dtype=fifo.dtype))
        assert fifo.flush() == 10 and fifo.fill() == 0 and fifo.pop() is None
    finally:
        fifo.close()


def test_capacity_below_two_is_refused():
    with pytest.raises(ValueError, match="capacity 1"):
        SetpointFifo.create(unique_name("test", "tiny"), 1, 2)
