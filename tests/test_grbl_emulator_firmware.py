"""doodlecam's GRBL emulator against GRBL 1.1h's own firmware (``../shared/grbl-fw``, built with gcc into a
simulator whose clock does not depend on the machine's load): the same lines through both, the same answers.

Both get their bytes at 115200 baud whenever GRBL's receive ring has room. Status reports are compared too,
except the position and speed of a report taken while moving (the firmware's stepper reports the speed of the
segments it has prepared ahead)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from doodlecam.link.grbl.emulator import GrblConfig, GrblEmulator



@pytest.fixture(scope="module")
def firmware(grbl_firmware):  # tests/conftest.py builds the firmware once
    def run(text: str) -> tuple[list[str], float]:
        out, fields = grbl_firmware(text)
        return [x for x in out.replace("\r", "").split("\n")[2:] if x], float(fields["job_s"])  # after the banner

    return run


def emulated(text: str) -> tuple[list[str], float]:
    """The emulator with the firmware simulator's EEPROM (its README): $10=3, the doodlebot's axes."""
    emu = GrblEmulator(GrblConfig(report_mask=3, rapid=9000.0, travel=(400.0, 300.0)))
    try:
        sim = emu.simulate(text)
    finally:
        emu.stop()
    return [x for x in sim.lines if x], sim.job_s


def comparable(lines: list[str]) -> list[str]:
    return [re.sub(r"\|MPos:[^|]*|\|FS:[^|,]*", "", x) if x.startswith(("<Run", "<Jog", "<Hold")) else x
            for x in lines]


# each case: lines sent in one stream; trailing G4P0 lines keep the firmware simulator running until the end
CASES = {
    "soft limits need homing": ["$20=1", "$22=1", "$20=1", "$22=0", "$$"],
    "arcs by radius": ["G2X10Y0R5F1000", "G2X0Y0R-5", "G3X10R5F100", "G2X0Y0R4", "G2X0Y0I5", "G4P0", "?"],
    "arc errors": ["G2X10F1000", "G2I5", "G2X10Y0R4F1000", "G2X0Y0R5F1000", "G2X0Y10I0J5.1", "G19G2Z1Y0J0.5F100"],
    "G92 and G92.1": ["G92X5Y-2", "G4P0", "?", "G92.1", "$#", "G92.1X1", "G4P0", "$#"],
    "tools and optional stop": ["T1", "T255", "T256", "M1", "M6", "$G", "T7G0X1", "$G"],
    "G28 and G30": ["G0X10Y5", "G28.1", "G0X0Y0", "G28", "G4P0", "?", "G30.1", "G28X2", "G30", "G4P0", "$#"],
    "probing": ["G38.3X1F100", "G4P0", "$#", "G38.2X0F100", "G38.2X2F100", "G4P0", "G4P0"],
    "probing away": ["G38.4X1F100", "G4P0"],
    "work coordinate systems": ["G10L2P2X5", "G55", "$G", "G0X1", "G4P0", "?", "G59", "G59.1", "G10L20P0X3",
                                "$#", "G54", "$G"],
    "dwell and $ error codes": ["G4P-1", "G4", "$Q", "$1", "$1=", "$1=2X", "$256=1", "$99=1", "$0=2", "$100=-1",
                                "$$X", "$N0=G0X1", "$N", "$N0=G5", "$I"],
    "settings and their formats": ["$1=300", "$26=1000", "$4=5", "$11=0.0005", "$12=0.0026", "$30=1200.7", "$$"],
    "status report in WPos": ["$10=0", "G92X5", "G4P0", "?", "G4P0", "?", "$10=2", "?", "$10=3", "?"],
    "report in inches": ["$13=1", "G92X1", "G4P0", "?", "G0X25.4", "G4P0", "?", "$#", "$G"],
    "spindle and overrides in status": ["M3S1000", "G4P0", "?", "G4P0", "?", "M5", "G4P0", "?", "M8", "G4P0", "?"],
    "word and group errors": ["G0X1X2", "G0G1X1", "M3M5", "G1X1", "N99999999", "G1.5", "G38.1", "M3.5",
                              "G0X1I1", "G17G18", "G53G2X1I1F100", "G90.1", "G64", "G10L3P1X1", "G10P1X1",
                              "G10L2P7X1", "G43.1X1", "G43Z1", "S-1", "F-1", "G1X1F100.5.5", "X", "1", "G80G0X1"],
    "modes": ["G20", "G93", "G91", "G18", "$G", "G93G1X1", "G93G1X1F1", "G1X2", "G94", "G1X3F10", "M2", "$G"],
    "jogging": ["$J=X5", "$J=G1X1F100", "$J=X1F100S1", "$J=G91X1F1000", "G0X1", "G4P0", "$J=X1Y1F100G53",
                "G4P0", "G4P0"],
    "block delete and comments": ["/G0X5", "G0 (a comment) X6 ; and another", "g1x7f100", "G4P0", "?"],
}


@pytest.mark.parametrize("name", list(CASES))
def test_the_emulator_answers_as_the_firmware(firmware, name):
    text = "".join(x + "\n" for x in CASES[name] + ["G4P0"])
    fw, _ = firmware(text)
    emu, _ = emulated(text)
    assert comparable(emu) == comparable(fw)


def test_the_emulator_refuses_what_the_firmware_refuses_and_no_more(firmware):
    """The issue's list, as one job: every answer the firmware gives."""
    text = "\n".join(["$20=1", "G2X10Y0R5F1000", "G92.1", "T1", "M1", "G28", "G55", "G56", "G57", "G58", "G59",
                      "G54", "G4P-1", "$Q", "G4P0", ""])
    fw, _ = firmware(text)
    emu, _ = emulated(text)
    assert fw == emu and fw[0] == "error:10" and fw.count("ok") == 12 and fw[-3:-1] == ["error:4", "error:2"]


def _job(seed: int) -> str:
    """A job shaped like the gcode post's: travels, pen changes with dwells, strokes of short chords."""
    rng = np.random.default_rng(seed)
    out = ["G21 G90 G94", "M3 S0", "G4 P0.15"]
    for _ in range(12):
        p = rng.uniform(20, 280, 2)
        out += [f"G0 X{p[0]:.3f} Y{p[1]:.3f}", "M3 S1000", "G4 P0.15"]
        heading = rng.uniform(0, 2 * np.pi)
        feed = rng.choice([3000, 6000, 9000])
        for k in range(60):
            heading += rng.normal(0, 0.15)
            p = np.clip(p + rng.uniform(0.2, 2.0) * np.array([np.cos(heading), np.sin(heading)]), 0, 290)
            out.append(f"G1 X{p[0]:.3f} Y{p[1]:.3f}" + (f" F{feed}" if k == 0 else ""))
        out += ["M3 S0", "G4 P0.15"]
    out += ["G2 X100 Y100 R30 F6000", "G0 X0 Y0", "M2"]
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("seed", [1, 2])
def test_the_emulators_job_time_is_the_firmwares(firmware, seed):
    """GRBL's planner in the emulator (step-rounded targets, junctions, look-ahead, ramps): a job of short chords,
    pen changes and an arc takes the firmware's time within 1 % (the emulator timed every block at its feed,
    without acceleration, before)."""
    text = _job(seed)
    fw, fw_s = firmware(text)
    emu, emu_s = emulated(text)
    assert emu == fw
    assert abs(emu_s / fw_s - 1) <= 0.01, (emu_s, fw_s)
