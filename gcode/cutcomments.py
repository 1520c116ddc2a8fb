"""The cutting job written into a program: `(MATERIAL, ...)` and `(QUALITY, ...)` comments.

A CAM post-processor states what the program was made for, in LinuxCNC's active-comment form
(a word, a comma, then fields; a plain comment stays a comment):

    (MATERIAL, leather, THICKNESS=2.5, QUALITY=3)          the material (an id of the machine's
    (MATERIAL, mild_steel, THICKNESS=0.25in, QUALITY=2, MODE=QUALITY)   library), its thickness,
    (QUALITY, 5)                                            the edge quality 1-5 from here on

- THICKNESS is in the program's units at that line (G20/G21 in force), or as its suffix says
  (`mm`, `in`), like every other length of the program.
- MODE is how the speed is set, as CAM tools name it: QUALITY (the default: the cutting model
  sets the speed everywhere and the programmed F is only an upper bound) or FEED (F as
  programmed; the model only reports).
- `(QUALITY, n)` changes the quality for the moves after it (a hole at a finer edge, a scrap
  cut at separation), until the next one.

Here the syntax is checked (an error names the line and the column of the field); whether the
material exists and its chart covers the thickness is the controller's question
(`cnc.cutmodel`), asked when the program is loaded.
"""

from __future__ import annotations

import math
import re

from .errors import GCodeError
from .modal import INCH_MM

QUALITY_RANGE = (1, 5)
MODES = ("quality", "feed")
_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}$")  # as cnc.cutmodel.MATERIAL_ID
_LENGTH = re.compile(r"^([+]?\d+(?:\.\d*)?|[+]?\.\d+)\s*(mm|in)?$", re.IGNORECASE)


def cut_comment_kind(text: str) -> str | None:
    """"material" or "quality" when the comment is one of these, else None."""
    head = text.lstrip().split(",", 1)[0].strip().lower()
    if "," not in text:
        return None
    return head if head in ("material", "quality") else None


def parse_cut_comment(text: str, units_mm: float, line: int, column: int) -> tuple[str, dict]:
    """(kind, data) of a `(MATERIAL, ...)` or `(QUALITY, n)` comment; GCodeError names the field.

    `units_mm`: mm per program unit at this line; `column`: where the comment's text starts."""
    kind = cut_comment_kind(text)
    fields = text.split(",")
    starts = []  # column of each field's text
    at = column
    for f in fields:
        starts.append(at + len(f) - len(f.lstrip()))
        at += len(f) + 1

    def err(k: int, why: str) -> GCodeError:
        return GCodeError(f"({kind.upper()}, ...): {why}", code="cut-comment", line=line, column=starts[min(k, len(starts) - 1)])

    values = [f.strip() for f in fields]
    if kind == "quality":
        if len(values) != 2:
            raise err(len(values) - 1 if len(values) > 2 else 0, "expected one quality, 1 to 5: (QUALITY, 3)")
        return "quality", {"quality": _quality(values[1], lambda why: err(1, why))}
    if len(values) < 2 or not values[1]:
        raise err(1, "expected the material first: (MATERIAL, leather, THICKNESS=2, QUALITY=3)")
    material = values[1]
    if not _ID.match(material):
        raise err(1, f"{material!r} is not a material id (letters, digits, _ . -: the name of its file in the library)")
    data: dict = {"material": material, "mode": "quality"}
    for k, value in enumerate(values[2:], 2):
        key, eq, raw = value.partition("=")
        key, raw = key.strip().lower(), raw.strip()
        if not eq or not raw:
            raise err(k, f"{value!r}: expected KEY=VALUE (THICKNESS, QUALITY, MODE)")
        if key in data and key != "mode" or (key == "mode" and "mode_given" in data):
            raise err(k, f"{key.upper()} given twice")
        if key == "thickness":
            m = _LENGTH.match(raw)
            if not m:
                raise err(k, f"THICKNESS={raw}: expected a positive length (2.5, 2.5mm, 0.1in)")
            scale = {"mm": 1.0, "in": INCH_MM}.get((m.group(2) or "").lower(), units_mm)
            thickness = float(m.group(1)) * scale
            if not (math.isfinite(thickness) and thickness > 0.0):
                raise err(k, f"THICKNESS={raw}: must be above 0")
            data["thickness_mm"] = thickness
        elif key == "quality":
            data["quality"] = _quality(raw, lambda why, k=k: err(k, why))
        elif key == "mode":
            if raw.lower() not in MODES:
                raise err(k, f"MODE={raw}: expected QUALITY (the model sets the speed) or FEED (F as programmed)")
            data["mode"], data["mode_given"] = raw.lower(), True
        else:
            raise err(k, f"unknown field {key.upper()!r} (known: THICKNESS, QUALITY, MODE)")
    data.pop("mode_given", None)
    for key in ("thickness_mm", "quality"):
        if key not in data:
            raise err(len(values) - 1, f"{key.split('_')[0].upper()}= is missing: the cut needs material, thickness and quality")
    return "material", data


def _quality(raw: str, err) -> int:  # noqa: ANN001 - a callable making the error
    try:
        q = int(raw)
    except ValueError:
        raise err(f"{raw!r}: a quality is a whole number, 1 (separation) to 5 (finest)") from None
    if not QUALITY_RANGE[0] <= q <= QUALITY_RANGE[1]:
        raise err(f"quality {q} is not 1 (separation) to 5 (finest)")
    return q
