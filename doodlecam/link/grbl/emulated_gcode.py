"""GRBL 1.1h's G-code interpreter for the emulator, written from reading the firmware's gcode.c and
motion_control.c (not copied): the same words, modal groups and checks in the same order, so a line gets the
firmware's ``ok`` or ``error:N``, and the same actions in the same order of execution.

``Interpreter.execute(line)`` raises ``GcodeError(code)`` or returns the actions the machine then runs:

    ("sync",)                     protocol_buffer_synchronize: wait until motion has stopped
    ("spindle", m, s)             spindle state M3/M4/M5 at speed s (after a sync)
    ("coolant", flood)            M8/M9 (after a sync)
    ("dwell", seconds)            G4 (a sync, then the wait)
    ("line", Move)                mc_line: soft limits, then a planner block
    ("probe", Move, away, quiet)  G38.x: a sync, the move, then the probe's verdict
    ("jog", Move)                 $J=: travel check (error:15), then a planner block
    ("wco",), ("eeprom",)         a work offset changed / a stored one was written: both synchronise
    ("pause",), ("end",)          M0 / M2, M30 (a sync, then hold / program end)

This emulator's probe never touches anything (as the firmware simulator's probe pin): G38.2/G38.3 run to
their target and fail there, G38.4/G38.5 fail at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from doodlecam.link.grbl.emulated_motion import lround

MM_PER_INCH = 25.4
MAX_LINE_NUMBER = 10_000_000
MAX_TOOL_NUMBER = 255
MAX_INT_DIGITS = 8
N_COORDINATE_SYSTEM = 6  # G54..G59; slots 6 and 7 hold G28 and G30
G28_SLOT, G30_SLOT = 6, 7
SEEK, LINEAR, CW_ARC, CCW_ARC, MOTION_NONE = 0, 1, 2, 3, 80
PROBES = {382: (False, False), 383: (False, True), 384: (True, False), 385: (True, True)}  # G38.x: (away, quiet)
# the plane's two arc axes and its linear axis (G17, G18, G19)
PLANES = {0: (0, 1, 2), 1: (2, 0, 1), 2: (1, 2, 0)}


class GcodeError(Exception):
    def __init__(self, code: int):
        super().__init__(f"error:{code}")
        self.code = code


@dataclass(frozen=True)
class Move:
    target: tuple[float, float, float]  # machine mm
    feed: float  # mm/min (1/min in inverse time); ignored by rapids
    rapid: bool = False
    inverse_time: bool = False
    no_override: bool = False


def read_float(line: str, i: int) -> tuple[float, int]:
    """nuts_bolts.c's read_float: a sign, digits and one point (no exponent), 8 significant digits kept."""
    n = len(line)
    negative = False
    if i < n and line[i] in "+-":
        negative = line[i] == "-"
        i += 1
    intval, exp, ndigit, point = 0, 0, 0, False
    while i < n:
        c = line[i]
        if "0" <= c <= "9":
            ndigit += 1
            if ndigit <= MAX_INT_DIGITS:
                exp -= point
                intval = intval * 10 + ord(c) - 48
            elif not point:
                exp += 1  # digits past the eighth are dropped
        elif c == "." and not point:
            point = True
        else:
            break
        i += 1
    if not ndigit:
        raise GcodeError(2)
    value = intval * 10.0 ** exp
    return (-value if negative else value), i


def _default_modal() -> dict:
    return {"motion": SEEK, "coord": 0, "plane": 0, "units": 0, "distance": 0, "feed_mode": 0, "spindle": 5,
            "coolant": 0, "tlo": 0}


