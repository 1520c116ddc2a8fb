"""The parameter store: numbered parameters #1..#5601, named parameters and subroutine scopes, as LinuxCNC.

Numbered parameters are one flat list (`values`, index 0 unused) that expression nodes index
directly, so the list object never changes; a subroutine call saves the caller's #1..#30 and
writes the call's arguments over them, the return copies the saved values back.

Named parameters whose name begins with `_` are global; the others are local to the current
call level (level 0 is the main program). Read-only predefined globals such as `#<_x>` or
`#<_metric>` are not stored here: a hook given to the constructor answers them, so they always
reflect the interpreter's current state.
"""

from __future__ import annotations

from typing import Callable, Iterable, Union

from .errors import GCodeError

# LinuxCNC's RS274NGC_MAX_PARAMETERS is 5602: valid numbers are 1..5601 (#0 is out of range).
PARAMETER_COUNT = 5602
MAX_PARAMETER = PARAMETER_COUNT - 1
# A subroutine call passes at most 30 arguments, which become #1..#30 of the new scope.
SUB_ARGUMENTS = 30
# Written by the interpreter only (tool data and the current position); a program assigning
# them gets LinuxCNC's "Parameter is readonly".
READ_ONLY_NUMBERS = frozenset([*range(5400, 5414), *range(5420, 5429)])

Target = Union[int, str]
Predefined = Callable[[str], Union[float, None]]


class Parameters:
    """Numbered and named parameters of a running program, with one scope per call level."""

    def __init__(self, predefined: Predefined | None = None) -> None:
        self.values: list[float] = [0.0] * PARAMETER_COUNT
        self._predefined = predefined
        self._globals: dict[str, float] = {}
        self._locals: list[dict[str, float]] = [{}]
        self._saved: list[list[float]] = []

    # -- numbered ---------------------------------------------------------------------------

    def get(self, number: int) -> float:
        if not 0 < number <= MAX_PARAMETER:
            raise _out_of_range(number)
        return self.values[number]

    def set(self, number: int, value: float) -> None:
        """Assign as a program does: out-of-range and read-only numbers are rejected."""
        self.check_writable(number)
        self.values[number] = float(value)

    def set_system(self, number: int, value: float) -> None:
        """Assign as the interpreter does, read-only numbers included (position, tool data)."""
        if not 0 < number <= MAX_PARAMETER:
            raise _out_of_range(number)
        self.values[number] = float(value)

    # -- named ------------------------------------------------------------------------------

    def get_named(self, name: str) -> float:
        if name[:1] == "_":
            if self._predefined is not None:
                value = self._predefined(name)
                if value is not None:
                    return value
            scope = self._globals
        else:
            scope = self._locals[-1]
        try:
            return scope[name]
        except KeyError:
            raise GCodeError(f"Named parameter #<{name}> not defined", code="parameter") from None

    def set_named(self, name: str, value: float) -> None:
        self.check_writable(name)
        self._scope(name)[name] = float(value)

    def exists(self, name: str) -> bool:
        return self._is_predefined(name) or name in self._scope(name)

    def declare(self, name: str) -> None:
        """Create `name` with value 0 unless it exists: LinuxCNC does this when it reads
        `#<name>=` on a line, so a later `#<b>=#<name>` on the same line reads 0, not an error."""
        if not self._is_predefined(name):
            self._scope(name).setdefault(name, 0.0)

    # -- assignment -------------------------------------------------------------------------

    def check_writable(self, target: Target) -> None:
        """Raise the error an assignment to `target` (a number or a name) would raise."""
        if isinstance(target, str):
            if self._is_predefined(target):
                raise GCodeError(f"Cannot assign to read-only parameter #<{target}>", code="parameter")
        elif not 0 < target <= MAX_PARAMETER:
            raise _out_of_range(target)
        elif target in READ_ONLY_NUMBERS:
            raise GCodeError(f"Parameter #{target} is read-only", code="parameter")

    def apply(self, assignments: Iterable[tuple[Target, float]]) -> None:
        """Apply one line's settings in order. LinuxCNC sets parameters in parallel: the caller
        evaluates every value on the line first, then calls this. Nothing is set if any target
        is invalid."""
        assignments = list(assignments)
        for target, _ in assignments:
            self.check_writable(target)
        for target, value in assignments:
            if isinstance(target, str):
                self._scope(target)[target] = float(value)
            else:
                self.values[target] = float(value)

    # -- scopes -----------------------------------------------------------------------------

    @property
    def call_level(self) -> int:
        return len(self._saved)

    def push_scope(self, args: list[float]) -> None:
        """Enter a subroutine: the arguments become #1..#30 (missing ones 0), locals start empty."""
        if len(args) > SUB_ARGUMENTS:
            raise GCodeError(
                f"Too many subroutine parameters: {len(args)} given, at most {SUB_ARGUMENTS}",
                code="parameter",
            )
        self._saved.append(self.values[1 : SUB_ARGUMENTS + 1])
        self.values[1 : SUB_ARGUMENTS + 1] = [float(a) for a in args] + [0.0] * (SUB_ARGUMENTS - len(args))
        self._locals.append({})

    def pop_scope(self) -> None:
        """Return from a subroutine: restore the caller's #1..#30 and drop the callee's locals."""
        if not self._saved:
            raise GCodeError("Return from a subroutine that was not called", code="parameter")
        self.values[1 : SUB_ARGUMENTS + 1] = self._saved.pop()
        self._locals.pop()

    # -- helpers ----------------------------------------------------------------------------

    def _scope(self, name: str) -> dict[str, float]:
        return self._globals if name[:1] == "_" else self._locals[-1]

    def _is_predefined(self, name: str) -> bool:
        return name[:1] == "_" and self._predefined is not None and self._predefined(name) is not None


def _out_of_range(number: object) -> GCodeError:
    return GCodeError(f"Parameter number #{number} out of range 1..{MAX_PARAMETER}", code="parameter")
