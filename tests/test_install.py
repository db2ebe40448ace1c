"""A non-editable install without extras, used from an empty folder, as a new user would (issues 16, 27).

Builds the wheel once (offline: no build isolation, setuptools comes from the
test extra), installs it without dependencies into a fresh venv that borrows
from this environment only the distributions the wheel's base requirements
pull in (no extra: FastAPI, matplotlib, trimesh, qpsolvers, ... are not
importable there), and runs the CLI from an empty folder: nothing of the
checkout is on the path. Slow (the installed package compiles its numba
kernels on the first conversion, about a minute of CPU), so one test.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import venv
import zipfile
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parent.parent
COPY_IGNORE = shutil.ignore_patterns(".venv", ".git", "__pycache__", "build", "*.egg-info", "out", ".pytest_cache",
                                     ".hypothesis", "tests", "benchmarks")


def _run(cmd, cwd, env, timeout=900):
    return subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def base_requirements(wheel: Path) -> list[str]:
    """The Requires-Dist lines of the wheel's METADATA that no extra guards (markers kept)."""
    with zipfile.ZipFile(wheel) as z:
        (name,) = [n for n in z.namelist() if n.endswith(".dist-info/METADATA")]
        lines = z.read(name).decode().splitlines()
    reqs = [line.partition(":")[2].strip() for line in lines if line.startswith("Requires-Dist:")]
    return [r for r in reqs if "extra" not in str(Requirement(r).marker or "")]


def link_closure(requirements: list[str], into: Path) -> set[str]:
    """Symlink into ``into`` the installed files (top-level packages, modules, .libs folders,
    dist-info) of every distribution these requirements pull in, transitively, from this
    environment; what pip would install for them, and nothing else. Returns their names."""
    into.mkdir()
    done: set[tuple[str, str]] = set()
    names: set[str] = set()
    todo = [(r, "") for r in requirements]
    while todo:
        text, extra = todo.pop()
        req = Requirement(text)
        if req.marker is not None and not req.marker.evaluate({"extra": extra}):
            continue
        dist = metadata.distribution(req.name)
        for want in ("", *req.extras):
            if (canonicalize_name(req.name), want) not in done:
                done.add((canonicalize_name(req.name), want))
                todo += [(r, want) for r in dist.requires or ()]
        if canonicalize_name(req.name) in names:
            continue
        names.add(canonicalize_name(req.name))
        assert dist.files, f"{req.name} lists no files (no RECORD): cannot borrow it"
        site = Path(dist.locate_file(""))
        for top in {f.parts[0] for f in dist.files if f.parts[0] != ".."}:
            if not (into / top).exists() and (site / top).exists():
                (into / top).symlink_to(site / top)
    return names


