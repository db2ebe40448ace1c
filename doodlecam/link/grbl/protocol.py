"""GRBL 1.1's serial protocol as data and parsers: buffer sizes, error and alarm codes
(doc/csv/error_codes_en_US.csv and alarm_codes_en_US.csv in the gnea/grbl repository),
G-code line preparation and the status report.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from doodlecam.errors import InputError
from doodlecam.link.session import LinkError

RX_BUFFER_SIZE = 128
MAX_OUTSTANDING = RX_BUFFER_SIZE - 1  # bytes of unanswered lines GRBL can hold
MAX_LINE = 79  # characters after GRBL drops spaces and comments (LINE_BUFFER_SIZE 80)
STATUS_PERIOD = 0.2  # s between '?' queries: GRBL asks for at most 5 Hz
REALTIME = "?!~\x18"

ERRORS: dict[int, str] = {
    1: "G-code words consist of a letter and a value; letter was not found",
    2: "numeric value format is not valid or missing an expected value",
    3: "GRBL '$' system command was not recognized or supported",
    4: "negative value received for an expected positive value",
    5: "homing cycle is not enabled via settings ($22)",
    6: "minimum step pulse time must be greater than 3 usec",
    7: "EEPROM read failed; affected values were restored to defaults",
    8: "GRBL '$' command cannot be used unless GRBL is idle",
    9: "G-code locked out during alarm or jog state",
    10: "soft limits cannot be enabled without homing also enabled",
    11: "max characters per line exceeded; line was not processed",
    12: "'$' setting value exceeds the maximum step rate supported",
    13: "safety door detected as opened and door state initiated",
    14: "build info or startup line exceeded EEPROM line length limit",
    15: "jog target exceeds machine travel; command ignored",
    16: "jog command with no '=' or contains prohibited G-code",
    17: "laser mode requires PWM output",
    20: "unsupported or invalid G-code command found in block",
    21: "more than one G-code command from the same modal group found in block",
    22: "feed rate has not yet been set or is undefined",
    23: "G-code command in block requires an integer value",
    24: "two G-code commands that both require XYZ axis words were detected in the block",
    25: "a G-code word was repeated in the block",
    26: "a G-code command requires XYZ axis words in the block, but none were detected",
    27: "N line number value is not within the valid range of 1 - 9,999,999",
    28: "a G-code command is missing some required P or L value words",
    29: "GRBL supports six work coordinate systems G54-G59; G59.1, G59.2 and G59.3 are not supported",
    30: "the G53 command requires either a G0 seek or G1 feed motion mode to be active",
    31: "there are unused axis words in the block and G80 motion mode cancel is active",
    32: "a G2 or G3 arc was commanded but there are no XYZ axis words in the selected plane",
    33: "the motion command has an invalid target",
    34: "a G2 or G3 arc traced with the radius definition had a mathematical error",
    35: "a G2 or G3 arc traced with the offset definition is missing the IJK offset word",
    36: "there are unused, leftover G-code words that aren't used by any command in the block",
    37: "the G43.1 dynamic tool length offset cannot apply to an axis other than its configured axis",
    38: "tool number greater than max supported value",
}

ALARMS: dict[int, str] = {
    1: "hard limit triggered; machine position is likely lost due to the sudden halt",
    2: "soft limit: a G-code motion target exceeds machine travel; machine position retained",
    3: "reset while in motion; machine position is likely lost",
    4: "probe fail: the probe is not in the expected initial state before starting the probe cycle",
    5: "probe fail: the probe did not contact the workpiece within the programmed travel",
    6: "homing fail: the active homing cycle was reset",
    7: "homing fail: the safety door was opened during the homing cycle",
    8: "homing fail: pull-off travel failed to clear the limit switch",
    9: "homing fail: could not find the limit switch within the search distance",
    10: "homing fail: on dual-axis machines, could not find the second limit switch",
}

HOME = "doodlecam machine --serial PORT home"
UNLOCK = "doodlecam machine --serial PORT unlock"

_ALARM_TODO = {
    1: f"check what hit the limit, then home ($H: '{HOME}'), or unlock ($X: '{UNLOCK}') and re-zero",
    2: ("the job leaves the machine's travel (with soft limits GRBL's travel is -$130..0, -$131..0: set work zero "
        f"with 'doodlecam machine --serial PORT zero' or convert with --post-opt gcode.work_offset=g10), then "
        f"unlock ($X: '{UNLOCK}')"),
    3: f"home ($H: '{HOME}'), or unlock ($X: '{UNLOCK}') and re-zero, before running again",
}


def error_text(code: int) -> str:
    return ERRORS.get(code, "unknown error code (see your firmware's documentation)")


def alarm_text(code: int) -> str:
    return ALARMS.get(code, "unknown alarm code (see your firmware's documentation)")


def alarm_advice(code: int) -> str:
    return _ALARM_TODO.get(code, f"fix the cause, then home ($H: '{HOME}') or unlock ($X: '{UNLOCK}')")


class GrblError(LinkError):
    """GRBL refused a line, raised an alarm, or reset itself."""


# ---------------------------------------------------------------- the file

@dataclass(frozen=True)
class GcodeLine:
    text: str  # what is sent: spaces and comments removed, as GRBL would
    lineno: int  # 1-based line in the file; 0 for lines the sender adds
    source: str = ""


_COMMENT = re.compile(r"\([^)]*\)|;.*$")


def prepare(text: str, name: str = "G-code") -> list[GcodeLine]:
    """The lines to stream, checked; raise InputError naming the file line that GRBL cannot take."""
    out = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        s = "".join(_COMMENT.sub("", raw).split())
        if not s:
            continue
        if "(" in s or ")" in s:
            raise InputError(f"{name}:{lineno}: unbalanced comment parentheses; close the comment on the same line")
        bad = [c for c in s if c in REALTIME or not (32 < ord(c) < 127)]
        if bad:
            raise InputError(f"{name}:{lineno}: contains {bad[0]!r}, which GRBL treats as a real-time command or "
                             "cannot read; remove it")
        if len(s) > MAX_LINE:
            raise InputError(f"{name}:{lineno}: {len(s)} characters without spaces and comments; GRBL takes at most "
                             f"{MAX_LINE}, split the line")
        out.append(GcodeLine(s, lineno, raw))
    return out


_AXIS = re.compile(r"([XYZF])([-+]?(?:\d+\.?\d*|\.\d+))")
_SPINDLE = re.compile(r"M0*[345](?!\d)|S[-+.\d]")


def _is_pen(text: str) -> bool:
    return bool(_SPINDLE.search(text.upper())) and not re.search(r"G0*[0-3](?!\d)", text.upper())


def _is_offset(text: str) -> bool:
    """G10 / G92: axis words that set an offset and move nothing."""
    return bool(re.search(r"G(?:10|92)(?![\d.])", text.upper()))


def _is_g0(text: str) -> bool:
    return bool(re.match(r"G0*0(?!\d)", text.upper()))


def pen_up_line(lines: list[GcodeLine]) -> str:
    """The file's own pen-up command: the pen line right before a G0 travel (skipping dwells)."""
    last_pen = None
    for ln in lines:
        t = ln.text.upper()
        if _is_g0(t) and last_pen is not None:
            return last_pen
        if _is_pen(t):
            last_pen = ln.text
        elif not t.startswith("G4"):
            last_pen = None
    return "M5"


