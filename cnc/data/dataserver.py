"""Data server: the controller's shared-memory area of single-writer blocks.

Each block has exactly one writing process and any number of readers. Consistency is a
seqlock: the writer makes the block's sequence number odd, writes the body, makes it even;
a reader copies the body between two reads of the sequence number and retries when they
differ or are odd. Readers never block the writer, and a reader never waits for long:

- `read()` (off the tick path) spins a little, then yields the CPU, so a writer preempted on
  a loaded machine can finish; a writer that stays in one write for 50 ms has died there, and
  the reader returns its last consistent copy with `consistent=False`. It remembers that
  sequence number: while the block stays stuck there, later reads return at once.
- `read_nowait()` (the tick path) never yields or sleeps: a few spins, then the last
  consistent copy. `odd_since_ns` says since when the block has been stuck mid-write, so the
  tick can tell a writer preempted for a moment from a dead one (`cnc.interlock`).

A restarted writer never continues from a torn body: `load_current()` answers False ("unknown")
for a block left mid-write, and the writer starts from the layout's safe defaults.

The body of a block is packed and unpacked whole with one precompiled `struct.Struct`
(one C call: the servo's tick path stays cheap), and is also visible as a numpy structured
array for tools and tests. Memory ordering relies on x86-64's total store order; 8-byte
aligned stores are atomic there. The sequence number is read and written through a
`memoryview.cast("Q")` (one 8-byte load or store): `struct.pack_into` zeroes its target
before writing, which would let a reader see a transient 0 and take a torn body for whole.
"""

from __future__ import annotations

import functools
import os
import secrets
import struct
import time
from dataclasses import dataclass
from multiprocessing import shared_memory
from typing import Any, Iterable

import numpy as np

_ALIGN = 64  # a cache line per block start: writers of different blocks do not share lines
_SPINS = 200  # retries before a reader starts yielding the CPU to a preempted writer
_NAP_EVERY = 16  # ...and every 16th retry sleeping: a real-time reader must leave the CPU to any writer
_NAP_S = 20e-6
_GIVE_UP_NS = 50_000_000  # a writer in the same write for 50 ms has died mid-write
_NOWAIT_SPINS = 32  # the tick path's retries: a writer running on another CPU finishes a write within them

SHM_PREFIX = "wjcnc"


@dataclass(frozen=True)
class FieldSpec:
    name: str
    code: str  # struct code: d (float64), q (int64), Q (uint64), I (uint32), i (int32), s (text)
    count: int = 1  # values; for text, its size in bytes (UTF-8, cut to fit)


class BlockLayout:
    """Field layout of one block: struct format, numpy dtype and flat indices of every field."""

    def __init__(self, name: str, fields: Iterable[FieldSpec]) -> None:
        self.name = name
        self.fields = tuple(fields)
        fmt, offsets, index, pos, flat = "<", [], {}, 8, 0
        np_fields = [("seq", "<u8")]
        for f in self.fields:
            if f.code == "s":  # text: one bytes value of f.count bytes
                offsets.append(pos)
                fmt += f"{f.count}s"
                np_fields.append((f.name, f"S{f.count}"))
                index[f.name] = flat
                pos += f.count
                flat += 1
                continue
            size = struct.calcsize("<" + f.code)
            if pos % size:
                pad = size - pos % size
                fmt += f"{pad}x"
                pos += pad
            offsets.append(pos)
            fmt += f"{f.count}{f.code}" if f.count > 1 else f.code
            np_fields.append((f.name, np.dtype("<" + f.code), (f.count,)) if f.count > 1 else (f.name, "<" + f.code))
            index[f.name] = slice(flat, flat + f.count) if f.count > 1 else flat
            pos += size * f.count
            flat += f.count
        self.body = struct.Struct(fmt)
        self.size = 8 + self.body.size
        self.index: dict[str, int | slice] = index
        self.n_values = flat
        self.text_size = {f.name: f.count for f in self.fields if f.code == "s"}
        self.dtype = np.dtype(
            {
                "names": [n[0] for n in np_fields],
                "formats": [np.dtype((n[1], n[2])) if len(n) == 3 else np.dtype(n[1]) for n in np_fields],
                "offsets": [0] + offsets,
                "itemsize": self.size,
            }
        )

    def defaults(self) -> list[Any]:
        out: list[Any] = []
        for f in self.fields:
            if f.code == "s":
                out.append(b"")
                continue
            zero = 0.0 if f.code == "d" else 0
            out.extend([zero] * f.count)
        return out


