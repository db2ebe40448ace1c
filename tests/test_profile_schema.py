"""The machine profile's schema (doodlecam/schema.py, pydantic models): each mistake is one line
naming the file, the key as a dotted path and the fix, exit 2, for `machines check` and for every
command that loads the profile, and never pydantic's multi-line report."""

import copy
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from doodlecam.errors import MachineError
from doodlecam.machine import parse_machine

from conftest import PROFILE

ROOT = Path(__file__).resolve().parent.parent
GRBL = ROOT / "doodlecam" / "machines" / "grbl-servo.toml"
CAMERA = ROOT / "samples" / "images" / "camera.png"

# (edit of grbl-servo.toml, the whole message after "<file>: ")
MISTAKES = {
    "wrong type": ("max_velocity = 100.0", 'max_velocity = "fast"',
                   "axes.x.max_velocity = 'fast' is not a number; give the axis' top speed in mm/s, e.g. 100"),
    "out of range": ("degree = 3", "degree = 7",
                     "fit.degree = 7 must be at most 5; give 2 to 5 (3 is the report's cubic URBS; "
                     "2 and up keep the velocity continuous)"),
    "unknown key": ("max_acceleration = 1000.0           # GRBL $120", "max_accel = 1000.0",
                    "unknown key axes.x.max_accel (did you mean 'max_acceleration'?); rename or remove it"),
    "missing key": ("steps_per_mm = 80.0                 # GRBL $101\n", "",
                    "axes.y.steps_per_mm is missing; add it under [axes.y]: steps_per_mm = motor steps per mm of "
                    "travel, e.g. 80"),
    "pen entry": ("[pen]\nwidth = 0.5", '[[pen]]\nname = "black"\n[[pen]]\nname = "red"\nwidth = -0.3',
                  "pen[2].width = -0.3 must be positive; give the line width in mm, e.g. 0.5 "
                  "(shorter strokes are dropped)"),
    "stray key": ("[machine]\n", "margin = 5\n[machine]\n",
                  "unknown key margin (it belongs under [work_area] or [layout]); rename or remove it"),
}


def cli(*args):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, "-m", "doodlecam", *map(str, args)], capture_output=True, text=True,
                          env=env, timeout=300)


@pytest.mark.parametrize("old,new,expected", MISTAKES.values(), ids=MISTAKES.keys())
def test_each_mistake_is_one_line_naming_file_key_and_fix(tmp_path, old, new, expected):
    text = GRBL.read_text()
    assert old in text
    prof = tmp_path / "mine.toml"
    prof.write_text(text.replace(old, new, 1))
    r = cli("machines", "check", prof)
    assert r.returncode == 2 and r.stdout == "", r.stdout + r.stderr
    assert r.stderr == f"doodlecam: error: {prof}: {expected}\n"


def test_convert_refuses_before_any_work(tmp_path):
    prof = tmp_path / "mine.toml"
    prof.write_text(GRBL.read_text().replace("[pen]\nwidth = 0.5", "[[pen]]\nwidht = 0.5", 1))
    r = cli("convert", CAMERA, "-o", tmp_path / "out", "-m", prof)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr
    assert f"{prof}: unknown key pen[1].widht (did you mean 'width'?)" in r.stderr
    assert not (tmp_path / "out").exists()


def refused(edit) -> str:
    data = copy.deepcopy(PROFILE)
    edit(data)
    with pytest.raises(MachineError) as e:
        parse_machine(data, "p.toml")
    return str(e.value)


