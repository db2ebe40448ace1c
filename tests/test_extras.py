"""The optional parts (pyproject's extras): a command that needs a missing one names it in one
line, exit 2, before any work and with nothing written. A module is made missing here by
putting None in sys.modules, which is what importlib.util.find_spec then answers; the real
install without extras is tests/test_install.py."""

from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from doodlecam.cli import main
from doodlecam.extras import EXTRAS

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
CAMERA = ROOT / "samples" / "images" / "camera.png"


def hide(monkeypatch, extra):
    for module in EXTRAS[extra]:
        monkeypatch.setitem(sys.modules, module, None)


def refused(capsys, args, line, out: Path | None = None):
    assert main([str(a) for a in args]) == 2
    err = capsys.readouterr().err
    assert err == f"doodlecam: error: {line}\n", err
    assert out is None or not out.exists()


@pytest.mark.parametrize("extra, args, line", [
    ("studio", ["studio", "--no-browser", "--port", "0"],
     "the studio needs the studio extra: pip install 'doodlecam[studio]'"),
    ("plot", ["plot", CAMERA, "-o", "{out}/fig.png"], "doodlecam plot needs the plot extra: pip install 'doodlecam[plot]'"),
    ("plot", ["motion", ROOT / "samples" / "motion" / "fuse.toml", "-o", "{out}"],
     "the motion plot (NAME.png) needs the plot extra: pip install 'doodlecam[plot]' (or --no-plot)"),
    ("solvers", ["convert", CAMERA, "-o", "{out}", "--solver", "lp:clarabel"],
     "the lp solver needs the solvers extra: pip install 'doodlecam[solvers]' (or use the default, --solver reach)"),
    ("solvers", ["convert", CAMERA, "-o", "{out}", "--solver", "qp"],
     "the qp solver needs the solvers extra: pip install 'doodlecam[solvers]' (or use the default, --solver reach)"),
    ("mesh", ["convert", ROOT / "samples" / "vectors" / "gear.stl", "-o", "{out}"],
     "a mesh (STL, OBJ, PLY, OFF) needs the mesh extra: pip install 'doodlecam[mesh]'"),
    ("dask", ["batch", ROOT / "samples" / "images", "{out}", "--scheduler", "tcp://127.0.0.1:9"],
     "--scheduler needs the dask extra: pip install 'doodlecam[dask]'"),
])
def test_a_missing_extra_is_named_in_one_line(tmp_path, monkeypatch, capsys, extra, args, line):
    out = tmp_path / "out"
    hide(monkeypatch, extra)
    refused(capsys, [str(a).format(out=out) for a in args], line, out)


def test_without_the_optional_parts_the_default_commands_run(tmp_path, monkeypatch, capsys):
    for extra in EXTRAS:
        hide(monkeypatch, extra)
    out = tmp_path / "out"
    assert main(["convert", str(CAMERA), "-o", str(out), "--post", "svg", "--post", "gcode", "--json"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["camera.gcode", "camera.svg"]
    motion = ROOT / "samples" / "motion" / "fuse.toml"
    assert main(["motion", str(motion), "-o", str(out), "--no-plot", "--json"]) == 0
    capsys.readouterr()


def _names(requirements) -> set[str]:
    """The distributions these requirements name, and those their extras add (dask[distributed])."""
    out = set()
    for text in requirements:
        req = Requirement(text)
        out.add(canonicalize_name(req.name))
        for dep in map(Requirement, (metadata.requires(req.name) or []) if req.extras else []):
            if dep.marker and any(dep.marker.evaluate({"extra": e}) for e in req.extras):
                out.add(canonicalize_name(dep.name))
    return out


def test_the_extras_table_matches_pyproject():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    providers = metadata.packages_distributions()  # module -> the distributions that install it
    base = _names(project["dependencies"])
    for extra, modules in EXTRAS.items():
        for module in modules:
            dists = {canonicalize_name(d) for d in providers[module]}
            assert dists & _names(extras[extra]), (extra, module)  # the extra installs what it is checked by
            assert not dists & base, (extra, module)  # and the base install does not
    (everything,) = extras["all"]
    assert set(Requirement(everything).extras) == set(EXTRAS)
    assert "doodlecam[all]" in extras["test"]  # the README's set-up and CI install every part