class Block:
    """One block placed in a shared buffer at a fixed offset."""

    def __init__(self, layout: BlockLayout, buf: memoryview, offset: int) -> None:
        self.layout, self.buf, self.offset = layout, buf, offset
        self.body_offset = offset + 8
        self.array = np.ndarray((1,), dtype=layout.dtype, buffer=buf, offset=offset)
        self.seq_cell = buf[offset : offset + 8].cast("Q")

    def seq(self) -> int:
        return self.seq_cell[0]


class BlockWriter:
    """The single writer's side: edit `values` (flat list) then `publish()` it whole."""

    def __init__(self, block: Block) -> None:
        self.block = block
        self.layout = block.layout
        self.values: list[Any] = self.layout.defaults()
        seq = block.seq()
        self._seq = seq + (seq & 1)  # even, never backwards: a block left mid-write is made whole by the first publish
        self._pack = self.layout.body.pack_into
        self._buf, self._body_off, self._cell = block.buf, block.body_offset, block.seq_cell

    def idx(self, name: str) -> int | slice:
        return self.layout.index[name]

    def set(self, name: str, value: Any) -> None:
        i = self.layout.index[name]
        if isinstance(i, slice):
            self.values[i] = list(value)
        elif isinstance(value, str):
            self.values[i] = _fit(value, self.layout.text_size[name])
        else:
            self.values[i] = value

    def get(self, name: str) -> Any:
        return self.values[self.layout.index[name]]

    def load_current(self) -> bool:
        """Start from what is in shared memory (a restarted writer continues its counters); False,
        and the layout's defaults, when the block was left mid-write: a torn body is unknown, never
        a state to continue from (zeroed fields would read as commands)."""
        if self.block.seq() & 1:
            self.values = self.layout.defaults()
            return False
        values, consistent = BlockReader(self.block).read()
        self.values = list(values) if consistent else self.layout.defaults()
        return consistent

    def publish(self) -> None:
        cell = self._cell
        cell[0] = self._seq + 1
        self._pack(self._buf, self._body_off, *self.values)
        self._seq += 2
        cell[0] = self._seq


class BlockReader:
    """A reader's side: consistent copies of the block body, never blocking the writer."""

    def __init__(self, block: Block) -> None:
        self.block = block
        self.layout = block.layout
        self._unpack = self.layout.body.unpack_from
        self._buf, self._body_off, self._cell = block.buf, block.body_offset, block.seq_cell
        self._last: tuple | None = None  # the last consistent copy
        self._stuck = -1  # an odd sequence number this reader gave up on: its writer died mid-write
        self.odd_since_ns = 0  # read_nowait: when it first found the block stuck at its current odd number (0: not stuck)
        self._odd_seq = -1

    def read(self) -> tuple[tuple, bool]:
        """Return (flat values, consistent).

        When the writer stays in the middle of one write past _GIVE_UP_NS (it died there), the
        last consistent copy this reader had, flagged False: a torn body is never handed out (it
        is partly zeros: the PLC's inputs read as zeros made a false e-stop). A writer that keeps
        writing is alive, however long the reader has to try. The wait is paid once: while the
        block stays at the number given up on, reads return the last copy at once."""
        buf, cell = self._buf, self._cell
        tries, give_up, watched = 0, 0, -1
        while True:
            s1 = cell[0]
            if not s1 & 1:
                values = self._unpack(buf, self._body_off)
                if cell[0] == s1:
                    self._last = values
                    return values, True
            elif s1 == self._stuck:
                return self._fallback(), False
            tries += 1
            if tries > _SPINS:
                now = time.monotonic_ns()
                if s1 != watched:  # the writer has moved on since: alive, the wait starts again
                    watched, give_up = s1, now + _GIVE_UP_NS
                elif now > give_up:
                    self._stuck = s1
                    return self._fallback(), False
                if tries % _NAP_EVERY:
                    os.sched_yield()
                else:
                    # now and then a sleep: a real-time reader's sched_yield only gives the CPU to its
                    # own priority, and a normal-priority writer preempted mid-write on it never finished
                    time.sleep(_NAP_S)

    def read_nowait(self) -> tuple[tuple, bool]:
        """The tick path's read: (values, consistent) without ever yielding the CPU. A block found
        mid-write after a few spins gives the last consistent copy, flagged False, and
        `odd_since_ns` says since when it has been stuck at that sequence number."""
        buf, cell = self._buf, self._cell
        s1 = -1
        for _ in range(_NOWAIT_SPINS):
            s1 = cell[0]
            if not s1 & 1:
                values = self._unpack(buf, self._body_off)
                if cell[0] == s1:
                    self._last = values
                    self.odd_since_ns = 0
                    return values, True
        if s1 & 1:
            if s1 != self._odd_seq:
                self._odd_seq, self.odd_since_ns = s1, time.monotonic_ns()
        return self._fallback(), False

    def _fallback(self) -> tuple:
        """The last consistent copy; before any, the layout's defaults (never the torn body)."""
        if self._last is None:
            self._last = tuple(self.layout.defaults())
        return self._last

    def read_dict(self) -> dict[str, Any]:
        """Consistent snapshot as {field: value, list or str}, fields in the layout's order; for
        readers off the tick path (the control logic reads four blocks so every scan)."""
        values, _ = self.read()
        fields, arrays, texts = self._fields
        out = {name: values[i] for name, i in fields}  # an array's slice gives a tuple: made a list below
        for name, i in arrays:
            out[name] = list(values[i])
        for name, i in texts:
            out[name] = values[i].rstrip(b"\0").decode("utf-8", "replace")
        return out

    @functools.cached_property
    def _fields(self) -> tuple[list[tuple[str, Any]], list[tuple[str, slice]], list[tuple[str, Any]]]:
        """(every field, the arrays, the texts) as (name, index into the flat values)."""
        index, text = self.layout.index, self.layout.text_size
        fields = list(index.items())
        return (fields, [(n, i) for n, i in fields if isinstance(i, slice) and n not in text],
                [(n, i) for n, i in fields if n in text])


