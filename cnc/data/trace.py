"""Trace ring: what the servo did at every tick, in shared memory, for whoever records it.

The servo (single producer) appends one record per tick while tracing is enabled: the
setpoint, the measured position, the reference velocity, the speed command, the setpoint's
flags, segment and line, the FIFO fill, how late the tick started, the control program's CPU
time and its log variables. A recorder (single consumer: `waterjet
simulate`, the data logger) copies records out. The servo never waits: when the ring is
full it drops the record and counts it. Counters and memory ordering are as in the setpoint
FIFO (`fifo.py`): monotonic 8-byte counters, one writer each, on their own cache lines.
"""

from __future__ import annotations

import struct
from multiprocessing import shared_memory

import numpy as np

from .fifo import copy_out

_HEADER = 256
_OFF_META, _OFF_HEAD, _OFF_TAIL, _OFF_DROPPED = 0, 64, 128, 192
_META = struct.Struct("<QQQQ")
_MAGIC = 0x5754_5241_4345_0003  # "WTRACE" v3


def trace_dtype(n_axes: int, n_extra: int = 0) -> np.dtype:
    """One tick's record; same bytes as the struct the servo packs. `latency_ns`: how late the
    servo started the tick after its deadline (0 on the virtual clock, where time is not real).
    `control_ns`: the control program's CPU time in that tick (`cnc.control`, 0 when it did not run);
    `control`: its log variables, `n_extra` floats, when it has any."""
    n = n_axes
    names = ["tick", "commanded", "actual", "velocity", "speed_cmd", "flags", "segment", "line", "fifo_fill", "latency_ns",
             "control_ns"]
    formats = ["<u8", ("<f8", (n,)), ("<f8", (n,)), ("<f8", (n,)), ("<f8", (n,)), "<u4", "<u4", "<i4", "<i4", "<i8", "<i8"]
    offsets = [0, 8, 8 + 8 * n, 8 + 16 * n, 8 + 24 * n, 8 + 32 * n, 12 + 32 * n, 16 + 32 * n, 20 + 32 * n, 24 + 32 * n,
               32 + 32 * n]
    if n_extra:
        names.append("control")
        formats.append(("<f8", (n_extra,)))
        offsets.append(40 + 32 * n)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": 40 + 32 * n + 8 * n_extra})


class TraceRing:
    """Either end of the ring: `create` in the owner, `attach` elsewhere."""

    def __init__(self, shm: shared_memory.SharedMemory, owner: bool) -> None:
        self.shm, self.owner = shm, owner
        magic, capacity, n_axes, n_extra = _META.unpack_from(shm.buf, _OFF_META)
        if magic != _MAGIC:
            raise RuntimeError(f"shared memory {shm.name!r} is not a trace ring")
        self.capacity, self.n_axes, self.n_extra = int(capacity), int(n_axes), int(n_extra)
        self.dtype = trace_dtype(self.n_axes, self.n_extra)
        self._rec = struct.Struct(f"<Q{4 * self.n_axes}dIIiiqq{self.n_extra}d")
        self.ring = np.ndarray((self.capacity,), dtype=self.dtype, buffer=shm.buf, offset=_HEADER)
        self._buf = shm.buf
        self._head_cell = shm.buf[_OFF_HEAD:_OFF_HEAD + 8].cast("Q")
        self._tail_cell = shm.buf[_OFF_TAIL:_OFF_TAIL + 8].cast("Q")
        self._dropped_cell = shm.buf[_OFF_DROPPED:_OFF_DROPPED + 8].cast("Q")
        self._head = self._head_cell[0]
        self._tail = self._tail_cell[0]

    @classmethod
    def create(cls, name: str, capacity: int, n_axes: int, n_extra: int = 0) -> "TraceRing":
        """A ring for `n_axes` axes and `n_extra` floats of control-program log variables per record."""
        size = _HEADER + capacity * trace_dtype(n_axes, n_extra).itemsize
        shm = shared_memory.SharedMemory(name=name, create=True, size=size)
        shm.buf[:_HEADER] = bytes(_HEADER)
        _META.pack_into(shm.buf, _OFF_META, _MAGIC, capacity, n_axes, n_extra)
        return cls(shm, owner=True)

    @classmethod
    def attach(cls, name: str) -> "TraceRing":
        return cls(shared_memory.SharedMemory(name=name, create=False), owner=False)

    def dropped(self) -> int:
        return self._dropped_cell[0]

    # -- producer (the servo) ---------------------------------------------------------------
    def write(self, tick, commanded, actual, velocity, speed_cmd, flags, segment, line, fifo_fill, latency_ns,
              control_ns=0, extra=()) -> None:
        head = self._head
        if head - self._tail_cell[0] >= self.capacity:
            self._dropped_cell[0] += 1
            return
        self._rec.pack_into(
            self._buf, _HEADER + (head % self.capacity) * self._rec.size,
            tick, *commanded, *actual, *velocity, *speed_cmd, flags, segment, line, fifo_fill, latency_ns, control_ns,
            *extra,
        )
        self._head = head + 1
        self._head_cell[0] = self._head

    # -- consumer ---------------------------------------------------------------------------
    def drain(self) -> np.ndarray:
        """Take every record waiting, oldest first (a copy)."""
        tail = self._tail
        n = self._head_cell[0] - tail
        if n <= 0:
            return np.empty(0, dtype=self.dtype)
        out = copy_out(self.ring, tail, n)
        self._tail = tail + n
        self._tail_cell[0] = self._tail
        return out

    def close(self) -> None:
        self.ring = None
        self._buf = None
        for cell in (self._head_cell, self._tail_cell, self._dropped_cell):
            cell.release()
        try:
            self.shm.close()
        except BufferError:
            pass
        if self.owner:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass
