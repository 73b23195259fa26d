"""Format checks of a two-line element set (TLE), before SGP4 reads it.

SGP4 (``sgp4.api.Satrec.twoline2rv``) reads the fixed columns of the two lines and
ignores their checksums, so a mistyped digit gives a different orbit, silently. The
checks here follow the NORAD format (CelesTrak, "FAQs: Two-Line Element Set Format"):
69 characters per line, line numbers ``1`` and ``2`` in column 1, the same catalogue
number in columns 3-7 of both lines, and a modulo-10 checksum in column 69 (the sum of
the digits of columns 1-68, each ``-`` counting 1, letters, spaces, ``.`` and ``+``
counting 0).
"""

from __future__ import annotations

from gnomon.errors import InputError

__all__ = ["tle_checksum", "check_tle"]

TLE_LINE_LENGTH = 69


def tle_checksum(line: str) -> int:
    """The modulo-10 checksum of a TLE line: digits of columns 1-68, ``-`` counts 1."""
    return sum(int(c) if c.isdigit() else (1 if c == "-" else 0) for c in line[:68]) % 10


def check_tle(line1: str, line2: str,
              fields: tuple[str, str] = ("orbit.tle_line1", "orbit.tle_line2")) -> None:
    """Raise ``InputError`` naming ``fields[0]`` or ``fields[1]`` (and the wrong value)
    if the two lines are not a well-formed TLE: length, line numbers, matching catalogue
    numbers, checksums. Trailing spaces are ignored."""
    lines = (line1.rstrip(), line2.rstrip())
    for i, (line, field) in enumerate(zip(lines, fields, strict=True), start=1):
        other = 3 - i
        if line.startswith(f"{other} "):
            raise InputError(f"line {i} starts with '{other} ': are the two lines swapped? "
                             f"got {line[:20]!r}...", field=field)
        if not line.startswith(f"{i} "):
            raise InputError(f"a TLE line {i} starts with '{i} ', got {line[:20]!r}...",
                             field=field)
        if len(line) != TLE_LINE_LENGTH:
            raise InputError(f"a TLE line has {TLE_LINE_LENGTH} characters, got {len(line)} "
                             "(a missing or extra space? the columns are fixed)", field=field)
        if not line[68].isdigit() or int(line[68]) != tle_checksum(line):
            raise InputError(f"checksum in column 69 is {line[68]!r} but the line sums to "
                             f"{tle_checksum(line)} (a mistyped digit, or a wrong checksum)",
                             field=field)
    if lines[0][2:7] != lines[1][2:7]:
        raise InputError(f"catalogue number {lines[1][2:7].strip()!r} differs from line 1's "
                         f"{lines[0][2:7].strip()!r}: lines of two different objects?",
                         field=fields[1])
