import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings
from PIL import Image

from doodlecam.machine import parse_machine

# Property-based tests draw the same examples on every run, so a red CI is
# reproducible and never luck; HYPOTHESIS_PROFILE=explore searches with fresh
# random examples (do that when changing geometry or planning code).
settings.register_profile("default", derandomize=True)
settings.register_profile("explore", derandomize=False, max_examples=200)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

# The user's own machine profiles (platformdirs honours $XDG_CONFIG_HOME) must not
# change what the tests see; subprocesses inherit this too.
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="doodlecam-test-config-")
# ... and the simulators' non-volatile memory (the PLC simulator keeps one per port there by default)
os.environ["XDG_STATE_HOME"] = tempfile.mkdtemp(prefix="doodlecam-test-state-")

GRBL_FIRMWARE = Path(__file__).resolve().parents[2] / "shared" / "grbl-fw"


@pytest.fixture(scope="session")
def grbl_firmware(tmp_path_factory):
    """GRBL 1.1h's own code in ../shared/grbl-fw's load-independent simulator, built once per run:
    ``run(text, *args)`` feeds it ``text`` with the doodlebot EEPROM (its README) and returns GRBL's
    answers and the fields of its summary line (ok, error, alarm, job_s, ...)."""
    if not (GRBL_FIRMWARE / "build.sh").is_file() or shutil.which("gcc") is None:
        pytest.skip("GRBL's firmware simulator (../shared/grbl-fw) or gcc is not here")
    out = tmp_path_factory.mktemp("grblfw")
    r = subprocess.run(["bash", str(GRBL_FIRMWARE / "build.sh"), str(out)], capture_output=True, text=True, timeout=300)
    if not (out / "grbl_lock").is_file():
        pytest.skip(f"the firmware simulator did not build: {r.stderr[-300:]}")

    def run(text: str, *args: str) -> tuple[str, dict[str, str]]:
        run_dir = Path(tmp_path_factory.mktemp("run"))
        shutil.copy(GRBL_FIRMWARE / "eeprom-doodlebot" / "EEPROM.DAT", run_dir / "EEPROM.DAT")
        p = subprocess.run([str(out / "grbl_lock"), *args], input=text, cwd=run_dir, capture_output=True, text=True,
                           timeout=600)
        end = p.stderr.strip().splitlines()[-1]
        return p.stdout, dict(kv.split("=", 1) for kv in end.split() if "=" in kv)

    return run


PROFILE = {
    "machine": {"name": "testbot", "kinematics": "cartesian"},
    "work_area": {"width": 300.0, "height": 200.0, "margin": 10.0},
    "axes": {
        "x": {"steps_per_mm": 80.0, "max_velocity": 150.0, "max_acceleration": 2000.0},
        "y": {"steps_per_mm": 80.0, "max_velocity": 120.0, "max_acceleration": 1500.0},
    },
    "pen": {"up_delay": 0.1, "down_delay": 0.1},
    "sampling": {"delta_time": 0.04},
}


@pytest.fixture
def machine():
    return parse_machine(PROFILE, "test.toml")


@pytest.fixture
def limits(machine):
    from doodlecam.registry import kinematics_for
    from doodlecam.plan.planner import Limits

    return Limits.from_machine(machine, kinematics_for(machine))


def report_curve():
    """A curve like the report's Fig. 2.4.1: 8 control points, several limiting-axis changes."""
    from doodlecam.model import Spline

    ctrl = np.array([[20, 20], [60, 90], [110, 30], [150, 110], [90, 150], [40, 120], [100, 60], [160, 40]], float)
    return Spline(3, ctrl)


def save(tmp_path, name, array, mode=None, **kw):
    """A picture file made from an array (PIL infers the format from the name)."""
    path = tmp_path / name
    (Image.fromarray(array, mode) if mode else Image.fromarray(array)).save(path, **kw)
    return path


def assert_one_line(err, path):
    """A user error: one line that names the file."""
    msg = str(err.value)
    assert "\n" not in msg and path.name in msg


def plc_strokes(path):
    """(header, strokes) of a PLC packet file, walked like the PLC does it: a MOVE
    starts a stroke at its position (mm), the DRAWs after it are its velocity
    targets (mm/s). Strokes without DRAWs (the final move home) are left out."""
    from doodlecam.link.plc.packetfile import read_plc

    header, cmds = read_plc(path.read_bytes())
    kx, ky = header.steps_per_mm_x, header.steps_per_mm_y
    strokes, cur = [], None
    for c in cmds:
        if c.type == 1:
            cur = {"start": np.array([c.x / kx, c.y / ky]), "v": []}
            strokes.append(cur)
        else:
            cur["v"].append((c.x / kx, c.y / ky))
    return header, [s for s in strokes if s["v"]]


def plc_pieces(header, runs, samples):
    """The runs of ``plc_strokes`` split into the job's strokes: a MOVE's run of DRAWs holds
    the strokes drawn without lifting (Job.lifts), each with as many targets as its samples,
    each starting where the one before left the machine (mm)."""
    out, it = [], iter(samples)
    for run in runs:
        start, at = run["start"], 0
        while at < len(run["v"]):
            part = run["v"][at:at + len(next(it).velocity)]
            out.append({"start": start, "v": part})
            v = np.vstack([[0, 0], part])
            start = start + np.sum(0.5 * header.delta_time * (v[1:] + v[:-1]), axis=0)
            at += len(part)
    return out
