"""Shared-memory blocks: one writer, readers always get consistent snapshots and never block it."""

from __future__ import annotations

import multiprocessing

from cnc.data.dataserver import BlockLayout, FieldSpec, SharedArea, unique_name

LAYOUT = BlockLayout("t", [FieldSpec("a", "Q"), FieldSpec("v", "d", 5), FieldSpec("b", "I"), FieldSpec("c", "q", 3)])


def _writer(name: str, count: int, started) -> None:
    area = SharedArea.attach(name, [LAYOUT])
    w = area.writer("t")
    started.set()
    for k in range(1, count + 1):
        w.values = [k] + [float(k)] * 5 + [k % 2**32] + [-k] * 3
        w.publish()
    area.close()


def test_reader_never_sees_a_torn_block_while_another_process_writes():
    area = SharedArea.create(unique_name("test", "seqlock"), [LAYOUT])
    try:
        ctx = multiprocessing.get_context("spawn")
        started = ctx.Event()
        p = ctx.Process(target=_writer, args=(area.shm.name, 300_000, started))
        p.start()
        started.wait(30)
        reader = area.reader("t")
        seen, last = 0, 0
        while p.is_alive() or seen == 0:
            values, consistent = reader.read()
            assert consistent
            k = values[0]
            assert values[1:6] == (float(k),) * 5 and values[6] == k % 2**32 and values[7:] == (-k,) * 3
            assert k >= last, "a reader went back in time"
            last, seen = k, seen + 1
        p.join()
        assert p.exitcode == 0
        assert reader.read()[0][0] == 300_000
    finally:
        area.close()


def test_block_fields_are_visible_by_name_and_as_numpy():
    area = SharedArea.create(unique_name("test", "names"), [LAYOUT])
    try:
        w = area.writer("t")
        w.set("v", [1.5, 2.5, 3.5, 4.5, 5.5])
        w.set("b", 7)
        w.publish()
        d = area.reader("t").read_dict()
        assert d["v"] == [1.5, 2.5, 3.5, 4.5, 5.5] and d["b"] == 7
        arr = area.blocks["t"].array[0]
        assert arr["b"] == 7 and list(arr["v"]) == d["v"] and arr["seq"] % 2 == 0
    finally:
        area.close()


def test_text_fields_hold_utf8_cut_to_their_size_without_splitting_a_character():
    layout = BlockLayout("t", [FieldSpec("n", "I"), FieldSpec("name", "s", 8), FieldSpec("x", "d")])
    area = SharedArea.create(unique_name("test", "text"), [layout])
    try:
        w = area.writer("t")
        w.set("n", 3)
        w.set("name", "Düsseldorf")  # 11 bytes in UTF-8
        w.set("x", 1.5)
        w.publish()
        got = area.reader("t").read_dict()
        assert got == {"n": 3, "name": "Düsseld", "x": 1.5}
    finally:
        area.close()


def test_a_writer_stuck_mid_write_gives_the_reader_its_last_consistent_copy_never_a_torn_one():
    # the PLC link preempted inside a write, with the control logic (real-time) reading: the
    # torn body (partly zeros) read as "the PLC reports the safety circuit open"
    area = SharedArea.create(unique_name("test", "stuck"), [LAYOUT])
    try:
        w, reader = area.writer("t"), area.reader("t")
        w.values = [7] + [1.5] * 5 + [3] + [-7] * 3
        w.publish()
        assert reader.read() == (tuple(w.values), True)
        block = area.blocks["t"]
        block.seq_cell[0] = block.seq() + 1  # a write begun...
        area.shm.buf[block.body_offset : block.body_offset + LAYOUT.size - 8] = bytes(LAYOUT.size - 8)  # ...half done
        values, consistent = reader.read()
        assert not consistent and values == tuple(w.values), "the last consistent copy, flagged"
        w.publish()  # the writer finishes its next write: consistent again
        assert reader.read() == (tuple(w.values), True)
    finally:
        area.close()


def _stuck(area: SharedArea) -> None:
    """The writer died inside a publish: its sequence number stays odd, its body half written."""
    block = area.blocks["t"]
    block.seq_cell[0] = block.seq() + 1
    area.shm.buf[block.body_offset : block.body_offset + LAYOUT.size - 8] = bytes(LAYOUT.size - 8)


def test_a_reader_pays_the_wait_for_a_dead_writer_once_and_the_tick_path_never():
    import time

    area = SharedArea.create(unique_name("test", "dead"), [LAYOUT])
    try:
        w = area.writer("t")
        w.values = [7] + [1.5] * 5 + [3] + [-7] * 3
        w.publish()
        reader, tick_reader, late = area.reader("t"), area.reader("t"), area.reader("t")
        assert reader.read() == (tuple(w.values), True)
        assert tick_reader.read_nowait() == (tuple(w.values), True) and tick_reader.odd_since_ns == 0
        _stuck(area)
        assert late.read_nowait() == (tuple(LAYOUT.defaults()), False), "never a consistent copy: the safe defaults"
        t0 = time.monotonic()
        assert reader.read() == (tuple(w.values), False)
        first = time.monotonic() - t0
        t0 = time.monotonic()
        for _ in range(100):
            assert reader.read() == (tuple(w.values), False)
        again = (time.monotonic() - t0) / 100
        assert first >= 0.05 and again < 0.005, (first, again)  # the give-up wait once, then at once
        t0 = time.monotonic_ns()
        assert tick_reader.read_nowait() == (tuple(w.values), False)
        assert tick_reader.odd_since_ns >= t0, "the tick path notes since when the block is stuck"
        assert time.monotonic_ns() - t0 < 5_000_000, "and never waits"
    finally:
        area.close()


def test_a_restarted_writer_starts_from_safe_defaults_never_from_a_torn_body():
    area = SharedArea.create(unique_name("test", "torn"), [LAYOUT])
    try:
        w = area.writer("t")
        w.values = [7] + [1.5] * 5 + [3] + [-7] * 3
        w.publish()
        again = area.writer("t")
        assert again.load_current() and again.values == w.values, "a whole block: the counters go on"
        _stuck(area)
        restarted = area.writer("t")
        assert not restarted.load_current(), "a block left mid-write is unknown"
        assert restarted.values == LAYOUT.defaults()
        restarted.publish()
        assert area.reader("t").read() == (tuple(LAYOUT.defaults()), True), "its first write makes the block whole"
        assert area.blocks["t"].seq() % 2 == 0
    finally:
        area.close()
