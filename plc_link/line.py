"""The master's end of the RTU line: send one request, take back the answer that is its own.

Modbus RTU has no transaction id. An answer that comes after the master gave up on it (a
slave or a host busy for longer than the timeout) is still on its way when the next request
goes out, and a reader that takes the first frame it sees answers the next request with it:
a write's echo read as the input image, then that request's own answer read as the one after,
a chain of failed exchanges that ends in a lost link. This reader takes a frame as the answer
only when it fits the request, and drops the others:

- the unit id and the function code (or the function's exception code) must be the request's;
- a read's answer must carry the byte count the request asked for;
- a write's answer must echo the request's address and value or quantity.

A late answer to a read of the same table and size cannot be told from the current one: it is
then taken, and the inputs are one exchange older than they could be (the next read has them
fresh); the current answer is dropped as a misfit by the next request of another function, or
thrown away with the receive buffer before the next request goes out.

A request goes out no sooner than 3.5 characters of silence after the last answer ended, the
gap by which an RTU slave knows a frame is over. The timeout counts from the request's send; at the deadline whatever has arrived is still
read and parsed, so a master that was not scheduled while the answer came does not declare a
timeout with the answer in its buffer. Bytes that make no frame (a bad CRC, an unknown
function) are dropped one at a time until a frame starts, as a real line's noise needs; the
tail of a frame cut short, whose length byte promises bytes that never come, does not hide the
answer behind it.
"""

from __future__ import annotations

import select
import termios
import time

import serial

from . import rtu


class NoAnswer(Exception):
    """No answer that fits the request came within the timeout. `received` bytes came meanwhile
    (0: the line stayed silent; more: noise or answers to other requests), and the master gave
    up `waited_s` after sending: far past the timeout, the master itself was not scheduled."""

    def __init__(self, received: int = 0, waited_s: float = 0.0) -> None:
        super().__init__(received, waited_s)
        self.received, self.waited_s = received, waited_s

    def describe(self) -> str:
        """What came, in words: "nothing came in 0.251 s", "7 bytes came, none the answer, in ..."."""
        came = "nothing came" if not self.received else f"{self.received} bytes came, none the answer,"
        return f"{came} in {self.waited_s:.3f} s"


