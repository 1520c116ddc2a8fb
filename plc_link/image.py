"""The PLC variable map as Modbus requests: grouping, decoding, encoding, and line time.

The input image (discrete inputs and input registers) is read with as few requests as the
protocol allows: one per table, split only where reading through an address gap would cost
more line time than a request of its own, or where a request would exceed the protocol's
quantity limits. The output image (coils and holding registers) is written in groups of
strictly contiguous addresses: writing through a gap would overwrite PLC memory that is not
ours. Values cross the link raw (bits, 16-bit words) and are engineering values
(raw * scale, int16 sign applied, bits 0.0/1.0) everywhere else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from cnc.config import PlcConfig, PlcVarConfig

from . import rtu

# One extra request costs request (8) + exception-free short response (5) + two silences (7)
# characters; reading through a gap costs 1/8 character per bit or 2 per register.
_REQUEST_OVERHEAD_CHARS = 8 + 5 + 2 * rtu.SILENCE_CHARS

_RAW_RANGE = {"uint16": (0, 0xFFFF), "int16": (-0x8000, 0x7FFF), "bool": (0, 1)}


class ImageError(ValueError):
    """An engineering value cannot be sent to the PLC; the message names the variable."""


@dataclass(frozen=True)
class ReadRequest:
    """One read request of the input image: which image slots its answer fills."""

    function: int  # rtu.READ_DISCRETE_INPUTS or rtu.READ_INPUT_REGISTERS
    address: int
    count: int
    slots: tuple[tuple[int, int], ...]  # (input image index, offset in the answer)

    def describe(self) -> str:
        table = "discrete inputs" if self.function == rtu.READ_DISCRETE_INPUTS else "input registers"
        return f"read {table} {self.address}..{self.address + self.count - 1} (function {self.function})"


@dataclass(frozen=True)
class WriteGroup:
    """A run of contiguous output addresses of one table; written whole or as a changed span."""

    bits: bool  # coils, else holding registers
    address: int
    indices: tuple[int, ...]  # output image index of each address, in address order

    def describe(self, first: int = 0, last: int | None = None) -> str:
        last = len(self.indices) - 1 if last is None else last
        table = "coils" if self.bits else "holding registers"
        return f"write {table} {self.address + first}..{self.address + last}"


@dataclass(frozen=True)
class WriteRequest:
    """A write of `values` (raw) at `address`: the changed span of one group."""

    group: int  # index in PlcImage.write_groups
    function: int
    address: int
    values: tuple[int, ...]

    def describe(self) -> str:
        table = "coils" if self.function in (rtu.WRITE_SINGLE_COIL, rtu.WRITE_MULTIPLE_COILS) else "holding registers"
        return f"write {table} {self.address}..{self.address + len(self.values) - 1} (function {self.function})"


class PlcImage:
    """The requests that move the map's input and output images, and their value conversions."""

    def __init__(self, config: PlcConfig) -> None:
        self.config = config
        self.inputs: list[PlcVarConfig] = config.inputs()
        self.outputs: list[PlcVarConfig] = config.outputs()
        self.input_index = {v.id: i for i, v in enumerate(self.inputs)}
        self.output_index = {v.id: i for i, v in enumerate(self.outputs)}
        self.read_requests: list[ReadRequest] = []
        for kind, function, limit, cost in (
            ("discrete_input", rtu.READ_DISCRETE_INPUTS, rtu.MAX_READ_BITS, 1 / 8),
            ("input_register", rtu.READ_INPUT_REGISTERS, rtu.MAX_READ_REGISTERS, 2.0),
        ):
            max_gap = int(_REQUEST_OVERHEAD_CHARS / cost)
            self.read_requests += _group_reads(self.inputs, kind, function, limit, max_gap)
        self.write_groups: list[WriteGroup] = _group_writes(self.outputs, "coil", True, rtu.MAX_WRITE_BITS)
        self.write_groups += _group_writes(self.outputs, "holding_register", False, rtu.MAX_WRITE_REGISTERS)

    # -- values --------------------------------------------------------------------------

    def decode_inputs(self, answers: Sequence[Sequence[int]], out: list[float]) -> None:
        """Fill `out` (input image order) from the raw answers of `read_requests`, in order."""
        for request, raw in zip(self.read_requests, answers):
            for slot, offset in request.slots:
                out[slot] = decode_value(self.inputs[slot], raw[offset])

    def encode_outputs(self, values: Sequence[float]) -> list[int]:
        """Raw values of the output image; raises ImageError naming the first bad variable."""
        raw, errors = self.clamp_outputs(values)
        if errors:
            raise ImageError(errors[0])
        return raw

    def clamp_outputs(self, values: Sequence[float]) -> tuple[list[int], list[str]]:
        """Raw values of the output image, each clamped into its type's range, with a message
        for every variable that had to be clamped (the cyclic loop sends and reports, it does
        not stop)."""
        raw, errors = [], []
        for var, value in zip(self.outputs, values):
            r, err = encode_value(var, value)
            raw.append(r)
            if err:
                errors.append(err)
        return raw, errors

    def write_span(self, group_index: int, raw: Sequence[int], first: int, last: int) -> WriteRequest:
        """The request that writes positions first..last of a group (single-item functions for
        one item: shorter on the line)."""
        group = self.write_groups[group_index]
        values = tuple(raw[group.indices[i]] for i in range(first, last + 1))
        if group.bits:
            function = rtu.WRITE_SINGLE_COIL if len(values) == 1 else rtu.WRITE_MULTIPLE_COILS
        else:
            function = rtu.WRITE_SINGLE_REGISTER if len(values) == 1 else rtu.WRITE_MULTIPLE_REGISTERS
            values = tuple(v & 0xFFFF for v in values)
        return WriteRequest(group_index, function, group.address + first, values)

    def full_writes(self, raw: Sequence[int]) -> list[WriteRequest]:
        """Every group written whole."""
        return [self.write_span(g, raw, 0, len(grp.indices) - 1) for g, grp in enumerate(self.write_groups)]

    # -- line time -----------------------------------------------------------------------

    def char_time_s(self) -> float:
        return rtu.char_time_s(self.config.baud, self.config.parity, self.config.stop_bits)

    def read_time_s(self) -> float:
        """Theoretical minimum line time of reading the whole input image."""
        c = self.char_time_s()
        return sum(rtu.transaction_time_s(r.function, r.count, c) for r in self.read_requests)

    def write_time_s(self, request: WriteRequest) -> float:
        return rtu.transaction_time_s(request.function, len(request.values), self.char_time_s())

    def full_exchange_time_s(self) -> float:
        """Theoretical minimum of one complete exchange: read every input, write every output."""
        zeros = [0] * len(self.outputs)
        return self.read_time_s() + sum(self.write_time_s(w) for w in self.full_writes(zeros))