def test_messages_of_the_nested_tables():
    assert refused(lambda d: d.update(axis={})) == ("p.toml: unknown table [axis] (did you mean [axes]?); "
                                                    "rename or remove it")
    assert refused(lambda d: d["axes"].update(xx=d["axes"].pop("x"))) == (
        "p.toml: unknown table [axes.xx] (did you mean [axes.x]?); rename or remove it")  # not also "missing"
    assert refused(lambda d: d["axes"].update(z={})) == ("p.toml: unknown table [axes.z] (known here: [axes.x], "
                                                         "[axes.y]); rename or remove it")
    assert refused(lambda d: d.pop("work_area")) == ("p.toml: missing table [work_area]; add it with the keys "
                                                     "width, height (see 'doodlecam machines new')")
    assert refused(lambda d: d.update(pen=[{"name": "a"}, {"name": "A"}])) == (
        "p.toml: pen[2].name = 'A' is taken: two [[pen]] entries are named 'A'; give each pen its own name")
    assert refused(lambda d: d.update(pen=[{"layers": ["x", 3]}])).startswith(
        "p.toml: pen[1].layers[2] = 3 is not text (put it in quotes); give the drawing's layers this pen draws")
    assert refused(lambda d: d["work_area"].update(home=[1.0])) == (
        "p.toml: work_area.home = [1.0] has too few values; give two numbers [x, y] in mm, e.g. [0, 0]")
    assert refused(lambda d: d.update(kinematics="fivebar")).startswith(
        "p.toml: kinematics = 'fivebar' is not a table; give a table of the kinematics plugin's parameters "
        "(the plugin's name goes under [machine]")
    assert refused(lambda d: d.update(travel={"law": "smoth"})).startswith(
        "p.toml: travel.law = 'smoth' is unknown (did you mean 'smooth'?); use one of trapezoid")
    assert refused(lambda d: d.update(layout={"rotat": 90})) == (
        "p.toml: unknown key layout.rotat (did you mean 'rotate'?); rename or remove it")
    assert refused(lambda d: d.update(layout={"rotate": 45})).startswith("p.toml: layout.rotate must be one of 0, 90")
    # TOML's types as they are: no "1.5" or true for a number, no 3.0 for a whole number
    assert "sampling.delta_time = True is not a number" in refused(lambda d: d["sampling"].update(delta_time=True))
    assert "fit.degree = 3 is not a whole number" in refused(lambda d: d.update(fit={"degree": 3.0}))
    # several mistakes: the first is told, and how many more there are (a misspelt key is one)
    msg = refused(lambda d: (d["axes"]["x"].update(max_velocity="fast"), d["axes"]["y"].update(max_velocity=-1)))
    assert msg.startswith("p.toml: axes.x.max_velocity = 'fast'") and msg.endswith("(and 1 more problem)")
    assert "more" not in refused(lambda d: d["axes"]["x"].update(max_accleration=d["axes"]["x"].pop("max_acceleration")))


# A profile broken at a random place in a random way: refused in one line naming the file and the
# key, never with pydantic's own report.
KEYS = [(t, k) for t in ("machine", "work_area", "pen", "sampling") for k in PROFILE.get(t, {})] + [
    ("axes", "x"), ("axes", "y"), ("fit", "degree"), ("travel", "speed")]
VALUES = st.one_of(st.text(max_size=5), st.booleans(), st.floats(allow_nan=True), st.integers(-10**6, 10**6),
                   st.lists(st.integers(), max_size=3), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


@settings(max_examples=150, deadline=None)
@given(where=st.sampled_from(KEYS), value=VALUES, how=st.sampled_from(["set", "drop", "rename"]))
def test_any_broken_profile_gives_one_line(where, value, how):
    data = copy.deepcopy(PROFILE)
    table, key = where
    t = data.setdefault(table, {})
    if how == "set":
        t[key] = value
    elif key in t:
        v = t.pop(key)
        if how == "rename":
            t[key + "s"] = v
    try:
        parse_machine(data, "p.toml")
    except MachineError as e:
        msg = str(e)
        assert "\n" not in msg and msg.startswith("p.toml: "), msg
        assert table in msg, msg  # the key is named by its path
        assert not any(w in msg for w in ("validation error", "Input should", "pydantic", "For further")), msg