class ExceptionAnswer(Exception):
    """The slave answered the request with a Modbus exception response."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


class PortFailed(Exception):
    """The serial port could not be opened, or reading or writing it failed."""


class RtuLine:
    """One serial port, opened on `open()`, for request/answer transactions with one slave."""

    def __init__(
        self, device: str, baud: int, parity: str, stop_bits: int, timeout_s: float, silence_s: float,
        local_echo: bool = False,
    ) -> None:
        """`silence_s` is the inter-frame gap of the line as configured (a pty is opened without
        parity, but the gap is the one of the real cable's character time). `local_echo`: the
        port hears what it sends (half-duplex RS-485 with the receiver left on): each request's
        echo is taken off the front of what comes back. Without it, a single write's echo would
        be read as the PLC's answer (the answer repeats the request)."""
        self.device, self.baud, self.parity, self.stop_bits = device, baud, parity, stop_bits
        self.timeout_s, self.silence_s = timeout_s, silence_s
        self.local_echo = local_echo
        self.misfits = 0  # frames dropped because they were not the answer asked for
        self.noise = 0  # bytes dropped because they made no frame
        self._port: serial.Serial | None = None
        self._quiet_at = 0.0  # when the line has been silent long enough for the next request

    def open(self) -> None:
        """Open the port (once; later calls keep it). Raises PortFailed."""
        if self._port is not None:
            return
        try:
            self._port = serial.Serial(
                self.device, baudrate=self.baud, bytesize=8, parity=self.parity,
                stopbits=self.stop_bits, timeout=0, write_timeout=self.timeout_s,
            )
        except (serial.SerialException, OSError, ValueError, termios.error) as exc:
            raise PortFailed(f"cannot open serial port {self.device!r} ({exc})") from None

    def close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            finally:
                self._port = None

    def transact(self, unit: int, pdu: bytes, answer_size: int) -> bytes:
        """Send `pdu` (function and data) to `unit`; return the answer's PDU (function and data,
        without unit and CRC). `answer_size` is the whole answer frame's expected length.
        Raises NoAnswer, ExceptionAnswer or PortFailed."""
        if self._port is None:
            raise PortFailed(f"serial port {self.device!r} is not open")
        port = self._port
        wait = self._quiet_at - time.monotonic()
        if wait > 0.0:
            time.sleep(wait)
        try:
            port.reset_input_buffer()  # answers that came after their request was given up
            request = rtu.with_crc(bytes((unit,)) + pdu)
            port.write(request)
            deadline = time.monotonic() + self.timeout_s
            buffer = bytearray()
            received = 0
            echo = request if self.local_echo else b""
            while True:
                if echo:
                    echo = self._take_echo(buffer, echo)
                answer = None if echo else self._take_answer(buffer, unit, pdu, answer_size)
                if answer is not None:
                    return answer
                waiting = port.in_waiting
                if not waiting:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0.0:
                        raise NoAnswer(received, time.monotonic() - deadline + self.timeout_s)
                    select.select([port.fileno()], [], [], remaining)
                    waiting = port.in_waiting
                data = port.read(max(1, waiting))  # never blocks (timeout 0); a hung-up line raises
                received += len(data)
                buffer += data
        except serial.SerialException as exc:
            self.close()
            raise PortFailed(f"serial port {self.device!r} failed ({exc})") from None
        except (OSError, termios.error) as exc:  # termios.error: a hung-up pty refusing a flush
            self.close()
            raise PortFailed(f"serial port {self.device!r}: {exc}") from None
        finally:  # an answer, an exception answer or a timeout: the next request keeps the gap
            self._quiet_at = time.monotonic() + self.silence_s

    def _take_echo(self, buffer: bytearray, echo: bytes) -> bytes:
        """Take the request's echo off the front of `buffer`; what of it is still to come. What
        is not the echo ends the wait for it (the echo was lost): parsing goes on from there."""
        n = min(len(buffer), len(echo))
        if buffer[:n] != echo[:n]:
            return b""
        del buffer[:n]
        return echo[n:]

    def _take_answer(self, buffer: bytearray, unit: int, pdu: bytes, answer_size: int) -> bytes | None:
        """Take frames off the front of `buffer` until one is the answer to `pdu`; None when the
        buffer holds no such answer yet. When the front is the start of a frame still coming (or
        the tail of one cut short, whose length byte promises more than will come), the answer may
        already be further on: it is looked for there too, by its exact size and CRC."""
        function = pdu[0]
        while True:
            size = rtu.answer_length(buffer)
            if size is None or len(buffer) < size:
                if size == answer_size and buffer[0] == unit and buffer[1] == function:
                    return None  # the answer itself, still coming
                return self._find_answer(buffer, unit, pdu, answer_size)
            if size == 0 or not rtu.crc_ok(bytes(buffer[:size])):
                del buffer[0]  # noise: hunt for the start of a frame
                self.noise += 1
                continue
            frame = bytes(buffer[:size])
            del buffer[:size]
            if frame[0] != unit:
                self.misfits += 1
                continue
            if frame[1] != function | 0x80 and (frame[1] != function or size != answer_size or not _echoes(frame, pdu)):
                self.misfits += 1
                continue
            return _answer_of(frame)

    def _find_answer(self, buffer: bytearray, unit: int, pdu: bytes, answer_size: int) -> bytes | None:
        """The answer to `pdu` (or its exception answer) beyond the front of `buffer`, taken with
        everything before it (counted as noise); None when it is not there."""
        function = pdu[0]
        for at in range(1, len(buffer) - rtu.EXCEPTION_RESPONSE_SIZE + 1):
            if buffer[at] != unit or buffer[at + 1] not in (function, function | 0x80):
                continue
            size = rtu.EXCEPTION_RESPONSE_SIZE if buffer[at + 1] & 0x80 else answer_size
            frame = bytes(buffer[at : at + size])
            if len(frame) < size or not rtu.crc_ok(frame) or not (frame[1] & 0x80 or _echoes(frame, pdu)):
                continue
            del buffer[: at + size]
            self.noise += at
            return _answer_of(frame)
        return None


def _answer_of(frame: bytes) -> bytes:
    """The PDU of an answer frame that fits its request (without unit and CRC); an exception
    answer raises ExceptionAnswer with its code."""
    if frame[1] & 0x80:
        raise ExceptionAnswer(frame[2])
    return frame[1:-2]


def _echoes(frame: bytes, pdu: bytes) -> bool:
    """A write's answer repeats the request's address and value (single) or quantity
    (multiple); a read's answer carries the byte count its size says."""
    if pdu[0] in (rtu.WRITE_SINGLE_COIL, rtu.WRITE_SINGLE_REGISTER, rtu.WRITE_MULTIPLE_COILS, rtu.WRITE_MULTIPLE_REGISTERS):
        return frame[2:6] == pdu[1:5]
    return frame[2] == len(frame) - rtu.FRAME_OVERHEAD - 1