def resume_prefix(lines: list[GcodeLine], k: int) -> list[GcodeLine]:
    """Lines that put a freshly reset GRBL in the state the job had before line index ``k``.

    Units, distance and feed modes, the last position (reached pen up), the
    last pen command and its dwell, and the feed rate. Raise InputError when
    the job cannot be resumed there (relative coordinates).
    """
    units, absolute, feed, pen, dwell, pos = "G21", True, None, None, None, {}
    for ln in lines[:k]:
        t = ln.text.upper()
        if _is_offset(t):
            if re.search(r"G92(?![\d.])", t):
                raise InputError(f"line {ln.lineno} sets the origin with G92, which the reset before a resume "
                                 "clears; restart the job from the beginning (G10 L20 keeps it: work_offset=g10)")
            continue
        for g in re.findall(r"G0*(\d+(?:\.\d+)?)", t):
            if g in ("20", "21"):
                units = "G" + g
            elif g == "90":
                absolute = True
            elif g == "91":
                absolute = False
        if _is_pen(t):
            pen, dwell = ln.text, None
        elif t.startswith("G4") and pen is not None:
            dwell = ln.text
        for letter, val in _AXIS.findall(t):
            if letter == "F":
                feed = val
            elif not t.startswith("G4") and not t.startswith("$"):
                pos[letter] = val
    if not absolute:
        raise InputError("the job uses relative coordinates (G91) at the resume point; it can only restart from the beginning")
    out = [f"{units}G90G94G17"]
    if pos:
        out.append("G0" + "".join(f"{a}{pos[a]}" for a in "XYZ" if a in pos))
    if pen:
        out.append(pen)
        if dwell:
            out.append(dwell)
    if feed:
        out.append(f"F{feed}")
    return [GcodeLine(t, 0, t) for t in out]


