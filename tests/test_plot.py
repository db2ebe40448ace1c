"""``doodlecam plot``: the report's figures per stroke, through the CLI and directly."""

import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from doodlecam.errors import InputError, OutputError
from doodlecam.machine import load_machine
from doodlecam.model import Job, Profile, Spline, Stroke, StrokeSamples
from doodlecam.registry import kinematics_for
from doodlecam.plot import output_paths, pick_strokes, plot_job, stroke_figure

ROOT = Path(__file__).resolve().parent.parent
HORSE = ROOT / "samples" / "images" / "horse.png"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def run(capsys, *args):
    """The real CLI entry, in this process (one import of matplotlib for all)."""
    from doodlecam.cli import main

    capsys.readouterr()
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def assert_svg(path: Path):
    root = ET.parse(path).getroot()
    assert root.tag.endswith("svg")
    assert len(list(root.iter())) > 500  # eight panels of curves, not an empty page


# ------------------------------------------------------------- a hand-made job
# Built without the planner so these tests check the plotting alone: a
# trapezoidal path-velocity profile and naively sampled velocities.

def _job(machine_name="doodlebot", ctrl=None):
    machine = load_machine(machine_name)
    if ctrl is None:
        ctrl = [[20, 20], [60, 90], [110, 30], [150, 110], [90, 150], [40, 120], [100, 60], [160, 40]]
    spline = Spline(3, np.array(ctrl, float))
    u = np.linspace(0, 1, 201)
    b = np.minimum.reduce([8 * u, 8 * (1 - u), np.full_like(u, 0.6)])  # u-dot^2, rest to rest
    a = np.diff(b) / (2 * np.diff(u))
    sb = np.sqrt(b)
    t = np.concatenate([[0.0], np.cumsum(2 * np.diff(u) / (sb[:-1] + sb[1:]))])
    prof = Profile(u=u, b=b, a=a, t=t, solver="hand")
    dt = machine.delta_time
    m = int(np.ceil(prof.duration / dt))
    us, ud, _ = prof.state_at(dt * np.arange(1, m + 1))

    def naive(sp):  # the report's sampling, which drifts
        vel = sp(us, 1) * ud[:, None]
        vel[-1] = 0.0
        return StrokeSamples(start=sp.start, velocity=vel, delta_time=dt, time_scale=1.0)

    short = Spline(3, (np.array(ctrl[:4], float) - ctrl[0]) * 0.5 + ctrl[0])
    strokes = (Stroke(spline=short, profile=prof), Stroke(spline=spline, profile=prof))
    return Job(machine=machine, strokes=strokes, travels=(), samples=(naive(short), naive(spline)), source="hand.png")


def _lines(ax):
    return [ln for ln in ax.get_lines()]


def test_figure_has_the_report_panels_and_the_limits():
    job = _job()
    kin = kinematics_for(job.machine)
    fig = stroke_figure(job, 1, kin)
    titles = [ax.get_title() for ax in fig.axes]
    for fig_no in ("2.4.1", "2.4.2", "2.4.3", "2.4.4", "2.4.5"):
        assert any(fig_no in t for t in titles), fig_no
    vmax, amax = kin.actuator_limits()
    by_title = {ax.get_title(): ax for ax in fig.axes}
    for what, lim in (("velocity", vmax), ("acceleration", amax)):
        ax = by_title[f"Actuator {what} (Fig. 2.4.5)"]
        flat = {float(ln.get_ydata()[0]) for ln in _lines(ax) if ln.get_linestyle() == "--"}
        assert {float(lim[0]), -float(lim[0]), float(lim[1]), -float(lim[1])} <= flat
    # the path panel shows every control point
    path = by_title["Path (Fig. 2.4.1)"]
    ctrl = [ln for ln in _lines(path) if ln.get_label().startswith("control points")][0]
    np.testing.assert_array_equal(np.column_stack(ctrl.get_data()), job.strokes[1].spline.control)
    # planned and executed positions end on the stroke's end point
    pos = by_title["x position (Fig. 2.4.2)"]
    ends = [float(ln.get_ydata()[-1]) for ln in _lines(pos) if ln.get_label() in ("executed (PLC ramp)",)]
    assert ends and abs(ends[0] - job.strokes[1].spline.end[0]) < 1.0


