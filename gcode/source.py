"""Program text: bytes to lines, the way LinuxCNC reads a file.

UTF-8 is tried first and Latin-1 taken otherwise (CAM post-processors still write it);
CRLF, CR and LF all end a line; a file that starts with a `%` line ends at the next `%`
line (tape markers). Binary files are refused before anything is interpreted.
"""

from __future__ import annotations

import re

import numpy as np

from .errors import GCodeError

MAX_LINE_LENGTH = 4096  # LinuxCNC's LINELEN is 255; CAM comments can be longer, so allow more but stay bounded


def decode(data: bytes, file: str = "<string>") -> str:
    """Decode program bytes; NUL bytes mean a binary file."""
    nul = data.find(b"\x00")
    if nul >= 0:
        line = data.count(b"\n", 0, nul) + 1
        col = nul - (data.rfind(b"\n", 0, nul) + 1) + 1
        raise GCodeError("file contains NUL bytes: not a G-code text file", code="binary", file=file, line=line, column=col)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


class SourceLines:
    """The program's lines as views into one text: no Python string per line until one is asked for.

    `text` has "\n" line ends only and ends with "\n"; line i (0-based) is
    text[starts[i] : starts[i + 1] - 1].
    """

    def __init__(self, text: str) -> None:
        if text and not text.endswith("\n"):
            text += "\n"
        self.text = text
        starts = np.empty(text.count("\n") + 1, dtype=np.int64)
        starts[0] = 0
        if text.isascii():  # byte offsets are character offsets: find the newlines in C
            starts[1:] = np.flatnonzero(np.frombuffer(text.encode("ascii"), dtype=np.uint8) == 10) + 1
        else:
            starts[1:] = np.fromiter((m.end() for m in re.finditer("\n", text)), dtype=np.int64, count=len(starts) - 1)
        self.starts = starts

    def __len__(self) -> int:
        return len(self.starts) - 1

    def __getitem__(self, i: int) -> str:
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        return self.text[self.starts[i] : self.starts[i + 1] - 1]

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def lengths(self) -> np.ndarray:
        return np.diff(self.starts) - 1


def split_lines(text: str, file: str = "<string>") -> tuple[SourceLines, int]:
    """Lines of the program and the index of the first line after the tape markers' end.

    Returns (lines, end): line n (1-based) is lines[n - 1]; interpretation stops before
    index `end` (the closing `%`, or the end of the file).
    """
    lines = SourceLines(text.replace("\r\n", "\n").replace("\r", "\n"))
    lengths = lines.lengths()
    if len(lengths) and lengths.max() > MAX_LINE_LENGTH:
        i = int(np.argmax(lengths > MAX_LINE_LENGTH))
        raise GCodeError(
            f"line is {int(lengths[i])} characters long; the limit is {MAX_LINE_LENGTH}",
            code="line-too-long", file=file, line=i + 1, column=MAX_LINE_LENGTH + 1, source_line=lines[i][:120],
        )
    end = len(lines)
    nonblank = re.search(r"\S", lines.text)
    first = int(np.searchsorted(lines.starts, nonblank.start(), side="right")) - 1 if nonblank else None
    if first is not None and lines[first].strip() == "%":
        closing = re.compile(r"^[ \t]*%[ \t]*$", re.M).search(lines.text, int(lines.starts[first + 1]))
        if closing is None:
            raise GCodeError(
                "file starts with a '%' tape marker but has no closing '%' line",
                code="tape-marker", file=file, line=first + 1, column=1, source_line=lines[first],
            )
        end = int(np.searchsorted(lines.starts, closing.start(), side="right")) - 1
    return lines, end
