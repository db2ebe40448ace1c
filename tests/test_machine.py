import copy

import pytest

from doodlecam.errors import MachineError
from doodlecam.machine import load_machine, parse_machine

from conftest import PROFILE


def test_sample_profile_loads():
    m = load_machine("doodlebot")
    assert m.name == "doodlebot" and m.kinematics == "cartesian"
    assert m.x.max_acceleration > 0 and m.delta_time == pytest.approx(0.04)
    assert m.plugin_options["post.gcode"]["pen_up"]


def broken(edit):
    data = copy.deepcopy(PROFILE)
    edit(data)
    with pytest.raises(MachineError) as e:
        parse_machine(data, "bad.toml")
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("bad.toml")
    return msg


def test_missing_key_is_named():
    msg = broken(lambda d: d["axes"]["y"].pop("max_acceleration"))
    assert "max_acceleration" in msg and "[axes.y]" in msg


def test_mistyped_key_gets_a_suggestion():
    def edit(d):
        d["axes"]["x"]["max_accleration"] = d["axes"]["x"].pop("max_acceleration")

    msg = broken(edit)
    assert "max_accleration" in msg and "max_acceleration" in msg


@pytest.mark.parametrize("value", [0, -5.0, "fast", True, float("nan")])
def test_bad_limit_values(value):
    msg = broken(lambda d: d["axes"]["x"].__setitem__("max_velocity", value))
    assert "max_velocity" in msg


def test_missing_table_and_unknown_table():
    assert "[work_area]" in broken(lambda d: d.pop("work_area"))
    assert "[axis]" in broken(lambda d: d.__setitem__("axis", {}))


def test_margin_must_leave_room():
    assert "margin" in broken(lambda d: d["work_area"].__setitem__("margin", 150.0))


def test_unknown_machine_name(tmp_path):
    with pytest.raises(MachineError, match="unknown machine 'doodlebt'.*did you mean 'doodlebot'"):
        load_machine("doodlebt")
    bad = tmp_path / "x.toml"
    bad.write_text("[machine\nname=1")
    with pytest.raises(MachineError, match="not valid TOML"):
        load_machine(bad)


def test_path_tolerance_defaults_to_the_fit_tolerance_and_is_not_negative():
    assert load_machine("doodlebot").path_tolerance == 0.1
    data = copy.deepcopy(PROFILE)
    data["sampling"].pop("path_tolerance", None)
    data.setdefault("fit", {})["tolerance"] = 0.05
    assert parse_machine(data, "p.toml").path_tolerance == 0.05  # absent: as close as the fit
    data["sampling"]["path_tolerance"] = 0.0
    assert parse_machine(data, "p.toml").path_tolerance == 0.0  # 0: not enforced
    assert "path_tolerance" in broken(lambda d: d["sampling"].__setitem__("path_tolerance", -0.1))
    assert "path_tolerance" in broken(lambda d: d["sampling"].__setitem__("path_tolerance", "tight"))


@pytest.mark.parametrize("profile", ["doodlebot", "grbl-servo", "axidraw-v3"])  # cartesian, cartesian, axidraw
def test_machines_that_reach_their_work_area_say_so_the_same_way(profile):
    from doodlecam.errors import PlanError
    from doodlecam.registry import kinematics_for

    m = load_machine(profile)
    kin = kinematics_for(m)
    w, h = m.width, m.height
    kin.check_reachable([[0, 0], [w, h], [w, 0], [0, h], [w / 2, h / 3]])  # edges included
    kin.check_reachable([[w + 1e-10, -1e-10]])  # rounding on an edge
    for point, shown in (([w + 0.5, 1.0], f"({w + 0.5:.2f}, 1.00)"), ([1.0, -0.25], "(1.00, -0.25)")):
        with pytest.raises(PlanError) as e:
            kin.check_reachable([[1.0, 1.0], point, [-5.0, -5.0]])  # the first point outside is named
        assert str(e.value) == f"point {shown} mm is outside the {w:g} x {h:g} mm work area of '{m.name}'"
