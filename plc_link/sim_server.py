"""Modbus RTU server (slave) of the PLC simulator, paced like a real serial line.

Serves the `PlcModel` at the addresses of the machine file's `[plc]` map on a file
descriptor (the simulator's end of a pty pair) with functions 01/02/03/04/05/06/15/16 and
exception responses 01 (function), 02 (address), 03 (quantity or value). Frames for other
unit ids are ignored, frames with a bad CRC dropped, as a real slave does.

Timing: a pty moves bytes instantly, so the server adds what the wire would cost. A request
is taken to start on the line when its first byte is seen (or when the line became free
after our last answer, if later), its last byte arrives `len x char` later, the slave
recognises the end of the frame after 3.5 characters of silence, and the answer is written
no earlier than that plus its own `len x char`. A master timing its exchanges therefore
measures what it would on a real 19200-baud cable. The model is stepped on the server's own
clock every `step_s`.

`start_simulator_process` runs model and server in a spawned child on a fresh pty pair and
returns a handle with the device path for the master and a Pipe for fault injection.
"""

from __future__ import annotations

import errno
import logging
import multiprocessing as mp
import os
import select
import signal
import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.context import BaseContext
from pathlib import Path
from typing import Any, Callable

from cnc.config import MachineConfig, PlcConfig, PlcVarConfig, load_machine

from . import rtu
from .image import decode_value, encode_value
from .pty_pair import PtyPair
from .sim_model import FAULTS, ModelError, PlantTimes, PlcModel

log = logging.getLogger(__name__)

#: a loop woken this much later than it asked for says so: a PLC stands for a CPU of its own, so
#: a master that counts answers missing then lost them to the host, not to the line or the PLC
STALL_S = 0.1

_READS = {  # function -> (table kind, bits, protocol limit)
    rtu.READ_COILS: ("coil", True, rtu.MAX_READ_BITS),
    rtu.READ_DISCRETE_INPUTS: ("discrete_input", True, rtu.MAX_READ_BITS),
    rtu.READ_HOLDING_REGISTERS: ("holding_register", False, rtu.MAX_READ_REGISTERS),
    rtu.READ_INPUT_REGISTERS: ("input_register", False, rtu.MAX_READ_REGISTERS),
}


class ModbusException(Exception):
    """A request the server answers with an exception response."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


@dataclass
class ServerStats:
    """What the server has seen; for tests and the CLI's summary."""

    requests: int = 0  # frames for our unit with a good CRC
    responses: int = 0
    exceptions: int = 0
    crc_errors: int = 0
    other_unit: int = 0
    unanswered: int = 0  # requests swallowed while the link_dead fault is on
    stalls: int = 0  # times the server's loop woke STALL_S or more after it asked to
    longest_stall_s: float = 0.0


class _Tables:
    """The map's four tables: address -> variable, and each table's size (highest address + 1)."""

    def __init__(self, config: PlcConfig) -> None:
        self.vars: dict[str, dict[int, PlcVarConfig]] = {k: {} for k in ("discrete_input", "input_register", "coil", "holding_register")}
        for v in config.var:
            self.vars[v.kind][v.address] = v
        self.size = {k: (max(t) + 1 if t else 0) for k, t in self.vars.items()}
        self.scratch: dict[tuple[str, int], int] = {}  # written addresses that carry no variable


