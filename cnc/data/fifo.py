"""Setpoint FIFO: a lock-free single-producer single-consumer ring in shared memory.

The planner (producer) pushes setpoints in bursts; the servo (consumer) pops one per tick.
`head` counts records ever pushed and is written only by the producer; `tail` counts
records ever popped and is written only by the consumer; each sits on its own cache line.
Both are monotonic 64-bit counters, so full and empty are told apart without a spare slot
and a record's slot is `counter % capacity`. The counters are read and written through
`memoryview.cast("Q")` cells, one 8-byte access each (`struct.pack_into` would zero the
cell first and let the other end see a transient 0). The producer writes records before it
advances `head`, the consumer copies a record before it advances `tail`; on x86-64 stores
are not reordered with stores nor loads with loads, which is all the ring needs.

Every record carries the motion epoch its producer was given when the motion began (the
servo's `motion_epoch`): the servo drops records of any other epoch, so setpoints made before
a trip, a stop or a reset can never move the machine after it, whoever pushed them when.
"""

from __future__ import annotations

import enum
import struct
from multiprocessing import shared_memory
from typing import NamedTuple

import numpy as np

_HEADER = 256  # magic/capacity/axes on line 0, head on line 1, tail on line 2
_OFF_META, _OFF_HEAD, _OFF_TAIL = 0, 64, 128
_META = struct.Struct("<QQQ")
_MAGIC = 0x5746_4946_4F30_0001  # "WFIFO0" v1


class SetpointFlag(enum.IntFlag):
    """Bits of a setpoint's `flags`. Output bits mirror `DigitalOut` so they pass straight through."""

    JET_ON = 1 << 0
    ABRASIVE = 1 << 1
    AUX1 = 1 << 2
    AUX2 = 1 << 3
    AUX3 = 1 << 4
    AUX4 = 1 << 5
    IN_MOTION = 1 << 8  # more setpoints of this motion follow: running dry now is an underrun
    SEGMENT_START = 1 << 9  # first setpoint of a program segment


OUTPUT_MASK = 0x3F  # the flag bits that drive digital outputs


class Setpoint(NamedTuple):
    """One servo-period sample of the commanded motion, as the consumer sees it."""

    position: tuple[float, ...]
    velocity: tuple[float, ...]
    flags: int
    segment: int
    line: int
    epoch: int = 0


def setpoint_dtype(n_axes: int) -> np.dtype:
    """numpy dtype of one record; same bytes as the struct the consumer unpacks."""
    return np.dtype(
        {
            "names": ["position", "velocity", "flags", "segment", "line", "epoch"],
            "formats": [(np.float64, (n_axes,)), (np.float64, (n_axes,)), np.uint32, np.uint32, np.int32, np.uint32],
            "offsets": [0, 8 * n_axes, 16 * n_axes, 16 * n_axes + 4, 16 * n_axes + 8, 16 * n_axes + 12],
            "itemsize": 16 * n_axes + 16,
        }
    )


def copy_out(ring: np.ndarray, counter: int, n: int) -> np.ndarray:
    """A copy of the n records of a ring buffer starting at monotonic counter `counter` (wrapping)."""
    capacity = len(ring)
    start = counter % capacity
    first = min(n, capacity - start)
    out = np.empty(n, dtype=ring.dtype)
    out[:first] = ring[start : start + first]
    if first < n:
        out[first:] = ring[: n - first]
    return out


