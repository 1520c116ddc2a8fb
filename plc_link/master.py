"""Modbus RTU master to the external PLC: one exchange per cycle, and link supervision.

`PlcMaster.exchange(outputs)` does one cycle on the line: read the whole input image, then
write the outputs that changed. It raises a `PlcLinkError` naming the request that failed.
`PlcMaster.cycle(outputs, now_s)` wraps it for the cyclic loop and never raises: it counts
consecutive failures, declares the link LOST after `lost_after_cycles`, and while lost
closes and reopens the serial port every `reconnect_s`.

Why outputs are written on change: at 19200 baud 8E1 one character takes 0.573 ms, and the
shipped map's four requests (read bits, read registers, write coils, write registers) need
59 ms on the line (frames plus 3.5-character silences, see `PlcImage.full_exchange_time_s`),
more than the 50 ms cycle. Outputs are state the PLC keeps, so the master reads the inputs
every cycle (29 ms) and writes only what changed since the PLC last confirmed it, as many
write requests as fit the cycle's line-time budget (at least one, so none starves; at 19200
baud that is one); after every (re)connection every output is written once, because the
PLC may have restarted.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Sequence

from cnc.config import PlcConfig
from cnc.data.layout import LinkState

from . import rtu
from .image import PlcImage, ReadRequest, WriteRequest
from .line import ExceptionAnswer, NoAnswer, PortFailed, RtuLine
from .pty_pair import is_pty

log = logging.getLogger(__name__)

NO_PORT = "no serial port: [plc] port is empty and no simulator was started"
BUDGET_FRACTION = 0.9  # share of cycle_ms the planned line time of one exchange may use


class PlcLinkError(Exception):
    """One exchange failed; the message names the request and what went wrong."""


class PlcTimeout(PlcLinkError):
    """No valid response in time: nothing answered, or the answer had a bad CRC."""


class PlcExceptionResponse(PlcLinkError):
    """The PLC answered with a Modbus exception response."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


class PlcPortError(PlcLinkError):
    """The serial port could not be opened or failed."""


_EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "device failure"}


@dataclass
class LinkStatus:
    """The link as the cyclic loop reports it."""

    state: LinkState = LinkState.CONNECTING
    exchanges: int = 0
    failed: int = 0
    missed: int = 0
    losses: int = 0
    dropped: int = 0  # answers dropped because they were not the one asked for (late, another unit's)
    noise: int = 0  # bytes dropped because they made no frame (bad CRC, garbage on the line)
    cycle_s: float = 0.0  # duration of the last exchange attempt
    error: str = ""