def decode_value(var: PlcVarConfig, raw: int) -> float:
    """Engineering value of one raw bit or register (int16 sign, scale; bits 0.0/1.0)."""
    if var.kind in ("discrete_input", "coil") or var.type == "bool":
        return 1.0 if raw else 0.0
    raw &= 0xFFFF
    if var.type == "int16" and raw & 0x8000:
        raw -= 0x10000
    return raw * var.scale


def encode_value(var: PlcVarConfig, value: float) -> tuple[int, str]:
    """(raw, error text or ""): rounded to the register's resolution and clamped into range;
    int16 values stay signed here (the wire form is `raw & 0xFFFF`)."""
    bits = var.kind in ("discrete_input", "coil") or var.type == "bool"
    if math.isnan(value):
        return 0, f"PLC output {var.id}: value is NaN, sent as 0"
    if bits:
        return (1 if value else 0), ""
    lo, hi = _RAW_RANGE[var.type]
    raw_f = value / var.scale
    if lo - 0.5 <= raw_f < hi + 0.5:
        return int(round(raw_f)), ""
    clamped = lo if raw_f < lo else hi
    return clamped, (
        f"PLC output {var.id}: {value:g} {var.unit}".rstrip()
        + f" is out of range {lo * var.scale:g}..{hi * var.scale:g} ({var.type}, scale {var.scale:g}); sent {clamped * var.scale:g}"
    )


def _group_reads(
    variables: list[PlcVarConfig], kind: str, function: int, limit: int, max_gap: int
) -> list[ReadRequest]:
    """Read requests covering every variable of `kind`, split at gaps wider than `max_gap`
    addresses and at the protocol's quantity `limit`."""
    members = sorted((v.address, i) for i, v in enumerate(variables) if v.kind == kind)
    out: list[ReadRequest] = []
    run: list[tuple[int, int]] = []
    for address, index in members:
        if run and (address - run[-1][0] - 1 > max_gap or address - run[0][0] + 1 > limit):
            out.append(_read_request(function, run))
            run = []
        run.append((address, index))
    if run:
        out.append(_read_request(function, run))
    return out


def _read_request(function: int, run: list[tuple[int, int]]) -> ReadRequest:
    start = run[0][0]
    return ReadRequest(function, start, run[-1][0] - start + 1, tuple((i, a - start) for a, i in run))


def _group_writes(variables: list[PlcVarConfig], kind: str, bits: bool, limit: int) -> list[WriteGroup]:
    """Groups of strictly contiguous addresses (no gaps: they belong to someone else)."""
    members = sorted((v.address, i) for i, v in enumerate(variables) if v.kind == kind)
    out: list[WriteGroup] = []
    run: list[tuple[int, int]] = []
    for address, index in members:
        if run and (address != run[-1][0] + 1 or len(run) >= limit):
            out.append(WriteGroup(bits, run[0][0], tuple(i for _, i in run)))
            run = []
        run.append((address, index))
    if run:
        out.append(WriteGroup(bits, run[0][0], tuple(i for _, i in run)))
    return out
