"""Implausible profiles (doodlecam.plausible): refused by every command that loads them, in one
line naming the file, the key and the fix, with the unit slip that most likely caused the value."""

import copy
import os
import subprocess
import sys
from pathlib import Path

import pytest

from doodlecam.errors import MachineError
from doodlecam.machine import load_machine, parse_machine
from doodlecam.plausible import findings

from conftest import PROFILE

ROOT = Path(__file__).resolve().parent.parent
GRBL = ROOT / "doodlecam" / "machines" / "grbl-servo.toml"
CAMERA = ROOT / "samples" / "images" / "camera.png"


def cli(*args, cwd=None):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, "-m", "doodlecam", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=300, cwd=cwd)


def edited(tmp_path, old, new, name="bad.toml"):
    text = GRBL.read_text()
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1))
    return p


# The four profiles: each passed 'machines check' and converted without a word.
SLIPS = [
    ("home = [0.0, 0.0]", "home = [500.0, 0.0]", ["work_area.home = [500, 0]", "outside the 297 x 210 mm", "[0, 0]"]),
    ("delta_time = 0.04", "delta_time = 40", ["sampling.delta_time = 40 s", "looks like milliseconds", "write 0.04"]),
    ("up_delay = 0.15", "up_delay = 150", ["pen.up_delay = 150 s", "looks like milliseconds", "write 0.15"]),
    ("max_velocity = 100.0", "max_velocity = 6000",
     ["axes.x.max_velocity = 6000 mm/s", "looks like mm/min", "write 100 (mm/s)"]),
]


@pytest.mark.parametrize("old,new,words", SLIPS, ids=["home", "delta_time", "up_delay", "mm/min"])
def test_implausible_profile_is_refused_by_check_and_convert(tmp_path, old, new, words):
    prof = edited(tmp_path, old, new)
    for args in (("machines", "check", prof), ("convert", CAMERA, "-o", tmp_path / "o", "-m", prof)):
        r = cli(*args)
        err = r.stderr.strip()
        assert r.returncode == 2 and "Traceback" not in r.stderr and len(err.splitlines()) == 1, r.stderr
        assert str(prof) in err and all(w in err for w in words), err
        assert "OK" not in r.stdout
    assert not (tmp_path / "o").exists()  # refused before anything was made


def data(edit):
    d = copy.deepcopy(PROFILE)
    edit(d)
    return d


def refused(edit) -> str:
    with pytest.raises(MachineError) as e:
        parse_machine(data(edit), "p.toml")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("p.toml: ")
    return msg


def test_bounds_of_each_value():
    assert "delta_time = 0.0001 s is shorter than 1 ms" in refused(lambda d: d["sampling"].update(delta_time=1e-4))
    assert "pen.down_delay = 9 s" in refused(lambda d: d["pen"].update(down_delay=9.0))
    assert "travel.speed = 9000" in refused(lambda d: d.update(travel={"speed": 9000.0}))
    assert "pen.max_speed = 3000" in refused(lambda d: d["pen"].update(max_speed=3000.0))
    assert "max_acceleration = 200000" in refused(lambda d: d["axes"]["y"].update(max_acceleration=2e5))
    assert "pen[2].up_delay = 100 s" in refused(
        lambda d: d.update(pen=[{"name": "a"}, {"name": "b", "up_delay": 100.0}]))
    # far beyond mm/min too: no misleading hint
    assert "looks like" not in refused(lambda d: d["axes"]["x"].update(max_velocity=5e5))
    # the edges of the bounds are accepted
    for edit in (lambda d: d["sampling"].update(delta_time=1.0), lambda d: d["pen"].update(up_delay=5.0),
                 lambda d: d["work_area"].update(home=[300.0, 200.0])):
        parse_machine(data(edit), "p.toml")


def test_warnings_are_kept_for_check_and_the_summary():
    m = parse_machine(data(lambda d: d["axes"]["x"].update(max_velocity=0.2)), "p.toml")
    assert any("axes.x.max_velocity = 0.2 mm/s is very slow" in w and "write 200" in w for w in m.warnings)
    m = parse_machine(data(lambda d: d["axes"]["y"].update(max_acceleration=5.0)), "p.toml")
    assert any("if you meant 5 m/s^2, write 5000" in w for w in m.warnings)
    assert any("takes 1440 mm, more than the 200 mm of travel" in w for w in m.warnings)
    assert parse_machine(PROFILE, "p.toml").warnings == ()


def test_step_rate_against_the_controller(tmp_path):
    # GRBL on an Arduino: 30 kHz; 300 mm/s at 160 steps/mm is 48 kHz (a warning: grblHAL steps faster)
    text = GRBL.read_text().replace("steps_per_mm = 80.0", "steps_per_mm = 160.0").replace(
        "max_velocity = 100.0", "max_velocity = 300.0")
    (tmp_path / "fast.toml").write_text(text)
    m = load_machine(tmp_path / "fast.toml")
    assert any("48 kHz of steps; GRBL 1.1 on an Arduino steps at most about 30 kHz: lower max_velocity to 188 mm/s"
               in w for w in m.warnings), m.warnings
    r = cli("machines", "check", tmp_path / "fast.toml")
    assert r.returncode == 0 and "warning: " in r.stdout and "with 2 warnings above" in r.stdout
    # the EiBotBoard cannot step faster than 25 kHz: an error
    ax = load_machine("axidraw-v3")
    text = Path(ax.source).read_text().replace("steps_per_mm = 80.0\nmax_velocity = 165.7",
                                               "steps_per_mm = 200.0\nmax_velocity = 165.7", 1)
    (tmp_path / "ebb.toml").write_text(text)
    with pytest.raises(MachineError, match=r"axes.x.max_velocity = 165.7 mm/s at 200 steps/mm is 33 kHz.*"
                                           r"EiBotBoard steps at most about 25 kHz: lower max_velocity to 125"):
        load_machine(tmp_path / "ebb.toml")


def test_shipped_profiles_are_plausible():
    from doodlecam.machine import available_machines

    for name in available_machines():
        assert [f.message for f in findings(load_machine(name))] == [], name


def test_unknown_solver_and_kinematics_name_the_file_and_key(tmp_path):
    prof = edited(tmp_path, 'solver = "reach"', 'solver = "rech"')
    r = cli("machines", "check", prof)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert f"{prof}: machine.solver = 'rech' is unknown (did you mean 'reach'?)" in r.stderr
    prof = edited(tmp_path, 'kinematics = "cartesian"', 'kinematics = "corexy"', "k.toml")
    for args in (("machines", "check", prof), ("convert", CAMERA, "-o", tmp_path / "o", "-m", prof)):
        r = cli(*args)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert f"{prof}: machine.kinematics = 'corexy' is unknown" in r.stderr and "cartesian" in r.stderr
    assert not (tmp_path / "o").exists()


def test_profile_encodings(tmp_path):
    text = GRBL.read_text()
    (tmp_path / "u16.toml").write_bytes(text.encode("utf-16"))
    r = cli("machines", "check", tmp_path / "u16.toml")
    assert r.returncode == 2 and "UTF-16" in r.stderr and "save it as UTF-8" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    (tmp_path / "latin.toml").write_bytes(text.replace("# A GRBL", "# Ä GRBL").encode("latin-1"))
    with pytest.raises(MachineError, match="is not UTF-8 text.*save it as UTF-8"):
        load_machine(tmp_path / "latin.toml")
    (tmp_path / "bom.toml").write_bytes(text.encode("utf-8-sig"))  # Notepad's UTF-8 with a byte-order mark
    assert load_machine(tmp_path / "bom.toml").name == "grbl-servo"
