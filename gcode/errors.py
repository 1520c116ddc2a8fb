"""GCodeError: bad input in a G-code program, with file, line, column, a stable code and the message.

Printed as the compiler convention:

    part.ngc:42:9: error: G2 radius 4.000 mm is smaller than kerf compensation radius 5.000 mm
       42 | G41 D3 G2 X10 Y0 R4
          |         ^
"""

from __future__ import annotations


class GCodeError(Exception):
    """A program is not valid; raised at the first error, as LinuxCNC does."""

    def __init__(
        self,
        message: str,
        *,
        code: str = "syntax",
        file: str = "<string>",
        line: int = 0,
        column: int = 0,
        source_line: str | None = None,
    ) -> None:
        super().__init__(message)
        self.message, self.code = message, code
        self.file, self.line, self.column = file, line, column
        self.source_line = source_line

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}: error: {self.message}"

    def render(self) -> str:
        """The one-line form followed by the source line and a caret under the column."""
        out = str(self)
        if self.source_line is not None:
            text = self.source_line.rstrip("\r\n").expandtabs(1)
            gutter = f"{self.line:>6} | "
            out += f"\n{gutter}{text}\n{' ' * (len(gutter) - 2)}| {' ' * max(self.column - 1, 0)}^"
        return out

    def located(self, file: str, line: int, column: int, source_line: str | None) -> "GCodeError":
        """Fill in where the error is, keeping what the raiser already knew."""
        if not self.line:
            self.line = line
        if not self.column:
            self.column = column
        if self.file == "<string>":
            self.file = file
        if self.source_line is None and self.line == line:
            self.source_line = source_line
        return self
