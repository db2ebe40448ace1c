"""The post-processor API: csv and json posts, `plugins show`, API versions,
broken plugins, and the third-party examples (a package with an entry point
and a single-file drop-in) run through the CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from doodlecam.errors import PluginError
from doodlecam.machine import parse_machine
from doodlecam.model import Profile, Spline
from doodlecam.postprocessors.csvtable import COLUMNS, CsvPost
from doodlecam.postprocessors.jsonplan import JsonPost
from test_posts import MACHINE, make_job

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = ROOT / "samples" / "plugin-example"
DROPINS = ROOT / "samples" / "plugins"
SVG = """<svg xmlns="http://www.w3.org/2000/svg" width="100mm" height="80mm" viewBox="0 0 100 80">
<path d="M10 10 L60 10 L60 60 L10 60 Z" fill="none" stroke="black"/>
<circle cx="75" cy="40" r="15" fill="none" stroke="black"/></svg>
"""


@pytest.fixture(scope="module")
def job():
    return make_job(parse_machine(MACHINE, "test.toml"))


def run(*args, env=None, cwd=ROOT):
    e = dict(os.environ)
    e.pop("DOODLECAM_PLUGIN_PATH", None)
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "doodlecam", *map(str, args)], capture_output=True, text=True,
                          env=e, cwd=cwd, timeout=120)


def one_line_error(r, *words):
    assert r.returncode != 0
    err = r.stderr.strip()
    assert err.startswith("doodlecam: error:") and "\n" not in err and "Traceback" not in err, r.stderr
    for w in words:
        assert w in err, err


# ------------------------------------------------------------------ csv

def table(text: str):
    lines = text.splitlines()
    assert lines[0].startswith("# doodlecam motion table")
    hdr = next(i for i, x in enumerate(lines) if not x.startswith("#"))
    assert tuple(lines[hdr].split(",")) == COLUMNS
    return np.array([[float(v) for v in x.split(",")] for x in lines[hdr + 1:]])


def test_csv_is_a_motdes_table_of_the_plan(job):
    fine = table(CsvPost().write(job, CsvPost.resolve_options({"step": 0.001, "decimals": 9})).decode())
    t, xy, v, a, jerk, j, pen = fine[:, 0], fine[:, 1:3], fine[:, 3:5], fine[:, 5:7], fine[:, 7], fine[:, 8:10], fine[:, 10]
    assert np.allclose(np.diff(t)[:-1], 0.001) and t[0] == 0.0
    m = job.machine
    total = sum(s.profile.duration for s in job.strokes) + sum(tr.duration for tr in job.travels) \
        + len(job.strokes) * (m.pen.up_delay + m.pen.down_delay)
    assert t[-1] == pytest.approx(total, abs=1e-9)
    assert np.allclose(jerk, np.linalg.norm(j, axis=1), atol=1e-6)
    down = pen == 1
    # Pen-down rows lie on the strokes' splines.
    pts = np.vstack([s.spline(np.linspace(0, 1, 200_001)) for s in job.strokes])
    from scipy.spatial import cKDTree

    assert cKDTree(pts).query(xy[down])[0].max() < 0.01
    # Within strokes, v, a and j are the time derivatives of x, a and v (central differences).
    inner = down[1:-1] & down[:-2] & down[2:]
    dv = (xy[2:] - xy[:-2]) / 0.002
    assert np.abs(dv - v[1:-1])[inner].max() < 0.05 * np.abs(v).max()
    da = (v[2:] - v[:-2]) / 0.002
    ok = inner & (np.abs(da - a[1:-1]).max(axis=1) < 0.02 * np.abs(a).max())
    assert ok.sum() > 0.95 * inner.sum()  # a jumps where the profile's piecewise-constant ü changes
    # Peak pen speed matches the profile's b = u̇².
    st = job.strokes[0]
    vplan = np.linalg.norm(st.spline(st.profile.u, 1), axis=1) * np.sqrt(st.profile.b)
    assert np.linalg.norm(v[down], axis=1).max() == pytest.approx(max(vplan.max(), np.linalg.norm(
        job.strokes[1].spline(job.strokes[1].profile.u, 1), axis=1).__mul__(np.sqrt(job.strokes[1].profile.b)).max()), rel=0.01)


def test_csv_options(job):
    only = table(CsvPost().write(job, CsvPost.resolve_options({"travels": "no"})).decode())
    assert (only[:, -1] == 1).all()
    assert only[-1, 0] == pytest.approx(sum(s.profile.duration for s in job.strokes), abs=1e-6)
    bare = CsvPost().write(job, CsvPost.resolve_options({"comments": "no", "decimals": 2})).decode()
    assert bare.splitlines()[0] == ",".join(COLUMNS) and "-0.00," not in bare
    with pytest.raises(PluginError):
        CsvPost().write(job, CsvPost.resolve_options({"step": 0}))


# ------------------------------------------------------------------ json

def test_json_is_the_whole_plan_exactly(job):
    doc = json.loads(JsonPost().write(job, JsonPost.resolve_options()))
    assert doc["format"] == "doodlecam-plan" and doc["version"] == 1
    assert doc["machine"]["name"] == "testbot" and doc["machine"]["axes"][0]["max_acceleration"] == 2000.0
    assert len(doc["strokes"]) == len(job.strokes) and len(doc["travels"]) == len(job.travels)
    for d, st in zip(doc["strokes"], job.strokes):
        sp = Spline(d["degree"], d["control"])
        assert np.array_equal(sp.control, st.spline.control)
        p = d["profile"]
        prof = Profile(u=p["u"], b=p["b"], a=p["a"], t=p["t"])
        for k in ("u", "b", "a", "t"):
            assert np.array_equal(getattr(prof, k), getattr(st.profile, k))  # repr precision: exact
    for d, sm in zip(doc["samples"], job.samples):
        assert np.array_equal(np.array(d["velocity"]), sm.velocity)
    assert doc["figures"]["job_time_s"] == job.duration
    small = json.loads(JsonPost().write(job, JsonPost.resolve_options({"decimals": 3, "samples": "no"})))
    assert "samples" not in small and small["strokes"][0]["control"][1] == [80.0, 120.0]


# ------------------------------------------------------------------ CLI: plugins show, broken plugins

def test_plugins_show_prints_options_and_origin():
    r = run("plugins", "show", "gcode")
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "postprocessor" in out and "entry point, doodlecam" in out and "doodlecam.postprocessors.gcode.GcodePost" in out
    for name in ("dialect", "chord_tolerance", "pen_up", "estimate"):
        assert f"    {name} " in out
    assert "default 'grbl'" in out and "one of: grbl, marlin, linuxcnc" in out and "float  default 0.05" in out
    assert "--post-opt gcode.KEY=VALUE" in out and "[post.gcode]" in out
    r = run("plugins")  # the listing still works, and points to `show`
    assert r.returncode == 0 and "  csv " in r.stdout and "  json " in r.stdout and "plugins show NAME" in r.stdout
    one_line_error(run("plugins", "show", "nosuch"), "nosuch", "gcode")


BAD = '''
from doodlecam.api import PostProcessor

class Bad(PostProcessor):
    name = "{name}"
    summary = "bad"
    extension = ".bad"
    {extra}
    def write(self, job, options):
        {body}
'''


def test_broken_plugins_are_named_in_one_line(tmp_path):
    plug = tmp_path / "plug"
    plug.mkdir()
    (plug / "wrongtype.py").write_text(BAD.format(name="wrongtype", extra="", body="return 'text, not bytes'"))
    (plug / "future.py").write_text(BAD.format(name="future", extra="api_version = 99", body="return b''"))
    (plug / "crash.py").write_text("raise RuntimeError('import-time kaput')\n")
    r = run("plugins", "show", "future", "--plugin-dir", plug)
    one_line_error(r, "future", "API 99")
    r = run("plugins", "show", "crash", "--plugin-dir", plug)
    one_line_error(r, "crash", "import-time kaput")
    svg = tmp_path / "in.svg"
    svg.write_text(SVG)
    out = tmp_path / "o"
    one_line_error(run("convert", svg, "-o", out, "--plugin-dir", plug, "--post", "svg", "--post", "wrongtype"),
                   "wrongtype", "not bytes")
    assert not out.exists() or not list(out.iterdir())  # nothing half-written


# ------------------------------------------------------------------ third-party examples

def _fake_install(site: Path) -> None:
    """Install samples/plugin-example into ``site`` the way pip lays it out, without pip:
    a .dist-info whose entry_points.txt comes from the package's own pyproject.toml
    (importlib.metadata finds it on sys.path exactly as it finds an installed package).
    The shared venv is never touched."""
    import tomllib

    meta = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]
    dist = site / f"{meta['name'].replace('-', '_')}-{meta['version']}.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {meta['name']}\nVersion: {meta['version']}\n")
    lines = []
    for group, eps in meta["entry-points"].items():
        lines.append(f"[{group}]")
        lines += [f"{k} = {v}" for k, v in eps.items()]
    (dist / "entry_points.txt").write_text("\n".join(lines) + "\n")


def test_example_package_and_dropin_through_the_cli(tmp_path):
    site = tmp_path / "site"
    _fake_install(site)
    env = {"PYTHONPATH": os.pathsep.join([str(site), str(EXAMPLE / "src")])}
    r = run("plugins", "show", "hpgl", env=env)
    assert r.returncode == 0, r.stderr
    assert "entry point, doodlecam-example 0.1.0" in r.stdout and "    pen " in r.stdout
    r = run("plugins", "show", "stats", "--plugin-dir", DROPINS)
    assert r.returncode == 0 and str(DROPINS / "stats.py") in r.stdout and "    top " in r.stdout

    svg = tmp_path / "in.svg"
    svg.write_text(SVG)
    out = tmp_path / "o"
    r = run("convert", svg, "-o", out, "--plugin-dir", DROPINS, "--post", "hpgl", "--post", "stats",
            "--post", "csv", "--post", "json", "--post-opt", "hpgl.pen=2", "--post-opt", "stats.top=2", env=env)
    assert r.returncode == 0, r.stderr
    hpgl = (out / "in.hpgl").read_text().splitlines()
    assert hpgl[:2] == ["IN;", "SP2;"] and hpgl[-1] == "SP0;"
    doc = json.loads((out / "in.json").read_text())
    assert sum(line.startswith("PD") for line in hpgl) == len(doc["strokes"]) >= 2
    first = next(line for line in hpgl if line.startswith("PD"))
    pd = np.array([int(v) for v in first[2:-1].split(",")]).reshape(-1, 2) / 40.0  # first stroke, mm
    ctrl = np.array(doc["strokes"][0]["control"])
    assert np.abs(pd[-1] - ctrl[-1]).max() <= 0.0125 + 1e-9  # ends where the spline ends, to a plotter unit
    stats = (out / "in.stats.txt").read_text()
    assert f"strokes {len(doc['strokes'])}" in stats and stats.count("  stroke ") == 2
    assert (out / "in.csv").read_text().count("\n") > 100


def test_example_package_declares_its_entry_point():
    import tomllib

    meta = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())
    assert meta["project"]["entry-points"]["doodlecam.postprocessors"] == {"hpgl": "doodlecam_example.hpgl:HpglPost"}
    assert meta["tool"]["setuptools"]["packages"]["find"]["where"] == ["src"]


def test_docs_cover_every_builtin_post_option():
    doc = (ROOT / "docs" / "plugins.md").read_text()
    from importlib.metadata import entry_points

    for ep in entry_points(group="doodlecam.postprocessors"):
        if ep.dist is None or ep.dist.name != "doodlecam":
            continue
        cls = ep.load()
        assert f"`{cls.name}`" in doc, cls.name
        for o in cls.options:
            assert f"`{o.name}`" in doc, f"docs/plugins.md does not mention {cls.name}.{o.name}"
