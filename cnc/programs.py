"""The machine's program directory: what a station may load by name, read safely.

A station names a program (`cmd/load`); the controller reads it. Without a fence that is a file
reader for anyone holding the lock: the credentials file came back line by line in the parse
error, `/dev/zero` grew the planner's memory without bound and a named pipe hung it. So a name is
resolved inside the program directory (symbolic links followed, then checked: a link out of it
is refused), the file must be a regular one, its size is checked before a byte is read, and it
must be text: a file that is not is refused by what it is, never by echoing its lines.

`read_program` is also the planner's own reader: whoever asks it, a program is read the same
bounded way (opened without blocking, checked on the open descriptor, read to the limit).
"""

from __future__ import annotations

import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from .bus.service import CommandRefused

_CONTROL = re.compile(rb"[\x00-\x08\x0b\x0e-\x1f\x7f]")  # tab, LF, FF, CR are text; the rest is not

_KINDS = {
    stat.S_IFDIR: "a directory", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
    stat.S_IFIFO: "a named pipe", stat.S_IFSOCK: "a socket", stat.S_IFLNK: "a symbolic link",
}


@dataclass(frozen=True)
class ProgramDirectory:
    """The directory stations load programs from (`[gateway] program_dir`)."""

    root: Path
    max_bytes: int

    def resolve(self, name: str) -> Path:
        """The file `name` (a plain name, or a path inside the directory) stands for, after links.
        CommandRefused when it lies outside the directory or does not exist."""
        if not name or "\0" in name:
            raise CommandRefused(f"program name {name!r} is empty or not a file name")
        root = self.root.resolve()
        candidate = Path(name) if Path(name).is_absolute() else root / name
        lexical = Path(os.path.normpath(candidate))
        if not (lexical.is_relative_to(root) or lexical.is_relative_to(self.root)):
            raise _outside(name, root)
        try:
            path = candidate.resolve(strict=True)
        except FileNotFoundError:
            raise CommandRefused(f"{name}: no such program in {root}") from None
        except (OSError, RuntimeError) as exc:  # a loop of links, a component that is not a directory
            raise CommandRefused(f"{name}: cannot be resolved in {root}: {exc}") from None
        if not path.is_relative_to(root):  # a link out of it
            raise _outside(name, root)
        return path

    def read(self, name: str) -> tuple[Path, bytes]:
        """Resolve `name` and read it as `read_program` does."""
        path = self.resolve(name)
        return path, read_program(path, self.max_bytes, shown_as=name)

    def names(self) -> list[str]:
        """The regular files of the directory (not hidden ones: uploads in progress), sorted."""
        if not self.root.is_dir():
            return []
        return sorted(p.name for p in self.root.iterdir() if not p.name.startswith(".") and p.is_file())


def _outside(name: str, root: Path) -> CommandRefused:
    return CommandRefused(f"{name}: outside the program directory {root}: load programs from there "
                          "(upload them, or copy them into it)")


def read_program(path: str | Path, max_bytes: int, shown_as: str | None = None) -> bytes:
    """The bytes of the program file `path`: a regular file of at most `max_bytes`, text.
    CommandRefused names the file (as `shown_as`) and what is wrong with it, never its contents."""
    shown = shown_as or str(path)
    try:
        # O_NONBLOCK: a named pipe swapped in after a check must not hang the reader
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise CommandRefused(f"{shown}: cannot read the program: {exc.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = _KINDS.get(stat.S_IFMT(st.st_mode), "not a regular file")
            raise CommandRefused(f"{shown}: is {kind}, not a program file")
        if st.st_size > max_bytes:
            raise CommandRefused(f"{shown}: the program is {st.st_size} bytes; this machine accepts at most {max_bytes}")
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > max_bytes:  # it grew while being read
            raise CommandRefused(f"{shown}: the program is more than {max_bytes} bytes; this machine accepts at most {max_bytes}")
    finally:
        os.close(fd)
    data = b"".join(chunks)
    check_text(data, shown)
    return data


def check_text(data: bytes, shown: str) -> None:
    """CommandRefused unless `data` is UTF-8 text without control characters; says where, not what."""
    bad = _CONTROL.search(data)
    if bad is None:
        try:
            data.decode("utf-8")
            return
        except UnicodeDecodeError as exc:
            at, why = exc.start, "not UTF-8 text"
    else:
        at, why = bad.start(), f"not text: control character 0x{data[bad.start()]:02x}"
    line = data.count(b"\n", 0, at) + 1
    raise CommandRefused(f"{shown}: line {line}: {why} (a binary file?); it is not loaded")