class PlcSimServer:
    """The simulator's Modbus RTU slave on `fd`, in a thread: `start()`, `stop()`."""

    def __init__(self, config: PlcConfig, model: PlcModel, fd: int, step_s: float = 0.01, echo: bool = False) -> None:
        """`echo`: hand every request back before its answer, as a half-duplex RS-485 adapter with
        its receiver left on does (the master then needs `[plc] local_echo`)."""
        self.config, self.model, self.fd, self.step_s = config, model, fd, step_s
        self.echo = echo
        self.unit_id = config.unit_id
        self.char_s = rtu.char_time_s(config.baud, config.parity, config.stop_bits)
        self.silence_s = rtu.SILENCE_CHARS * self.char_s
        self.stats = ServerStats()
        self._tables = _Tables(config)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rx = bytearray()
        self._rx_first = 0.0
        self._rx_last = 0.0
        self._line_free = 0.0
        self._pending: tuple[float, bytes] | None = None
        self._late: dict[int, float] = {}  # function -> extra delay of its next answer (one-shot)
        self._noise = b""  # bytes sent just before the next answer (one-shot)
        self.error: BaseException | None = None

    def start(self) -> None:
        os.set_blocking(self.fd, False)
        self._thread = threading.Thread(target=self._run, name="plc-sim-server", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop serving and join the thread; the fd stays open (its owner closes it)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None

    def answer_late(self, function: int, extra_s: float) -> None:
        """Send the next answer to a request of `function` `extra_s` later than the line would
        (a PLC busy with its own scan, a host that did not schedule it): past the master's
        timeout, it arrives while the master waits for the answer to its next request. The
        requests behind it wait, as they would for a slave that answers in order."""
        if extra_s < 0:
            raise ValueError(f"answer_late: extra_s must be >= 0, got {extra_s!r}")
        self._late[function] = extra_s

    def noise_before_next_answer(self, data: bytes) -> None:
        """Put `data` on the line just ahead of the next answer (a noisy cable, a reflection):
        the master must drop it and still take the answer."""
        self._noise = bytes(data)

    def __enter__(self) -> "PlcSimServer":
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- the loop --------------------------------------------------------------------------

    def _run(self) -> None:
        next_step = woke = time.monotonic()
        hung_up = False  # nobody has the device open: retry reading at the next step
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= next_step:
                    self.model.step(now)
                    next_step = max(next_step + self.step_s, now)
                wake = next_step
                if self._pending is not None:
                    wake = min(wake, self._pending[0])
                if self._rx:
                    wake = min(wake, self._rx_last + self.silence_s)
                timeout = max(0.0, wake - time.monotonic())
                if hung_up:  # select would report the hung-up fd readable at once: wait instead
                    time.sleep(timeout)
                    hung_up, readable = False, False
                else:
                    readable = bool(select.select([self.fd], [], [], timeout)[0])
                now = time.monotonic()
                self._note_stall(now - woke - timeout)  # the loop's own work, and any oversleep
                woke = now
                if readable:
                    hung_up = not self._receive(now)
                self._send_due(time.monotonic())
                if self._pending is None:
                    self._parse(time.monotonic())
        except Exception as exc:  # a bug in the simulator: log it, keep it for the tests
            log.exception("PLC simulator server failed")
            self.error = exc

    def _note_stall(self, late_s: float) -> None:
        """Count and say a loop `late_s` behind its plan (its work since it last woke, and how far
        it overslept its wait: it never asks to sleep past its next model step), when that is
        `STALL_S` or more."""
        if late_s < STALL_S:
            return
        self.stats.stalls += 1
        self.stats.longest_stall_s = max(self.stats.longest_stall_s, late_s)
        log.warning("PLC simulator: its server ran %.0f ms behind (the host did not run it, or a step was slow): answers "
                    "due meanwhile went late", late_s * 1000.0)

    def _receive(self, now: float) -> bool:
        """Read what arrived; False when the other end is hung up (no master opened it)."""
        try:
            data = os.read(self.fd, 512)
        except BlockingIOError:
            return True
        except OSError as exc:
            if exc.errno == errno.EIO:
                return False
            raise
        if not data:
            return False
        if not self._rx:
            self._rx_first = now
        self._rx += data
        self._rx_last = now
        return True

    def _send_due(self, now: float) -> None:
        if self._pending is not None and now >= self._pending[0]:
            os.write(self.fd, self._pending[1])
            self._pending = None

    def _parse(self, now: float) -> None:
        """Take one complete frame off the receive buffer, by its function's length or, for
        an unknown function or garbage, by 3.5 characters of silence."""
        n = rtu.request_length(self._rx)
        if n is not None and len(self._rx) >= n:
            frame = bytes(self._rx[:n])
            del self._rx[:n]
            start = self._rx_first
            self._rx_first = now
        elif self._rx and now - self._rx_last >= self.silence_s:
            frame, start = bytes(self._rx), self._rx_first
            self._rx.clear()
        else:
            return
        if self.echo:
            os.write(self.fd, frame)  # the master's own request, heard back as it went out
        if not rtu.crc_ok(frame):
            self.stats.crc_errors += 1
            self._rx.clear()  # resynchronise on the next frame
            return
        if frame[0] not in (self.unit_id, 0):
            self.stats.other_unit += 1
            return
        self.stats.requests += 1
        response = self._execute(frame[1], frame[2:-2])
        if frame[0] == 0:
            return  # broadcast: executed, never answered
        if self.model.link_dead:
            self.stats.unanswered += 1
            return
        start = max(start, self._line_free)
        ready = start + (len(frame) + rtu.SILENCE_CHARS + len(response)) * self.char_s
        ready += self._late.pop(frame[1], 0.0)
        self._line_free = ready + self.silence_s
        self._pending = (ready, self._noise + response)
        self._noise = b""
        self.stats.responses += 1

    # -- the functions ---------------------------------------------------------------------

    def _execute(self, function: int, data: bytes) -> bytes:
        """The framed response (normal or exception) to one request PDU."""
        try:
            if function in _READS:
                pdu = self._read(function, data)
            elif function in (rtu.WRITE_SINGLE_COIL, rtu.WRITE_SINGLE_REGISTER):
                pdu = self._write_single(function, data)
            elif function in (rtu.WRITE_MULTIPLE_COILS, rtu.WRITE_MULTIPLE_REGISTERS):
                pdu = self._write_multiple(function, data)
            else:
                raise ModbusException(rtu.ILLEGAL_FUNCTION)
        except ModbusException as exc:
            self.stats.exceptions += 1
            pdu = bytes((function | 0x80, exc.code))
        return rtu.with_crc(bytes((self.unit_id,)) + pdu)

    def _check_range(self, kind: str, address: int, count: int, limit: int) -> None:
        if not 1 <= count <= limit:
            raise ModbusException(rtu.ILLEGAL_DATA_VALUE)
        if address + count > self._tables.size[kind]:
            raise ModbusException(rtu.ILLEGAL_DATA_ADDRESS)

    def _read(self, function: int, data: bytes) -> bytes:
        kind, bits, limit = _READS[function]
        address, count = int.from_bytes(data[0:2], "big"), int.from_bytes(data[2:4], "big")
        self._check_range(kind, address, count, limit)
        values = self.model.inputs() if kind in ("discrete_input", "input_register") else self.model.outputs()
        table = self._tables.vars[kind]
        raw = []
        for a in range(address, address + count):
            var = table.get(a)
            if var is None:
                raw.append(self._tables.scratch.get((kind, a), 0))
            else:
                raw.append(encode_value(var, values[var.id])[0] & 0xFFFF if var.id in values else 0)
        if bits:
            payload = rtu.pack_bits(raw)
        else:
            payload = rtu.pack_registers(raw)
        return bytes((function, len(payload))) + payload

    def _write_single(self, function: int, data: bytes) -> bytes:
        address, value = int.from_bytes(data[0:2], "big"), int.from_bytes(data[2:4], "big")
        if function == rtu.WRITE_SINGLE_COIL:
            if value not in (0x0000, 0xFF00):
                raise ModbusException(rtu.ILLEGAL_DATA_VALUE)
            self._check_range("coil", address, 1, 1)
            self._store("coil", address, 1 if value else 0)
        else:
            self._check_range("holding_register", address, 1, 1)
            self._store("holding_register", address, value)
        return bytes((function,)) + data[0:4]

    def _write_multiple(self, function: int, data: bytes) -> bytes:
        address, count = int.from_bytes(data[0:2], "big"), int.from_bytes(data[2:4], "big")
        bits = function == rtu.WRITE_MULTIPLE_COILS
        kind = "coil" if bits else "holding_register"
        limit = rtu.MAX_WRITE_BITS if bits else rtu.MAX_WRITE_REGISTERS
        byte_count = data[4] if len(data) > 4 else -1
        expected = (count + 7) // 8 if bits else 2 * count
        if byte_count != expected or len(data) != 5 + byte_count:
            raise ModbusException(rtu.ILLEGAL_DATA_VALUE)
        self._check_range(kind, address, count, limit)
        values = rtu.unpack_bits(data[5:], count) if bits else rtu.unpack_registers(data[5:], count)
        for i, value in enumerate(values):
            self._store(kind, address + i, value)
        return bytes((function,)) + data[0:4]

    def _store(self, kind: str, address: int, raw: int) -> None:
        var = self._tables.vars[kind].get(address)
        if var is None:
            self._tables.scratch[(kind, address)] = raw
        else:
            self.model.set_output(var.id, decode_value(var, raw))


# -- as a child process --------------------------------------------------------------------


@dataclass
class SimulatorHandle:
    """A simulator running in a child process on its own pty pair; `device` is the master's."""

    process: mp.process.BaseProcess
    device: str
    commands: Connection  # requests to the child; each is answered
    _lock: threading.Lock

    def _ask(self, *request: Any) -> Any:
        with self._lock:
            self.commands.send(request)
            if not self.commands.poll(5.0):
                raise TimeoutError(f"PLC simulator (pid {self.process.pid}) did not answer {request[0]!r}")
            ok, value = self.commands.recv()
        if not ok:
            raise ValueError(value)
        return value

    def inject(self, name: str, on: bool) -> None:
        """Switch a fault of the simulated PLC on or off (names in sim_model.FAULTS)."""
        self._ask("inject", name, bool(on))

    def press_button(self) -> None:
        self._ask("press_button")

    def answer_late(self, function: int, extra_s: float) -> None:
        """The next answer to `function` comes `extra_s` late (see PlcSimServer.answer_late)."""
        self._ask("answer_late", int(function), float(extra_s))

    def inputs(self) -> dict[str, float]:
        """What the simulated PLC publishes now."""
        return self._ask("inputs")

    def outputs(self) -> dict[str, float]:
        """What the CNC last wrote to it."""
        return self._ask("outputs")

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the child (the pty goes away with it: the master's requests fail)."""
        if self.process.is_alive():
            try:
                self._ask("stop")
            except (TimeoutError, EOFError, BrokenPipeError, OSError):
                self.process.terminate()
            self.process.join(timeout_s)
            if self.process.is_alive():
                self.process.kill()
                self.process.join(timeout_s)
        self.commands.close()


def start_simulator_process(
    config: str | Path | MachineConfig | PlcConfig,
    ctx: BaseContext | None = None,
    times: PlantTimes | None = None,
    timeout_s: float = 10.0,
) -> SimulatorHandle:
    """Start the PLC simulator in a spawned child on a fresh pty pair; returns when it serves.
    `ctx` is a multiprocessing context (default: spawn). Raises RuntimeError with the child's
    message when it cannot start (e.g. the map lacks a variable the simulated program needs).
    Faults reach the child through the returned handle (`inject`, `press_button`), over a Pipe."""
    return launch_simulator_process(config, ctx, times, timeout_s)()


def launch_simulator_process(
    config: str | Path | MachineConfig | PlcConfig,
    ctx: BaseContext | None = None,
    times: PlantTimes | None = None,
    timeout_s: float = 10.0,
) -> Callable[[], SimulatorHandle]:
    """Spawn the simulator now and return what waits until it serves (and gives its handle, or
    raises as start_simulator_process does): the caller does other start-up meanwhile. Spawn
    from the thread that lives as long as the simulator should: the child ends with it."""
    if isinstance(config, (str, Path)):
        config = load_machine(config)
    plc = config.plc if isinstance(config, MachineConfig) else config
    ctx = ctx or mp.get_context("spawn")
    parent, child = ctx.Pipe()
    process = ctx.Process(target=_child_main, args=(plc, times, child, os.getpid()), name="plc-sim", daemon=True)
    process.start()
    child.close()
    started = time.monotonic()

    def serving() -> SimulatorHandle:
        if not parent.poll(max(0.0, timeout_s - (time.monotonic() - started))):
            process.kill()
            raise RuntimeError(f"PLC simulator did not start within {timeout_s:g} s")
        ok, value = parent.recv()
        if not ok:
            process.join(timeout_s)
            raise RuntimeError(f"PLC simulator did not start: {value}")
        return SimulatorHandle(process, value, parent, threading.Lock())
    return serving


def _child_main(plc: PlcConfig, times: PlantTimes | None, conn: Connection, launcher_pid: int) -> None:
    from cnc.runtime.child import die_with

    die_with(launcher_pid)  # a simulator outliving its controller would hold the pty for the next one
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops us in order
    logging.basicConfig(level=logging.WARNING,
                        format=f"%(asctime)s plc-sim[{os.getpid()}] %(levelname)s %(message)s")
    try:  # it stands for a PLC with a CPU of its own: the host's load is not its load
        os.nice(-10)
    except OSError:
        pass  # not permitted: it shares the CPU like any process
    try:
        model = PlcModel(plc, times)
    except ModelError as exc:
        conn.send((False, str(exc)))
        return
    with PtyPair() as pair:
        server = PlcSimServer(plc, model, pair.server_fd)
        server.start()
        conn.send((True, pair.device))
        try:
            _answer(model, server, conn)
        finally:
            server.stop()


def _answer(model: PlcModel, server: PlcSimServer, conn: Connection) -> None:
    """Serve the parent's requests until it says stop or goes away."""
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return
        verb = request[0]
        if verb == "stop":
            conn.send((True, None))
            return
        if verb == "inject":
            if request[1] not in FAULTS:
                conn.send((False, f"unknown PLC simulator fault {request[1]!r}; known: {', '.join(FAULTS)}"))
                continue
            model.inject(request[1], request[2])
            conn.send((True, None))
        elif verb == "press_button":
            model.press_button()
            conn.send((True, None))
        elif verb == "answer_late":
            try:
                server.answer_late(request[1], request[2])
            except ValueError as exc:
                conn.send((False, str(exc)))
                continue
            conn.send((True, None))
        elif verb == "inputs":
            conn.send((True, model.inputs()))
        elif verb == "outputs":
            conn.send((True, model.outputs()))
        else:
            conn.send((False, f"unknown PLC simulator request {verb!r}"))
