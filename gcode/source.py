"""Program text: bytes to lines, the way LinuxCNC reads a file.

UTF-8 is tried first and Latin-1 taken otherwise (CAM post-processors still write it);
CRLF, CR and LF all end a line; a file that starts with a `%` line ends at the next `%`
line (tape markers). Binary files are refused before anything is interpreted.
"""

from __future__ import annotations

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


def split_lines(text: str, file: str = "<string>") -> tuple[list[str], int]:
    """Lines of the program proper and the index of the first line after the tape markers' end.

    Returns (lines, end): `lines` are all physical lines (1-based line n is lines[n-1]);
    interpretation stops before index `end` (the closing `%`, or the end of the file).
    """
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    for i, line in enumerate(lines) if lines and max(map(len, lines)) > MAX_LINE_LENGTH else ():
        if len(line) > MAX_LINE_LENGTH:
            raise GCodeError(
                f"line is {len(line)} characters long; the limit is {MAX_LINE_LENGTH}",
                code="line-too-long", file=file, line=i + 1, column=MAX_LINE_LENGTH + 1, source_line=line[:120],
            )
    end = len(lines)
    first = next((i for i, line in enumerate(lines) if line.strip()), None)
    if first is not None and lines[first].strip() == "%":
        closing = next((i for i in range(first + 1, len(lines)) if lines[i].strip() == "%"), None)
        if closing is None:
            raise GCodeError(
                "file starts with a '%' tape marker but has no closing '%' line",
                code="tape-marker", file=file, line=first + 1, column=1, source_line=lines[first],
            )
        end = closing
    return lines, end