def line_durations(lines: list[GcodeLine]) -> list[float]:
    """Rough time (s) of each line: G1 length / F, G0 at the fastest feed seen, G4 dwells."""
    durs, pos, feed, mode, fastest = [], {"X": 0.0, "Y": 0.0, "Z": 0.0}, None, 0, 0.0
    for ln in lines:
        t = ln.text.upper()
        for m in re.finditer(r"F([-+]?[\d.]+)", t):
            fastest = max(fastest, float(m.group(1)))
    fastest = fastest or 3000.0
    for ln in lines:
        t = ln.text.upper()
        d = 0.0
        if t.startswith("G4"):
            m = re.search(r"P([\d.]+)", t)
            d = float(m.group(1)) if m else 0.0
        elif not t.startswith("$") and not _is_offset(t):
            g = re.match(r"G0*([01])(?!\d)", t)
            if g:
                mode = int(g.group(1))
            new = dict(pos)
            for letter, val in _AXIS.findall(t):
                if letter == "F":
                    feed = float(val)
                else:
                    new[letter] = float(val)
            dist = sum((new[a] - pos[a]) ** 2 for a in "XYZ") ** 0.5
            rate = (feed or fastest) if mode == 1 else fastest
            d = 60.0 * dist / rate if rate > 0 else 0.0
            pos = new
        durs.append(d)
    return durs


# ---------------------------------------------------------------- status

@dataclass(frozen=True)
class GrblStatus:
    state: str  # Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep
    substate: int | None
    mpos: tuple[float, ...] | None
    wpos: tuple[float, ...] | None
    buffer: tuple[int, int] | None  # Bf: planner blocks free, RX bytes free
    feed: float | None
    raw: str
    at: float  # time.monotonic() when received


def parse_status(line: str, at: float = 0.0) -> GrblStatus | None:
    if not (line.startswith("<") and line.endswith(">")):
        return None
    fields = line[1:-1].split("|")
    state, _, sub = fields[0].partition(":")
    data = {}
    for f in fields[1:]:
        k, _, v = f.partition(":")
        data[k] = v

    def nums(key):
        try:
            return tuple(float(x) for x in data[key].split(",")) if key in data else None
        except ValueError:
            return None

    bf = nums("Bf")
    fs = nums("FS") or nums("F")
    return GrblStatus(state, int(sub) if sub.isdigit() else None, nums("MPos"), nums("WPos"),
                      (int(bf[0]), int(bf[1])) if bf and len(bf) == 2 else None, fs[0] if fs else None, line, at)
