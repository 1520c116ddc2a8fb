"""Modbus RTU framing arithmetic: CRC-16/Modbus, character timing and frame sizes.

Shared by the master's timing budget, the simulator's server (which must pace its answers
like a real serial line) and the benchmark. Frame sizes follow the Modbus application
protocol v1.1b3: an RTU frame is address (1) + function (1) + data + CRC (2), and frames
are separated by at least 3.5 character times of silence on the line.
"""

from __future__ import annotations

from typing import Sequence

# Function codes this project uses (and the simulator serves).
READ_COILS = 0x01
READ_DISCRETE_INPUTS = 0x02
READ_HOLDING_REGISTERS = 0x03
READ_INPUT_REGISTERS = 0x04
WRITE_SINGLE_COIL = 0x05
WRITE_SINGLE_REGISTER = 0x06
WRITE_MULTIPLE_COILS = 0x0F
WRITE_MULTIPLE_REGISTERS = 0x10

# Exception codes
ILLEGAL_FUNCTION = 0x01
ILLEGAL_DATA_ADDRESS = 0x02
ILLEGAL_DATA_VALUE = 0x03

# Per-request quantity limits of the protocol
MAX_READ_BITS = 2000
MAX_READ_REGISTERS = 125
MAX_WRITE_BITS = 1968
MAX_WRITE_REGISTERS = 123

FRAME_OVERHEAD = 4  # address + function + CRC
SILENCE_CHARS = 3.5  # inter-frame gap, in character times

_BIT_FUNCTIONS = (READ_COILS, READ_DISCRETE_INPUTS, WRITE_MULTIPLE_COILS)