class SharedArea:
    """A named shared-memory segment holding a set of blocks laid out one after another."""

    def __init__(self, shm: shared_memory.SharedMemory, layouts: list[BlockLayout], owner: bool) -> None:
        self.shm, self.owner = shm, owner
        self.blocks: dict[str, Block] = {}
        offset = 0
        for layout in layouts:
            self.blocks[layout.name] = Block(layout, shm.buf, offset)
            offset += -(-layout.size // _ALIGN) * _ALIGN

    @staticmethod
    def size_of(layouts: list[BlockLayout]) -> int:
        return sum(-(-lay.size // _ALIGN) * _ALIGN for lay in layouts)

    @classmethod
    def create(cls, name: str, layouts: list[BlockLayout]) -> "SharedArea":
        shm = shared_memory.SharedMemory(name=name, create=True, size=cls.size_of(layouts))
        shm.buf[:] = bytes(shm.size)
        return cls(shm, layouts, owner=True)

    @classmethod
    def attach(cls, name: str, layouts: list[BlockLayout]) -> "SharedArea":
        shm = shared_memory.SharedMemory(name=name, create=False)
        if shm.size < cls.size_of(layouts):
            raise RuntimeError(f"shared memory {name!r} is {shm.size} bytes, layout needs {cls.size_of(layouts)}")
        return cls(shm, layouts, owner=False)

    def writer(self, block: str) -> BlockWriter:
        return BlockWriter(self.blocks[block])

    def reader(self, block: str) -> BlockReader:
        return BlockReader(self.blocks[block])

    def close(self) -> None:
        """Detach; the owner also unlinks the segment."""
        for b in self.blocks.values():
            b.array = None  # drop numpy and memoryview exports so the mmap can close
            b.seq_cell.release()
        self.blocks.clear()
        try:
            self.shm.close()
        except BufferError:
            pass  # a caller still holds a view; the mapping goes with the process
        if self.owner:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass


def _fit(text: str, size: int) -> bytes:
    """UTF-8 of `text` cut to at most `size` bytes without splitting a character."""
    raw = text.encode("utf-8")
    if len(raw) <= size:
        return raw
    return raw[:size].decode("utf-8", "ignore").encode("utf-8")


def unique_name(machine: str, what: str) -> str:
    """A segment name no other controller instance uses: wjcnc_<machine>_<random>_<what>."""
    return f"{SHM_PREFIX}_{machine}_{secrets.token_hex(4)}_{what}"
