"""G- and M-code tables: which codes exist, their modal groups, and what this dialect supports.

Codes are held as integers ten times the number (G41.1 -> 411) so that lookups are exact.
Groups follow RS274/NGC as LinuxCNC implements it; two codes of one group in a block are
an error, as are codes LinuxCNC knows but a 2D waterjet cannot do (named in the error).
"""

from __future__ import annotations

INCH_MM = 25.4  # mm per inch: G20 programs are converted with this

# G modal groups (0 = non-modal)
G_GROUP = {
    40: 0, 100: 0, 280: 0, 281: 0, 300: 0, 301: 0, 530: 0, 920: 0, 921: 0, 922: 0, 923: 0,
    0: 1, 10: 1, 20: 1, 30: 1, 330: 1, 331: 1, 382: 1, 383: 1, 384: 1, 385: 1, 730: 1, 760: 1,
    800: 1, 810: 1, 820: 1, 830: 1, 840: 1, 850: 1, 860: 1, 870: 1, 880: 1, 890: 1,
    170: 2, 180: 2, 190: 2, 171: 2, 181: 2, 191: 2,
    900: 3, 910: 3,
    901: 4, 911: 4,
    930: 5, 940: 5, 950: 5,
    200: 6, 210: 6,
    400: 7, 410: 7, 420: 7, 411: 7, 421: 7,
    430: 8, 431: 8, 432: 8, 490: 8,
    980: 10, 990: 10,
    540: 12, 550: 12, 560: 12, 570: 12, 580: 12, 590: 12, 591: 12, 592: 12, 593: 12,
    610: 13, 611: 13, 640: 13,
    960: 14, 970: 14,
    70: 15, 80: 15,
}

G_SUPPORTED = {
    0, 10, 20, 30, 40, 100, 170, 200, 210, 400, 410, 420, 411, 421, 530, 540, 550, 560, 570, 580, 590, 591, 592,
    593, 610, 611, 640, 800, 900, 910, 901, 911, 920, 921, 922, 923, 930, 940,
}

G_WHY_NOT = {
    180: "G18 (XZ plane): the machine cuts in the XY plane only; use G17",
    190: "G19 (YZ plane): the machine cuts in the XY plane only; use G17",
    171: "G17.1 (UV plane) is not available: the machine cuts in the XY plane only",
    181: "G18.1 is not available: the machine cuts in the XY plane only",
    191: "G19.1 is not available: the machine cuts in the XY plane only",
    280: "G28 (go to predefined position) is not available: the machine has no stored reference positions",
    281: "G28.1 is not available: the machine has no stored reference positions",
    300: "G30 is not available: the machine has no stored reference positions",
    301: "G30.1 is not available: the machine has no stored reference positions",
    330: "G33 (spindle-synchronised motion) is not available on a waterjet",
    331: "G33.1 (rigid tapping) is not available on a waterjet",
    382: "G38.x (probing) is not available: the machine has no probe",
    383: "G38.x (probing) is not available: the machine has no probe",
    384: "G38.x (probing) is not available: the machine has no probe",
    385: "G38.x (probing) is not available: the machine has no probe",
    730: "canned cycles (G73) are drilling cycles, not available on a waterjet",
    760: "G76 (threading) is not available on a waterjet",
    430: "G43 (tool length offset) is not available: the cutting head has no tool length",
    431: "G43.1 (tool length offset) is not available: the cutting head has no tool length",
    432: "G43.2 (tool length offset) is not available: the cutting head has no tool length",
    490: None,  # G49 (cancel tool length offset) is accepted and does nothing
    950: "G95 (feed per revolution) is not available: a waterjet has no spindle",
    960: "G96 (constant surface speed) is not available: a waterjet has no spindle",
    970: None,  # G97 (RPM mode) is the only mode there is: accepted
    980: None,  # canned-cycle return modes: accepted, no canned cycles run
    990: None,
    70: "G7 (lathe diameter mode) is not available",
    80: None,  # G8 (radius mode) is the only mode: accepted
}
for _code in range(810, 900, 10):
    G_WHY_NOT[_code] = f"canned cycle G{_code // 10} is a drilling cycle, not available on a waterjet"

# M modal groups
M_GROUP = {
    0: 4, 1: 4, 2: 4, 30: 4, 60: 4,
    6: 6, 61: 6,
    3: 7, 4: 7, 5: 7,
    7: 8, 8: 8, 9: 8,
    48: 9, 49: 9, 50: 9, 51: 9, 52: 9, 53: 9,
    62: 5, 63: 5, 64: 5, 65: 5, 66: 5, 67: 5, 68: 5,
    70: 10, 71: 10, 72: 10, 73: 10,
}
M_ALWAYS = {0, 1, 2, 30, 60, 6, 62, 63, 64, 65, 48, 49}  # handled by the interpreter itself
for _m in range(100, 200):
    M_GROUP[_m] = 10

# Which words each code needs or allows besides axes (used for "word not used" errors)
AXIS_LETTERS = ("x", "y", "z")
UNSUPPORTED_AXES = ("a", "b", "c", "u", "v", "w")


def code_number(value: float) -> int | None:
    """G/M value to the integer code (x10); None when it is not a multiple of 0.1."""
    code = round(value * 10.0)
    if abs(code - value * 10.0) > 1e-4 or code < 0:
        return None
    return code


def code_text(letter: str, code: int) -> str:
    """G411 -> 'G41.1', G10 -> 'G1'."""
    whole, tenth = divmod(code, 10)
    return f"{letter.upper()}{whole}" + (f".{tenth}" if tenth else "")