def test_fivebar_is_plotted_in_crank_angles():
    job = _job("fivebar", ctrl=[[40, 40], [120, 160], [200, 20], [250, 150]])
    kin = kinematics_for(job.machine)
    fig = stroke_figure(job, 1, kin)
    labels = {ax.get_ylabel() for ax in fig.axes}
    assert "theta1 (rad)" in labels and "velocity (rad/s)" in labels and "acceleration (rad/s²)" in labels
    ax = {a.get_title(): a for a in fig.axes}["theta4 position (Fig. 2.4.2)"]
    planned = [ln for ln in ax.get_lines() if ln.get_label().startswith("planned")][0]
    start = kin.inverse(job.strokes[1].spline.start[None])[0, 1]
    assert planned.get_ydata()[0] == pytest.approx(start)


def test_plot_job_writes_one_file_per_stroke(tmp_path):
    job = _job()
    out = plot_job(job, tmp_path / "fig.svg", strokes=[2, 1, 2])
    assert [(i, p.name) for i, p in out] == [(1, "fig_stroke2.svg"), (0, "fig_stroke1.svg")]
    for _, p in out:
        assert_svg(p)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig_stroke1.svg", "fig_stroke2.svg"]  # no temp files left
    # default: the longest stroke, to the given name
    (i, p), = plot_job(job, tmp_path / "one.png")
    assert i == 1 and p.name == "one.png" and png_size(p)[0] > 800


def test_bad_requests_are_refused_before_writing(tmp_path):
    job = _job()
    with pytest.raises(InputError, match=r"^--stroke 3: the job has 2 strokes; pick a number from 1 to 2"):
        pick_strokes(job, [1, 3])
    with pytest.raises(InputError, match="--stroke 0"):
        pick_strokes(job, [0])
    with pytest.raises(OutputError, match="give -o FILE.png or FILE.svg"):
        output_paths(tmp_path / "fig.jpeg", [0])
    with pytest.raises(InputError):
        plot_job(job, tmp_path / "x.png", strokes=[7])
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------- through the CLI

def test_cli_writes_png_of_the_longest_stroke(tmp_path, capsys):
    out = tmp_path / "horse.png"
    code, stdout, err = run(capsys, "plot", HORSE, "-o", out)
    assert code == 0, err
    w, h = png_size(out)
    assert w >= 1000 and h >= 1000
    assert stdout.startswith("stroke ") and str(out) in stdout
    assert [p.name for p in tmp_path.iterdir()] == ["horse.png"]


def test_cli_writes_svg(tmp_path, capsys):
    out = tmp_path / "h.svg"
    code, stdout, err = run(capsys, "plot", HORSE, "-o", out, "--stroke", "2", "--tracer-opt", "sigma=2")
    assert code == 0, err
    assert_svg(out)
    assert stdout.startswith("stroke 2 of ")


@pytest.fixture
def dots(tmp_path):
    """A small picture of two dots: quick to trace and plan."""
    from skimage.draw import disk
    from skimage.io import imsave

    img = np.full((60, 60), 255, np.uint8)
    img[disk((20, 20), 8)] = 0
    img[disk((40, 42), 8)] = 0
    path = tmp_path / "dots.png"
    imsave(path, img, check_contrast=False)
    return path


def test_cli_writes_one_file_per_stroke_and_refuses_bad_requests(tmp_path, dots, capsys):
    out = tmp_path / "figs" / "r.svg"
    code, stdout, err = run(capsys, "plot", dots, "-o", out, "--stroke", "2", "--stroke", "1")
    assert code == 0, err
    assert sorted(p.name for p in out.parent.iterdir()) == ["r_stroke1.svg", "r_stroke2.svg"]
    assert len(stdout.strip().splitlines()) == 2
    code, stdout, err = run(capsys, "plot", dots, "-o", tmp_path / "bad.png", "--stroke", "9999")
    lines = err.strip().splitlines()
    assert code != 0 and len(lines) == 1, err
    assert "--stroke 9999" in lines[0] and "pick a number from 1 to" in lines[0]
    code, stdout, err = run(capsys, "plot", dots, "-o", tmp_path / "bad.gif")
    assert code != 0 and len(err.strip().splitlines()) == 1 and "FILE.png" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dots.png", "figs"]  # nothing else written