@pytest.mark.install
def test_install_without_extras_from_an_empty_folder(tmp_path):
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=COPY_IGNORE)  # the build writes build/ and *.egg-info: not into the checkout
    wheels = tmp_path / "wheels"
    r = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
              "-w", wheels, src], tmp_path, os.environ)
    assert r.returncode == 0, r.stdout + r.stderr
    (wheel,) = wheels.glob("doodlecam-*.whl")

    fresh = tmp_path / "venv"
    venv.create(fresh, with_pip=False)
    py = fresh / "bin" / "python"
    purelib = _run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path, os.environ)
    # the base dependencies, borrowed from this environment; its (editable) doodlecam is not among them
    borrowed = link_closure(base_requirements(wheel), tmp_path / "deps")
    assert {"numpy", "clarabel", "click"} <= borrowed
    assert "pydantic" in borrowed  # the machine-profile schema
    assert not borrowed & {"fastapi", "uvicorn", "matplotlib", "trimesh", "rtree", "qpsolvers", "osqp", "highspy",
                           "distributed", "starlette"}, borrowed
    Path(purelib.stdout.strip(), "deps.pth").write_text(str(tmp_path / "deps") + "\n")
    r = _run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "-q", wheel],
             tmp_path, os.environ)
    assert r.returncode == 0, r.stdout + r.stderr

    empty = tmp_path / "empty"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DOODLECAM_", "PYTHON"))}
    env.update(XDG_CONFIG_HOME=str(tmp_path / "config"), XDG_CACHE_HOME=str(tmp_path / "cache"),
               PYTHONWARNINGS="ignore")
    exe = fresh / "bin" / "doodlecam"

    def doodlecam(*args):
        return _run([exe, *args], empty, env)

    where = _run([py, "-c", "import doodlecam; print(doodlecam.__file__)"], empty, env)
    assert where.stdout.startswith(str(fresh)), where.stdout  # the installed copy, not the checkout
    absent = _run([py, "-c", "import importlib.util as u; print([m for m in ('fastapi', 'matplotlib', 'trimesh', "
                   "'qpsolvers') if u.find_spec(m)])"], empty, env)
    assert absent.stdout.strip() == "[]", absent.stdout + absent.stderr  # really without the extras

    # what needs an extra says which, in one line, and writes nothing
    for args, line in [
        (("studio", "--no-browser"), "the studio needs the studio extra: pip install 'doodlecam[studio]'"),
        (("plot", "camera.png", "-o", "fig.png"), "doodlecam plot needs the plot extra: pip install 'doodlecam[plot]'"),
    ]:
        r = doodlecam(*args)
        assert (r.returncode, r.stderr) == (2, f"doodlecam: error: {line}\n"), (args, r.stderr)
    assert not any(empty.iterdir())

    # the built-in profiles, from anywhere
    r = doodlecam("machines")
    assert r.returncode == 0
    for name in ("doodlebot", "fivebar", "grbl-servo", "grbl-z"):
        assert f"  {name} " in r.stdout and "built-in" in r.stdout

    # a first plot with the built-in profile; the first run says it compiles, once
    picture = empty / "camera.png"
    shutil.copy(ROOT / "samples" / "images" / "camera.png", picture)
    r = doodlecam("convert", "camera.png", "-o", "out", "--post", "gcode", "--post", "svg")
    assert r.returncode == 0, r.stderr
    assert "first run" in r.stderr and "compil" in r.stderr
    assert sorted(p.name for p in (empty / "out").iterdir()) == ["camera.gcode", "camera.svg"]
    r = doodlecam("convert", "camera.png", "-o", "out", "--post", "svg")
    assert r.returncode == 0 and "first run" not in r.stderr, r.stderr

    # a batch: its index.html comes from a template shipped as package data
    (empty / "pics").mkdir()
    shutil.copy(picture, empty / "pics" / "camera.png")
    r = doodlecam("batch", "pics", "batch-out", "-j", "1", "--post", "svg", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "camera.svg" in (empty / "batch-out" / "index.html").read_text()
    shutil.rmtree(empty / "pics")
    shutil.rmtree(empty / "batch-out")

    # a profile of one's own
    r = doodlecam("machines", "new", "mine", "--from", "grbl-z")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "config" / "doodlecam" / "machines" / "mine.toml").is_file()
    r = doodlecam("machines", "check", "mine")
    assert r.returncode == 0 and "$100=80 $101=80" in r.stdout and "OK: the profile is valid" in r.stdout, r.stderr

    # mistakes: one line, exit 2, nothing written
    before = sorted(p.relative_to(empty) for p in empty.rglob("*"))
    for args, first_line in [
        (("convert", "camera.png", "-m", "doodlebto"), "doodlecam: error: unknown machine 'doodlebto' (did you mean 'doodlebot'?)"),
        (("convert", "camera.png", "--post", "gcod"), "doodlecam: error: unknown postprocessor 'gcod' (did you mean 'gcode'?)"),
        (("convert", "camera.png", "--post-opt", "gcode.pen_upp=M5"),
         "doodlecam: error: postprocessor 'gcode' has no option 'pen_upp' (did you mean 'pen_up'?)"),
        (("convert", "camera.png", "--tracer", "edgse"), "doodlecam: error: unknown tracer 'edgse' (did you mean 'edges'?)"),
        (("convert", "camera.png", "--solver", "qp:osqp"),
         "doodlecam: error: the qp solver needs the solvers extra: pip install 'doodlecam[solvers]' (or use the default"),
        (("convert", "camera.png", "-o", "camera.png/out"), "doodlecam: error: camera.png/out: camera.png is a file"),
        (("convert", "missing.png"), "doodlecam: error: missing.png: no such file"),
        (("machines", "check", "mien"), "doodlecam: error: unknown machine 'mien' (did you mean 'mine'?)"),
    ]:
        r = doodlecam(*args)
        assert r.returncode == 2 and r.stderr.splitlines() and r.stderr.count("\n") == 1, (args, r.stderr)
        assert r.stderr.startswith(first_line), (args, r.stderr)
    assert sorted(p.relative_to(empty) for p in empty.rglob("*")) == before
