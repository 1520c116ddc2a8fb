"""A raw pseudo-terminal pair standing in for a serial cable between the CNC and the PLC.

The simulator serves on the pty's master side (a file descriptor); the CNC's Modbus master
opens the slave side by its device path (`/dev/pts/N`) with pyserial, exactly as it would
open `/dev/ttyUSB0`. Both ends are raw (no echo, no line discipline, 8-bit clean), so Modbus
frames pass unchanged. Closing the simulator's side hangs the line up: the master's requests
then fail, which is how a cut cable is simulated.
"""

from __future__ import annotations

import os
import termios
import tty


def _make_raw(fd: int) -> None:
    tty.setraw(fd, termios.TCSANOW)
    attrs = termios.tcgetattr(fd)
    attrs[3] &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN)
    termios.tcsetattr(fd, termios.TCSANOW, attrs)


class PtyPair:
    """A raw pty pair: `server_fd` for the simulator, `device` (path) for the master.

    Use as a context manager, or call `close()`; `close_server()` alone cuts the link.

    The slave side is not held open here: the master opens it by path, and while nobody
    has it open the simulator's reads report a hang-up, as a serial port without a cable
    would. The device exists as long as the simulator's side is open.

    A pty carries no parity bit: the kernel drops PARENB from the slave's settings, and
    glibc's tcsetattr then reports EINVAL for a change that only asks for parity, which
    fails pyserial's configuration. `is_pty(path)` lets the master open a pty without
    parity; the line timing still uses the configured parity.
    """

    def __init__(self) -> None:
        self.server_fd, slave_fd = os.openpty()
        try:
            _make_raw(self.server_fd)
            self.device: str = os.ttyname(slave_fd)
        finally:
            os.close(slave_fd)

    def close_server(self) -> None:
        """Close the simulator's end: the line goes dead for the master."""
        if self.server_fd >= 0:
            os.close(self.server_fd)
            self.server_fd = -1

    def close(self) -> None:
        """Close the pair (the master's own handle on the device is the master's to close)."""
        self.close_server()

    def __enter__(self) -> "PtyPair":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def is_pty(path: str) -> bool:
    """True when `path` is a pseudo-terminal slave (/dev/pts/N), not a real serial port."""
    return os.path.realpath(path).startswith("/dev/pts/")