class PlcMaster:
    """The CNC's side of the Modbus RTU link, over one `RtuLine` (pyserial)."""

    def __init__(self, config: PlcConfig, port: str | None = None) -> None:
        self.config = config
        self.image = PlcImage(config)
        self.port = config.port if port is None else port
        self.inputs: list[float] = [0.0] * len(self.image.inputs)
        self.status = LinkStatus(state=LinkState.CONNECTING if self.port else LinkState.DOWN)
        self.output_errors: list[str] = []  # values clamped in the last exchange
        self.writes_pending = len(self.image.write_groups)  # groups not yet confirmed by the PLC
        self._sent: list[int | None] = [None] * len(self.image.outputs)
        self._next_group = 0
        self._budget_s = BUDGET_FRACTION * config.cycle_ms / 1000.0
        self._next_reconnect = 0.0
        self._line: RtuLine | None = None
        self._closed_counts = (0, 0)  # (dropped, noise) of the lines closed before this one

    # -- port ------------------------------------------------------------------------------

    def _open(self) -> RtuLine:
        if self._line is None:
            c = self.config
            # a pty (the simulator) has no parity bit and refuses to be asked for one (pty_pair)
            parity = "N" if is_pty(self.port) else c.parity
            silence_s = rtu.SILENCE_CHARS * rtu.char_time_s(c.baud, c.parity, c.stop_bits)
            self._line = RtuLine(self.port, c.baud, parity, c.stop_bits, c.timeout_ms / 1000.0, silence_s, c.local_echo)
        try:
            self._line.open()
        except PortFailed as exc:
            raise PlcPortError(f"{exc} for the PLC link") from None
        return self._line

    def close(self) -> None:
        """Close the serial port; the next exchange reopens it and rewrites every output."""
        if self._line is not None:
            self._line.close()
            self._closed_counts = (self._closed_counts[0] + self._line.misfits, self._closed_counts[1] + self._line.noise)
            self._line = None
        self._sent = [None] * len(self.image.outputs)

    def retarget(self, port: str) -> None:
        """Use another serial device from the next exchange on (a restarted simulator's pty)."""
        self.close()
        self.port = port
        if self.status.state == LinkState.DOWN and port:
            self.status.state = LinkState.CONNECTING

    # -- one exchange ----------------------------------------------------------------------

    def exchange(self, outputs: Sequence[float]) -> list[float]:
        """Read the input image and write the changed outputs; returns the inputs (engineering
        values in `PlcConfig.inputs()` order). Raises PlcLinkError naming the failed request."""
        if not self.port:
            raise PlcPortError(NO_PORT)
        line = self._open()
        raw_out, self.output_errors = self.image.clamp_outputs(outputs)
        answers = [self._read(line, r) for r in self.image.read_requests]
        self.image.decode_inputs(answers, self.inputs)
        for request in self._plan_writes(raw_out):
            self._write(line, request)
            group = self.image.write_groups[request.group]
            first = request.address - group.address
            for index in group.indices[first : first + len(request.values)]:
                self._sent[index] = raw_out[index]
        self.writes_pending = len(self._dirty_groups(raw_out))
        return list(self.inputs)

    def _dirty_groups(self, raw: Sequence[int]) -> list[tuple[int, int, int]]:
        """(group, first, last) of every group holding values the PLC has not confirmed."""
        out = []
        for g, group in enumerate(self.image.write_groups):
            changed = [p for p, i in enumerate(group.indices) if self._sent[i] != raw[i]]
            if changed:
                out.append((g, changed[0], changed[-1]))
        return out

    def _plan_writes(self, raw: Sequence[int]) -> list[WriteRequest]:
        """The changed spans to write now: round-robin from the group after the last one
        written, while the planned line time fits the budget (always at least one)."""
        dirty = self._dirty_groups(raw)
        n = len(self.image.write_groups)
        dirty.sort(key=lambda d: (d[0] - self._next_group) % n)
        planned, line_s = [], self.image.read_time_s()
        for g, first, last in dirty:
            request = self.image.write_span(g, raw, first, last)
            cost = self.image.write_time_s(request)
            if planned and line_s + cost > self._budget_s:
                break
            planned.append(request)
            line_s += cost
            self._next_group = (g + 1) % n
        return planned

    def _read(self, line: RtuLine, request: ReadRequest) -> list[int]:
        f, n = request.function, request.count
        answer = self._call(line, request.describe(), rtu.read_pdu(f, request.address, n), rtu.response_size(f, n))
        if f == rtu.READ_DISCRETE_INPUTS:
            return rtu.unpack_bits(answer[2:], n)
        return rtu.unpack_registers(answer[2:], n)

    def _write(self, line: RtuLine, request: WriteRequest) -> None:
        f, values = request.function, request.values
        pdu = rtu.write_pdu(f, request.address, values)
        self._call(line, request.describe(), pdu, rtu.response_size(f, len(values)))

    def _call(self, line: RtuLine, what: str, pdu: bytes, answer_size: int) -> bytes:
        """One request and its answer; every failure becomes a PlcLinkError naming the request."""
        try:
            return line.transact(self.config.unit_id, pdu, answer_size)
        except NoAnswer as exc:
            raise PlcTimeout(
                f"{what}: no valid response within {self.config.timeout_ms:g} ms ({exc.describe()})"
            ) from None
        except ExceptionAnswer as exc:
            name = _EXCEPTION_NAMES.get(exc.code, "exception")
            raise PlcExceptionResponse(f"{what}: PLC answered exception {exc.code:02d} ({name})", exc.code) from None
        except PortFailed as exc:
            self.close()
            raise PlcPortError(f"{what}: {exc}") from None

    # -- supervision -----------------------------------------------------------------------

    def cycle(self, outputs: Sequence[float], now_s: float | None = None) -> bool:
        """One supervised cycle; True when the inputs were refreshed. Never raises a link
        failure: it is counted in `status` (state, missed, failed, losses, error)."""
        s = self.status
        if not self.port:
            s.state, s.error = LinkState.DOWN, NO_PORT
            return False
        now_s = time.monotonic() if now_s is None else now_s
        if s.state == LinkState.LOST:
            if now_s < self._next_reconnect:
                return False
            self.close()  # a fresh open: the device may have been replaced
        t0 = time.perf_counter()
        try:
            self.exchange(outputs)
        except PlcLinkError as exc:
            s.cycle_s = time.perf_counter() - t0
            self._count_line()
            self._failed(str(exc), now_s)
            return False
        s.cycle_s = time.perf_counter() - t0
        self._count_line()
        s.exchanges += 1
        s.missed = 0
        s.state = LinkState.OK
        s.error = self.output_errors[0] if self.output_errors else ""
        return True

    def _count_line(self) -> None:
        """The line's dropped answers and noise, since the master was made (across reconnections)."""
        dropped, noise = self._closed_counts
        if self._line is not None:
            dropped, noise = dropped + self._line.misfits, noise + self._line.noise
        self.status.dropped, self.status.noise = dropped, noise

    def _failed(self, error: str, now_s: float) -> None:
        s = self.status
        s.failed += 1
        s.missed += 1
        s.error = error
        if s.state == LinkState.LOST:
            self._next_reconnect = now_s + self.config.reconnect_s
        elif s.missed >= self.config.lost_after_cycles:
            s.state = LinkState.LOST
            s.losses += 1
            self._next_reconnect = now_s + self.config.reconnect_s
            log.warning("PLC link lost after %d failed exchanges: %s", s.missed, error)
        else:  # on the way to a loss: said, so that a stale image tells answers missing from a link not run
            log.warning("PLC link: exchange failed (%d of %d before the link counts as lost): %s", s.missed,
                        self.config.lost_after_cycles, error)