class SetpointFifo:
    """Either end of the ring. Use `create` in the owner, `attach` elsewhere; one producer, one consumer."""

    def __init__(self, shm: shared_memory.SharedMemory, owner: bool) -> None:
        self.shm, self.owner = shm, owner
        magic, capacity, n_axes = _META.unpack_from(shm.buf, _OFF_META)
        if magic != _MAGIC:
            raise RuntimeError(f"shared memory {shm.name!r} is not a setpoint FIFO")
        self.capacity, self.n_axes = int(capacity), int(n_axes)
        self.dtype = setpoint_dtype(self.n_axes)
        self._rec = struct.Struct(f"<{2 * self.n_axes}dIIiI")
        self._rec_size = self._rec.size
        self.ring = np.ndarray((self.capacity,), dtype=self.dtype, buffer=shm.buf, offset=_HEADER)
        self._buf = shm.buf
        self._head_cell = shm.buf[_OFF_HEAD : _OFF_HEAD + 8].cast("Q")
        self._tail_cell = shm.buf[_OFF_TAIL : _OFF_TAIL + 8].cast("Q")
        # Each end caches its own counter: it is the only writer of it.
        self._head = self.head()
        self._tail = self.tail()

    @classmethod
    def create(cls, name: str, capacity: int, n_axes: int) -> "SetpointFifo":
        if capacity < 2:
            raise ValueError(f"FIFO capacity {capacity} must be at least 2")
        size = _HEADER + capacity * setpoint_dtype(n_axes).itemsize
        shm = shared_memory.SharedMemory(name=name, create=True, size=size)
        shm.buf[:_HEADER] = bytes(_HEADER)
        _META.pack_into(shm.buf, _OFF_META, _MAGIC, capacity, n_axes)
        return cls(shm, owner=True)

    @classmethod
    def attach(cls, name: str) -> "SetpointFifo":
        return cls(shared_memory.SharedMemory(name=name, create=False), owner=False)

    # -- counters ------------------------------------------------------------------------
    def head(self) -> int:
        return self._head_cell[0]

    def tail(self) -> int:
        return self._tail_cell[0]

    def fill(self) -> int:
        """Records waiting; exact for either end, a near-instant view for anyone else."""
        return self.head() - self.tail()

    def free(self) -> int:
        return self.capacity - self.fill()

    # -- producer ------------------------------------------------------------------------
    def push(self, records: np.ndarray) -> int:
        """Append as many of `records` (dtype `self.dtype`) as fit; return how many were taken."""
        head = self._head
        n = min(len(records), self.capacity - (head - self.tail()))
        if n <= 0:
            return 0
        start = head % self.capacity
        first = min(n, self.capacity - start)
        self.ring[start : start + first] = records[:first]
        if first < n:
            self.ring[: n - first] = records[first:n]
        self._head = head + n
        self._head_cell[0] = self._head
        return n

    def push_one(self, position, velocity, flags: int = 0, segment: int = 0, line: int = 0, epoch: int = 0) -> bool:
        """Append one record; False when the ring is full."""
        head = self._head
        if head - self.tail() >= self.capacity:
            return False
        self._rec.pack_into(
            self._buf, _HEADER + (head % self.capacity) * self._rec_size, *position, *velocity, flags, segment, line,
            epoch & 0xFFFF_FFFF,
        )
        self._head = head + 1
        self._head_cell[0] = self._head
        return True

    # -- consumer ------------------------------------------------------------------------
    def pop(self) -> tuple | None:
        """Take the oldest record as a flat tuple (positions..., velocities..., flags, segment, line, epoch)."""
        tail = self._tail
        if tail == self._head_cell[0]:
            return None
        rec = self._rec.unpack_from(self._buf, _HEADER + (tail % self.capacity) * self._rec_size)
        self._tail = tail + 1
        self._tail_cell[0] = self._tail
        return rec

    def peek(self, i: int = 0) -> tuple | None:
        """Consumer: the record `i` places after the oldest, without taking it (None when not there yet)."""
        tail = self._tail
        if tail + i >= self._head_cell[0]:
            return None
        return self._rec.unpack_from(self._buf, _HEADER + ((tail + i) % self.capacity) * self._rec_size)

    def pop_setpoint(self) -> Setpoint | None:
        """`pop` with named fields, for callers off the tick path."""
        rec = self.pop()
        if rec is None:
            return None
        n = self.n_axes
        return Setpoint(rec[:n], rec[n : 2 * n], rec[2 * n], rec[2 * n + 1], rec[2 * n + 2], rec[2 * n + 3])

    def pop_many(self, max_records: int) -> np.ndarray:
        """Take up to `max_records` oldest records as a numpy array (a copy)."""
        tail = self._tail
        n = min(max_records, self.head() - tail)
        if n <= 0:
            return np.empty(0, dtype=self.dtype)
        out = copy_out(self.ring, tail, n)
        self._tail = tail + n
        self._tail_cell[0] = self._tail
        return out

    def flush(self) -> int:
        """Consumer: drop everything waiting (stop); returns how many records were dropped."""
        head = self.head()
        dropped = head - self._tail
        self._tail = head
        self._tail_cell[0] = self._tail
        return dropped

    def close(self) -> None:
        self.ring = None
        self._buf = None
        self._head_cell.release()
        self._tail_cell.release()
        try:
            self.shm.close()
        except BufferError:
            pass
        if self.owner:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass
