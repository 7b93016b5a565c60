"""The frame number in a frame file's name (docs/recording-format.md, "Frame names").

Rule: every name in ``frames/`` holds the same text around exactly one integer that
changes from file to file; that integer is the frame number. Zero padding is optional
(``img1.png`` < ``img2.png`` < ``img10.png``: numbers are compared as integers, never as
text). Frame k is at ``t0_s + k / fps``; a number absent from the range is a dropped frame.
Names from which the number cannot be read unambiguously are refused.
"""

from __future__ import annotations

import re
from pathlib import Path

from vibro_model.errors import FrameError

NAMING_RULE = (
    "frame files must share one name pattern with exactly one integer, the frame number, changing "
    "from file to file (e.g. 000000.png, 000001.png, ... or img_0.tif, img_1.tif, ...; padding optional)"
)

_DIGITS = re.compile(r"(\d+)")


def _refuse(folder: Path, problem: str) -> FrameError:
    return FrameError(f"{folder}: {problem}; {NAMING_RULE}")


def frame_numbers(files: list[Path]) -> list[int]:
    """The frame number of each file (same order as ``files``); :class:`FrameError` if ambiguous.

    Refused: a name without a number, names that differ in their text (mixed prefixes or
    suffixes), two numbers that both change across the names, and two files that carry the
    same frame number (``01.png`` and ``1.png``).
    """
    if not files:
        return []
    folder = files[0].parent
    pieces = [_DIGITS.split(p.name) for p in files]  # text, digits, text, ..., text
    first = pieces[0]
    for path, parts in zip(files, pieces):
        if len(parts) == 1:
            raise _refuse(folder, f"frame name {path.name} holds no frame number")
        if len(parts) != len(first) or parts[0::2] != first[0::2]:
            raise _refuse(folder, f"frame names {files[0].name} and {path.name} differ in more than one number")
    n_fields = len(first) // 2
    varying = [i for i in range(n_fields) if len({parts[2 * i + 1] for parts in pieces}) > 1]
    if len(varying) > 1:
        a, b = varying[:2]
        example = next(p for p, parts in zip(files, pieces) if parts[2 * a + 1] != first[2 * a + 1])
        raise _refuse(folder, f"two numbers change across the frame names (e.g. {files[0].name} and "
                              f"{example.name}): which one is the frame number is ambiguous")
    if varying:
        field = varying[0]
    elif n_fields == 1:
        field = 0
    else:
        raise _refuse(folder, f"frame name {files[0].name} holds {n_fields} numbers and no other frame "
                              "tells which one is the frame number")
    numbers = [int(parts[2 * field + 1]) for parts in pieces]
    owner: dict[int, Path] = {}
    for n, path in zip(numbers, files):
        if n in owner:
            raise _refuse(folder, f"{owner[n].name} and {path.name} both carry frame number {n}")
        owner[n] = path
    return numbers