@dataclass
class Interpreter:
    """gc_state: the modal state, the parser's position and offsets; ``coords`` is the EEPROM's G54..G59, G28, G30."""

    coords: list[list[float]] = field(default_factory=lambda: [[0.0, 0.0, 0.0] for _ in range(8)])
    arc_tolerance: float = 0.002

    def __post_init__(self):
        self.reset([0.0, 0.0, 0.0])

    def reset(self, position) -> None:
        """gc_init + gc_sync_position (power-up and every soft reset)."""
        self.modal = _default_modal()
        self.feed_rate = 0.0
        self.spindle_speed = 0.0
        self.tool = 0
        self.line_number = 0
        self.tool_length_offset = 0.0
        self.coord_offset = [0.0, 0.0, 0.0]  # G92, forgotten on reset
        self.coord_system = list(self.coords[0])
        self.position = list(position)

    @property
    def wco(self) -> list[float]:
        """Work coordinate offset: machine = work + WCO."""
        w = [a + b for a, b in zip(self.coord_system, self.coord_offset)]
        w[2] += self.tool_length_offset
        return w

    def modes(self) -> str:
        """``$G``'s report (report_gcode_modes), without the F and S that the caller formats."""
        m = self.modal
        motion = f"38.{m['motion'] - 380}" if m["motion"] in PROBES else str(m["motion"])
        coolant = "M8" if m["coolant"] else "M9"
        return (f"G{motion} G{m['coord'] + 54} G{m['plane'] + 17} G{21 - m['units']} G{m['distance'] + 90} "
                f"G{94 - m['feed_mode']} M{m['spindle']} {coolant} T{self.tool}")

    # ------------------------------------------------------------ one line

    def execute(self, line: str, check: bool = False) -> list[tuple]:  # noqa: C901 (gcode.c's one long function)
        jog = line.startswith("$J=")
        m = dict(self.modal)
        if jog:
            m["motion"], m["feed_mode"] = LINEAR, 0
        axis_command = None  # "nonmodal" (G10/28/30/92), "motion" or "tlo" (G43.1/G49)
        nonmodal = 0  # G-number times ten: 40, 100, 280, 281, 300, 301, 530, 920, 921
        groups: set[str] = set()
        words: dict[str, float] = {}
        axes: dict[int, float] = {}
        ijk: dict[int, float] = {}

        # STEP 2: import the words; modal group, repeat and sign checks
        i = 3 if jog else 0
        while i < len(line):
            letter = line[i]
            if not "A" <= letter <= "Z":
                raise GcodeError(1)
            value, i = read_float(line, i + 1)
            whole = math.trunc(value) & 0xFF  # a uint8_t, as the firmware keeps it
            mantissa = lround(100 * (value - whole)) & 0xFFFF
            if letter == "G":
                if whole in (10, 28, 30, 92) and mantissa == 0:
                    if axis_command:
                        raise GcodeError(24)
                    axis_command = "nonmodal"
                if whole in (10, 28, 30, 92, 4, 53):
                    group, nonmodal = "G0", whole * 10
                    if whole in (28, 30, 92):
                        if mantissa not in (0, 10):
                            raise GcodeError(20)
                        nonmodal += mantissa // 10
                        mantissa = 0
                elif whole in (0, 1, 2, 3, 38, 80):
                    if whole != 80:
                        if axis_command:
                            raise GcodeError(24)
                        axis_command = "motion"
                    group, m["motion"] = "G1", whole
                    if whole == 38:
                        if mantissa not in (20, 30, 40, 50):
                            raise GcodeError(20)
                        m["motion"], mantissa = 380 + mantissa // 10, 0
                elif whole in (17, 18, 19):
                    group, m["plane"] = "G2", whole - 17
                elif whole in (90, 91):
                    if mantissa == 0:
                        group, m["distance"] = "G3", whole - 90
                    else:  # G91.1 (IJK incremental, the only mode); G90.1 unsupported
                        if mantissa != 10 or whole == 90:
                            raise GcodeError(20)
                        group, mantissa = "G4", 0
                elif whole in (93, 94):
                    group, m["feed_mode"] = "G5", 94 - whole
                elif whole in (20, 21):
                    group, m["units"] = "G6", 21 - whole
                elif whole == 40:
                    group = "G7"
                elif whole in (43, 49):
                    group = "G8"
                    if axis_command:
                        raise GcodeError(24)
                    axis_command = "tlo"
                    if whole == 49:
                        m["tlo"] = 0
                    elif mantissa == 10:
                        m["tlo"] = 1
                    else:
                        raise GcodeError(20)
                    mantissa = 0
                elif 54 <= whole <= 59:
                    group, m["coord"] = "G12", whole - 54
                elif whole == 61:
                    if mantissa:
                        raise GcodeError(20)
                    group = "G13"
                else:
                    raise GcodeError(20)
                if mantissa > 0:
                    raise GcodeError(23)
                if group in groups:
                    raise GcodeError(21)
                groups.add(group)
            elif letter == "M":
                if mantissa > 0:
                    raise GcodeError(23)
                if whole in (0, 1, 2, 30):
                    group = "M4"
                    if whole != 1:  # M1 (optional stop) is accepted and ignored
                        m["flow"] = whole
                elif whole in (3, 4, 5):
                    group, m["spindle"] = "M7", whole
                elif whole in (8, 9):
                    group, m["coolant"] = "M8", int(whole == 8)
                else:
                    raise GcodeError(20)
                if group in groups:
                    raise GcodeError(21)
                groups.add(group)
            else:
                if letter not in "FIJKLNPRSTXYZ":
                    raise GcodeError(20)
                if letter == "T" and value > MAX_TOOL_NUMBER:
                    raise GcodeError(38)
                if letter in words:
                    raise GcodeError(25)
                if letter in "FNPTS" and value < 0.0:
                    raise GcodeError(4)
                words[letter] = float(whole) if letter in "LT" else (float(math.trunc(value)) if letter == "N"
                                                                     else value)
                if letter in "XYZ":
                    axes["XYZ".index(letter)] = value
                elif letter in "IJK":
                    ijk["IJK".index(letter)] = value
        used: set[str] = set()

        # STEP 3: checks, with values converted as the modes of this line say
        if axes and not axis_command:
            axis_command = "motion"
        if words.get("N", 0.0) > MAX_LINE_NUMBER:
            raise GcodeError(27)
        inch = MM_PER_INCH if m["units"] else 1.0
        if jog:
            if "F" not in words:
                raise GcodeError(22)
            feed = words["F"] * inch
        elif m["feed_mode"] == 1:  # G93: F comes with every move
            if axis_command == "motion" and m["motion"] not in (MOTION_NONE, SEEK) and "F" not in words:
                raise GcodeError(22)
            feed = words.get("F", 0.0)
        elif self.modal["feed_mode"] == 0:
            feed = words["F"] * inch if "F" in words else self.feed_rate
        else:  # back to G94 from G93: only this line's F, unconverted (as the firmware)
            feed = words.get("F", 0.0)
        speed = words.get("S", self.spindle_speed)
        if nonmodal == 40:
            if "P" not in words:
                raise GcodeError(28)
            used.add("P")
        a0, a1, linear = PLANES[m["plane"]]
        axes = {k: v * inch for k, v in axes.items()}
        if axis_command == "tlo" and m["tlo"] == 1 and set(axes) != {2}:
            raise GcodeError(37)
        block_coord = list(self.coord_system)
        if "G12" in groups and self.modal["coord"] != m["coord"]:
            block_coord = list(self.coords[m["coord"]])

        target = [0.0, 0.0, 0.0]  # the firmware's zeroed block: a jog without axis words goes to 0,0,0
        stored = None  # G10's or G28/G30's coordinates
        new_offset = None
        slot = 0
        if nonmodal == 100:  # G10 L2 / L20
            if not axes:
                raise GcodeError(26)
            if "P" not in words and "L" not in words:
                raise GcodeError(28)
            slot = math.trunc(words.get("P", 0.0)) & 0xFF
            if slot > N_COORDINATE_SYSTEM:
                raise GcodeError(29)
            ell = words.get("L", 0.0)
            if ell != 20 and (ell != 2 or "R" in words):
                raise GcodeError(20)
            used |= {"P", "L"}
            slot = slot - 1 if slot > 0 else m["coord"]
            stored = list(self.coords[slot])
            for k, v in axes.items():
                if ell == 20:  # the current position gets these work coordinates
                    stored[k] = self.position[k] - self.coord_offset[k] - v - (self.tool_length_offset if k == 2 else 0)
                else:
                    stored[k] = v
        elif nonmodal == 920:  # G92
            if not axes:
                raise GcodeError(26)
            new_offset = [self.position[k] - block_coord[k] - axes[k] - (self.tool_length_offset if k == 2 else 0.0)
                          if k in axes else self.coord_offset[k] for k in range(3)]
        else:
            if axis_command != "tlo" and axes:
                for k in range(3):
                    if k not in axes:
                        target[k] = self.position[k]
                    elif nonmodal == 530:  # G53: machine coordinates
                        target[k] = axes[k]
                    elif m["distance"] == 0:
                        target[k] = axes[k] + block_coord[k] + self.coord_offset[k] + \
                            (self.tool_length_offset if k == 2 else 0.0)
                    else:
                        target[k] = axes[k] + self.position[k]
            if nonmodal in (280, 300):
                stored = list(self.coords[G28_SLOT if nonmodal == 280 else G30_SLOT])
                if axes:  # only the axes of the intermediate move go home
                    for k in range(3):
                        if k not in axes:
                            stored[k] = self.position[k]
                else:
                    axis_command = None
            elif nonmodal == 530 and m["motion"] not in (SEEK, LINEAR):
                raise GcodeError(30)

        radius, offset = 0.0, [0.0, 0.0, 0.0]
        if m["motion"] == MOTION_NONE:
            if axes:
                raise GcodeError(31)
        elif axis_command == "motion":
            if m["motion"] == SEEK:
                if not axes:
                    axis_command = None
            elif feed == 0.0:
                raise GcodeError(22)
            elif m["motion"] == LINEAR:
                if not axes:
                    axis_command = None
            elif m["motion"] in (CW_ARC, CCW_ARC):
                radius, offset = self._arc_centre(m, axes, ijk, words, target, inch, used)
            elif not axes:  # probes
                raise GcodeError(26)
            elif target == self.position:
                raise GcodeError(33)

        used |= {"N", "F"} if jog else {"N", "F", "S", "T"}
        if axis_command:
            used |= {"X", "Y", "Z"}
        if set(words) - used:
            raise GcodeError(36)

        # STEP 4: execute, in the firmware's order
        if jog:
            if groups - {"G3", "G6", "G0"} or nonmodal not in (0, 530):
                raise GcodeError(16)
            return [("jog", Move(tuple(target), feed, no_override=True))]  # the position follows if accepted
        actions: list[tuple] = []
        self.line_number = int(words.get("N", 0))
        self.modal["feed_mode"] = m["feed_mode"]
        self.feed_rate = feed
        if self.spindle_speed != speed:
            if self.modal["spindle"] != 5:
                actions += [("sync",), ("spindle", self.modal["spindle"], speed)]
            self.spindle_speed = speed
        self.tool = int(words.get("T", 0))
        if self.modal["spindle"] != m["spindle"]:
            actions += [("sync",), ("spindle", m["spindle"], self.spindle_speed)]
            self.modal["spindle"] = m["spindle"]
        if self.modal["coolant"] != m["coolant"]:
            actions += [("sync",), ("coolant", m["coolant"])]
            self.modal["coolant"] = m["coolant"]
        if nonmodal == 40:
            actions.append(("dwell", words["P"]))
        self.modal["plane"], self.modal["units"] = m["plane"], m["units"]
        if axis_command == "tlo":
            self.modal["tlo"] = m["tlo"]
            tlo = axes.get(2, 0.0) if m["tlo"] else 0.0
            if tlo != self.tool_length_offset:
                self.tool_length_offset = tlo
                actions.append(("wco",))
        if self.modal["coord"] != m["coord"]:
            self.modal["coord"], self.coord_system = m["coord"], block_coord
            actions.append(("wco",))
        self.modal["distance"] = m["distance"]
        if nonmodal == 100:
            self.coords[slot] = stored
            actions.append(("eeprom",))
            if self.modal["coord"] == slot:
                self.coord_system = list(stored)
                actions.append(("wco",))
        elif nonmodal in (280, 300):
            if axis_command:
                actions.append(("line", Move(tuple(target), 0.0, rapid=True)))
            actions.append(("line", Move(tuple(stored), 0.0, rapid=True)))
            self.position = stored
        elif nonmodal in (281, 301):
            self.coords[G28_SLOT if nonmodal == 281 else G30_SLOT] = list(self.position)
            actions.append(("eeprom",))
        elif nonmodal in (920, 921):
            self.coord_offset = new_offset if nonmodal == 920 else [0.0, 0.0, 0.0]
            actions.append(("wco",))
        self.modal["motion"] = m["motion"]
        if m["motion"] != MOTION_NONE and axis_command == "motion":
            inverse = m["feed_mode"] == 1
            if m["motion"] in (SEEK, LINEAR):
                actions.append(("line", Move(tuple(target), feed, rapid=m["motion"] == SEEK, inverse_time=inverse)))
            elif m["motion"] in (CW_ARC, CCW_ARC):
                actions += [("line", mv) for mv in self._arc(target, feed, inverse, offset, radius, m)]
            else:
                away, quiet = PROBES[m["motion"]]
                actions += [("sync",), ("probe", Move(tuple(target), feed, no_override=True), away, quiet)]
                if away and not check:  # fails before moving: the parser keeps its position
                    target = self.position
            self.position = list(target)
        flow = m.get("flow")
        if flow is not None:
            actions.append(("sync",))
            if flow == 0:
                actions.append(("pause",))
            else:  # M2/M30: some modes back to their defaults (LinuxCNC's program end)
                self.modal.update(motion=LINEAR, plane=0, distance=0, feed_mode=0, coord=0, spindle=5, coolant=0)
                if not check:
                    self.coord_system = list(self.coords[0])
                actions.append(("end",))
        return actions

    def _arc_centre(self, m, axes, ijk, words, target, inch, used) -> tuple[float, list[float]]:
        """The arc's radius and centre offset from the start, checked as gcode.c does (R or I/J/K form)."""
        a0, a1, _ = PLANES[m["plane"]]
        if not axes:
            raise GcodeError(26)
        if a0 not in axes and a1 not in axes:
            raise GcodeError(32)
        x = target[a0] - self.position[a0]
        y = target[a1] - self.position[a1]
        offset = [0.0, 0.0, 0.0]
        if "R" in words:
            used.add("R")
            if target == self.position:
                raise GcodeError(33)
            r = words["R"] * inch
            h = 4.0 * r * r - x * x - y * y
            if h < 0:
                raise GcodeError(34)
            h = -math.sqrt(h) / math.hypot(x, y)  # -(2h/d): the centre right of the chord
            if m["motion"] == CCW_ARC:
                h = -h
            if r < 0:  # a negative R asks for the arc longer than half a turn
                h, r = -h, -r
            offset[a0], offset[a1] = 0.5 * (x - y * h), 0.5 * (y + x * h)
            return r, offset
        if a0 not in ijk and a1 not in ijk:
            raise GcodeError(35)
        used |= {"I", "J", "K"}
        for k, v in ijk.items():
            offset[k] = v * inch
        r = math.hypot(offset[a0], offset[a1])
        delta_r = abs(math.hypot(x - offset[a0], y - offset[a1]) - r)
        if delta_r > 0.005 and (delta_r > 0.5 or delta_r > 0.001 * r):
            raise GcodeError(33)
        return r, offset

    def _arc(self, target, feed, inverse, offset, radius, m) -> list[Move]:
        """mc_arc: equal angles of chordal error at most $12, then the exact target (exact sin/cos here)."""
        a0, a1, linear = PLANES[m["plane"]]
        start = self.position
        c0, c1 = start[a0] + offset[a0], start[a1] + offset[a1]
        r0, r1 = -offset[a0], -offset[a1]
        t0, t1 = target[a0] - c0, target[a1] - c1
        theta = math.atan2(r0 * t1 - r1 * t0, r0 * t0 + r1 * t1)
        if m["motion"] == CW_ARC:
            if theta >= -5e-7:
                theta -= 2 * math.pi
        elif theta <= 5e-7:
            theta += 2 * math.pi
        tol = self.arc_tolerance
        segments = int(math.floor(abs(0.5 * theta * radius) / math.sqrt(tol * (2 * radius - tol)))) \
            if radius * 2 > tol else 0
        moves = []
        if segments:
            if inverse:  # inverse time over the whole arc becomes a feed per segment
                feed, inverse = feed * segments, False
            for k in range(1, segments):
                a = k * theta / segments
                p = list(start)
                p[a0] = c0 + r0 * math.cos(a) - r1 * math.sin(a)
                p[a1] = c1 + r0 * math.sin(a) + r1 * math.cos(a)
                p[linear] = start[linear] + (target[linear] - start[linear]) * k / segments
                moves.append(Move(tuple(p), feed, inverse_time=inverse))
        moves.append(Move(tuple(target), feed, inverse_time=inverse))
        return moves
