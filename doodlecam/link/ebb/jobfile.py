"""Reading an ``.ebb`` job back: its header comments and its checked command lines.

The one reader for ``doodlecam inspect``, ``doodlecam send --serial`` and the tests. A damaged
file is refused with one line naming the first bad line, before anything is sent.
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass

from doodlecam.errors import InputError

# command -> (fewest, most) integer parameters the stream may use (the EBB command reference)
COMMANDS = {"EM": (1, 2), "SC": (2, 2), "SP": (1, 3), "LM": (6, 7), "SM": (2, 4), "XM": (3, 4), "HM": (1, 3),
            "CS": (0, 0), "ES": (0, 1)}
_INT = re.compile(r"^-?\d{1,10}$")
I32 = (-(1 << 31), (1 << 31) - 1)


@dataclass(frozen=True)
class EbbJob:
    header: dict[str, str]
    lines: tuple[str, ...]  # board commands and @PAUSE directives, in order

    @property
    def planned_time(self) -> float:
        return float(self.header.get("planned_time", "nan"))

    def pauses(self) -> list[tuple[int, int]]:
        """(line index, pen) of every pen change."""
        return [(i, int(s.split(",")[1])) for i, s in enumerate(self.lines) if s.startswith("@PAUSE")]


def check_line(line: str) -> str | None:
    """Why ``line`` is not a command the stream may hold, or None."""
    parts = line.split(",")
    name = parts[0]
    if name == "@PAUSE":
        return None if len(parts) == 2 and parts[1].isdigit() and int(parts[1]) >= 1 else "a pen change is '@PAUSE,<pen>'"
    if name not in COMMANDS:
        return f"unknown command {name!r}"
    lo, hi = COMMANDS[name]
    args = parts[1:]
    if not lo <= len(args) <= hi:
        return f"{name} takes {lo}..{hi} parameters, this has {len(args)}"
    for a in args:
        if not _INT.match(a) or not I32[0] <= int(a) <= I32[1]:
            return f"parameter {a!r} is not a 32-bit integer"
    if name == "LM" and len(args) == 7 and not 0 <= int(args[6]) <= 3:
        return "LM's Clear must be 0..3"
    return None


def read_ebb(data: bytes, name: str = "EBB job") -> EbbJob:
    def fail(why: str) -> InputError:
        return InputError(f"{name}: {why}; re-export it with 'doodlecam convert --post ebb -m axidraw-v3'")

    try:
        text = bytes(data).decode("ascii")
    except UnicodeDecodeError:
        raise fail("not an ASCII .ebb file") from None
    rows = text.split("\n")
    if rows and rows[-1] == "":
        rows.pop()
    if not rows or not rows[0].startswith("; doodlecam EBB job"):
        raise fail("not a doodlecam EBB job (no '; doodlecam EBB job' first line)")
    header: dict[str, str] = {}
    lines: list[str] = []
    for n, row in enumerate(rows, 1):
        if row.startswith(";"):
            key, sep, value = row[1:].partition(":")
            if sep and not lines and re.fullmatch(r"[a-z_0-9]+", key.strip()):
                header[key.strip()] = value.strip()
            continue
        why = check_line(row)
        if why:
            raise fail(f"line {n} {row[:40]!r}: {why}")
        lines.append(row)
    if "crc32" in header:
        crc = zlib.crc32("\n".join(lines).encode("ascii"))
        if f"{crc:08x}" != header["crc32"]:
            raise fail(f"the commands do not match the header's crc32 {header['crc32']} (they give {crc:08x}): "
                       "the file was changed or damaged")
    want = header.get("commands")
    if want is not None and want.isdigit() and int(want) != sum(not s.startswith("@") for s in lines):
        raise fail(f"header says {want} commands, the file has {sum(not s.startswith('@') for s in lines)}")
    return EbbJob(header, tuple(lines))