def _crc_table() -> tuple[int, ...]:
    """Table-driven CRC-16/Modbus: reflected polynomial 0xA001, one entry per byte value."""
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16/Modbus of `data` (init 0xFFFF, reflected 0x8005); sent low byte first."""
    crc = 0xFFFF
    for b in data:
        crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ b) & 0xFF]
    return crc


def with_crc(frame: bytes) -> bytes:
    """`frame` followed by its CRC, low byte first, as it goes on the line."""
    crc = crc16(frame)
    return frame + bytes((crc & 0xFF, crc >> 8))


def crc_ok(frame: bytes) -> bool:
    """True when the last two bytes of `frame` are the CRC of the bytes before them."""
    return len(frame) >= 4 and crc16(frame[:-2]) == frame[-2] | (frame[-1] << 8)


def bits_per_char(parity: str, stop_bits: int) -> int:
    """Bits on the line per character: start + 8 data + parity (E/O) + stop bits."""
    return 1 + 8 + (0 if parity == "N" else 1) + stop_bits


def char_time_s(baud: int, parity: str = "E", stop_bits: int = 1) -> float:
    """Time one character takes on the line at `baud`."""
    return bits_per_char(parity, stop_bits) / baud


def request_size(function: int, count: int) -> int:
    """Bytes of the request frame of `function` for `count` bits or registers."""
    if function in (READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return FRAME_OVERHEAD + 4  # start address, quantity
    if function in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER):
        return FRAME_OVERHEAD + 4  # address, value
    if function == WRITE_MULTIPLE_COILS:
        return FRAME_OVERHEAD + 5 + (count + 7) // 8  # start, quantity, byte count, packed bits
    if function == WRITE_MULTIPLE_REGISTERS:
        return FRAME_OVERHEAD + 5 + 2 * count
    raise ValueError(f"function code {function:#04x} is not one this link uses")


def response_size(function: int, count: int) -> int:
    """Bytes of the normal (not exception) response frame of `function` for `count` items."""
    if function in _BIT_FUNCTIONS[:2]:
        return FRAME_OVERHEAD + 1 + (count + 7) // 8  # byte count, packed bits
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return FRAME_OVERHEAD + 1 + 2 * count
    if function in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS):
        return FRAME_OVERHEAD + 4  # echo of address and value / quantity
    raise ValueError(f"function code {function:#04x} is not one this link uses")


EXCEPTION_RESPONSE_SIZE = FRAME_OVERHEAD + 1  # exception code


def request_length(frame: bytes | bytearray) -> int | None:
    """Length of the master's request frame that starts `frame`, when its function tells it
    (None: too few bytes yet, or a function this link does not use: the slave then waits for
    the line's silence to end the frame)."""
    if len(frame) < 2:
        return None
    function = frame[1]
    if function in (READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS,
                    WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER):
        return FRAME_OVERHEAD + 4
    if function in (WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS):
        return FRAME_OVERHEAD + 5 + frame[6] if len(frame) >= 7 else None
    return None


def answer_length(frame: bytes | bytearray) -> int | None:
    """Length of the slave's answer frame that starts `frame`: None while too few bytes
    arrived to tell, 0 when the function is not one a slave of this link answers with
    (garbage on the line: the reader drops a byte and hunts for the next frame)."""
    if len(frame) < 2:
        return None
    function = frame[1]
    if function & 0x80:
        return EXCEPTION_RESPONSE_SIZE if function & 0x7F in _ALL_FUNCTIONS else 0
    if function in (READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return FRAME_OVERHEAD + 1 + frame[2] if len(frame) >= 3 else None
    if function in _ALL_FUNCTIONS:
        return FRAME_OVERHEAD + 4
    return 0


_ALL_FUNCTIONS = (
    READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS,
    WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS,
)


def pack_bits(values: Sequence[int]) -> bytes:
    """Modbus bit packing: first bit in the least significant bit of the first byte."""
    out = bytearray((len(values) + 7) // 8)
    for i, v in enumerate(values):
        if v:
            out[i // 8] |= 1 << (i % 8)
    return bytes(out)


def unpack_bits(payload: bytes, count: int) -> list[int]:
    """The first `count` bits of a packed payload (the inverse of `pack_bits`)."""
    return [(payload[i // 8] >> (i % 8)) & 1 for i in range(count)]


def pack_registers(values: Sequence[int]) -> bytes:
    """16-bit registers as they go on the line: each big-endian (raw values, taken modulo 2^16)."""
    return b"".join((v & 0xFFFF).to_bytes(2, "big") for v in values)


def unpack_registers(payload: bytes, count: int) -> list[int]:
    """The first `count` registers of a payload (the inverse of `pack_registers`)."""
    return [int.from_bytes(payload[2 * i : 2 * i + 2], "big") for i in range(count)]


def read_pdu(function: int, address: int, count: int) -> bytes:
    """The PDU (function and data) of a read of `count` bits or registers from `address`."""
    return bytes((function,)) + address.to_bytes(2, "big") + count.to_bytes(2, "big")


def write_pdu(function: int, address: int, values: Sequence[int]) -> bytes:
    """The PDU of a write of raw `values` from `address`: single or multiple, coils or
    holding registers, as `function` says. The slave's answer echoes its first 5 bytes."""
    head = bytes((function,)) + address.to_bytes(2, "big")
    if function == WRITE_SINGLE_COIL:
        return head + (b"\xff\x00" if values[0] else b"\x00\x00")
    if function == WRITE_SINGLE_REGISTER:
        return head + (values[0] & 0xFFFF).to_bytes(2, "big")
    if function == WRITE_MULTIPLE_COILS:
        payload = pack_bits(values)
    elif function == WRITE_MULTIPLE_REGISTERS:
        payload = pack_registers(values)
    else:
        raise ValueError(f"function code {function:#04x} is not a write this link uses")
    return head + len(values).to_bytes(2, "big") + bytes((len(payload),)) + payload


def transaction_time_s(function: int, count: int, char_s: float) -> float:
    """Theoretical minimum time of one request/response pair: both frames on the line, each
    followed by its 3.5-character silence (the receiver only knows a frame ended after it)."""
    chars = request_size(function, count) + response_size(function, count) + 2 * SILENCE_CHARS
    return chars * char_s
