"""`doodlecam motion` and `doodlecam learn` end to end, user errors included."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from doodlecam.cli import main
from doodlecam.motion.export import read_table
from doodlecam.motion.ilc import fir_coefficients, learn_step

ROOT = Path(__file__).resolve().parent.parent
FUSE = ROOT / "samples" / "motion" / "fuse.toml"


def run(*args):
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    return subprocess.run([sys.executable, "-m", "doodlecam", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=300)


@pytest.fixture(scope="module")
def fuse_out(tmp_path_factory):
    out = tmp_path_factory.mktemp("motion")
    r = run("motion", FUSE, "-o", out, "--split", "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout)


def test_motion_writes_the_motdes_table_and_a_plot(fuse_out):
    out, s = fuse_out
    assert sorted(p.name for p in out.iterdir()) == ["fuse.csv", "fuse.png", "fuse_x.csv", "fuse_y.csv"]
    header, rows = read_table(out / "fuse.csv")
    assert header == ["t"] + [f"{a}_{c}" for a in "xy" for c in ("pos", "vel", "acc", "jerk")]
    assert rows.shape == (300, 9)  # the thesis's 300 points
    assert rows[0, 0] == 0.0 and rows[-1, 0] == pytest.approx(0.666)
    assert rows[-1, 1] == pytest.approx(0.0, abs=1e-9) and rows[:, 1].max() == pytest.approx(150.0, abs=1e-6)
    xh, xrows = read_table(out / "fuse_x.csv")
    assert xh == ["pos", "vel", "acc", "jerk"] and np.allclose(xrows, rows[:, 1:5])
    assert (out / "fuse.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the summary: the doodlebot cannot run Table 5.1 in 0.666 s, and says how slowly it can
    assert s["machine"] == "doodlebot" and not s["ok"]
    assert {f["kind"] for f in s["findings"]} == {"limit"}
    assert 10 < s["fastest_cycle_s"] < 11


def test_strict_fails_until_the_design_is_slow_enough(fuse_out, tmp_path):
    _, s = fuse_out
    r = run("motion", FUSE, "-o", tmp_path, "--no-plot", "--strict")
    assert r.returncode == 1 and "check(s) failed" in r.stdout
    slow = s["fastest_cycle_s"] * 1.001
    assert main(["motion", str(FUSE), "-o", str(tmp_path), "--no-plot", "--strict", "--cycle-time", str(slow)]) == 0


def test_samples_option_and_no_machine(tmp_path, capsys):
    assert main(["motion", str(FUSE), "-o", str(tmp_path), "--samples", "51", "--no-machine", "--no-plot"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fuse.csv"]
    assert read_table(tmp_path / "fuse.csv")[1].shape == (51, 9)
    assert "all pass" in capsys.readouterr().out


def test_motion_errors_are_one_line_and_write_nothing(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('[motion]\ninput = "time"\n[[axis.x.point]]\nt = 0\npos = 0\n[[axis.x.point]]\nt = 0\npos = 1\n')
    out = tmp_path / "out"
    r = run("motion", bad, "-o", out)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "bad.toml: axis x: point 2 at t = 0 s does not come after point 1" in r.stderr
    assert "Traceback" not in r.stderr and not out.exists()
    r = run("motion", tmp_path / "missing.toml", "-o", out)
    assert r.returncode == 2 and "no such design file" in r.stderr


def response_of(r, lag=3, gain=0.97):
    """A stand-in for a recorded cycle: the reference delayed a few samples and a little short."""
    return gain * np.concatenate([np.full(lag, r[0]), r[:-lag]])


def test_learn_writes_the_next_command(fuse_out, tmp_path, capsys):
    out, _ = fuse_out
    header, rows = read_table(out / "fuse.csv")
    t, r = rows[:, 0], rows[:, [1, 5]]
    y = np.column_stack([response_of(r[:, 0]), response_of(r[:, 1])])
    resp = tmp_path / "run1.csv"
    resp.write_text("t,x_pos,y_pos\n" + "\n".join(",".join(f"{v:.12g}" for v in row) for row in np.column_stack([t, y])))
    nxt = tmp_path / "cmd2.csv"
    assert main(["learn", str(out / "fuse.csv"), "--response", str(resp), "-o", str(nxt), "--cutoff", "300"]) == 0
    h2, u2 = read_table(nxt)
    assert h2 == ["t", "x_pos", "y_pos"] and np.allclose(u2[:, 0], t)
    c = fir_coefficients(300 * (t[1] - t[0]))
    for i in range(2):
        assert np.allclose(u2[:, 1 + i], learn_step(r[:, i], r[:, i], y[:, i], 0.3, c), atol=1e-8)
    # the second cycle: the command it ran with is given
    plain = tmp_path / "cmd3.csv"
    assert main(["learn", str(out / "fuse.csv"), "-r", str(resp), "-c", str(nxt), "-o", str(plain), "--no-filter",
                 "--gain", "0.5"]) == 0
    u3 = read_table(plain)[1]
    assert np.allclose(u3[:, 1:], u2[:, 1:] + 0.5 * (r - y), atol=1e-8)
    assert "wrote" in capsys.readouterr().out


def test_learn_errors(fuse_out, tmp_path):
    out, _ = fuse_out
    short = tmp_path / "short.csv"
    short.write_text("t,x_pos,y_pos\n0,0,0\n0.1,1,1\n0.2,2,2\n")
    r = run("learn", out / "fuse.csv", "--response", short, "-o", tmp_path / "n.csv")
    assert r.returncode == 2 and "3 rows but the reference has 300" in r.stderr and not (tmp_path / "n.csv").exists()
    r = run("learn", out / "fuse.csv", "--response", short, "-o", tmp_path / "n.csv", "--gain", "1.5")
    assert r.returncode == 2 and "between 0 and 1" in r.stderr
    r = run("learn", out / "fuse.csv", "--simulate", "3", "--cutoff", "5000")
    assert r.returncode == 2 and "Nyquist" in r.stderr


def readme_demo_block() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("<!-- learn-demo -->")
    return text[start:text.index("<!-- /learn-demo -->")]


def test_readme_learning_demo_prints_what_the_readme_shows(tmp_path):
    # the README's two commands, as a user runs them; the README's printed lines must be the command's
    out = tmp_path / "out"
    r = run("motion", FUSE, "--cycle-time", "10.6", "--strict", "-o", out)
    assert r.returncode == 0, r.stderr
    r = run("learn", out / "fuse.csv", "--simulate", "16")
    assert r.returncode == 0, r.stderr
    shown = [ln.strip() for ln in readme_demo_block().splitlines() if ln.strip() and not ln.startswith(("<!--", "```", "$"))]
    printed = [ln.strip() for ln in r.stdout.splitlines()]
    assert len(shown) > 10 and all(ln in printed for ln in shown), [ln for ln in shown if ln not in printed]
    r = run("learn", out / "fuse.csv", "--simulate", "16", "--json")
    res = json.loads(r.stdout)
    assert res["servo"]["tick_s"] == pytest.approx(416e-6)
    for col in ("x_pos", "y_pos"):
        c = res["columns"][col]
        assert 7 <= c["plain_saturates_at"] <= 10 and c["filtered_saturates_at"] is None and c["thesis_saturates_at"] is None
        assert c["filtered"][-1]["rms_error"] < 0.25 * c["filtered"][0]["rms_error"]


POWERS_31 = """[motion]
input = "time"
continuity = 1
[[axis.x.point]]
t = 0
pos = 0
vel = 0
acc = 0
[[axis.x.point]]
t = 1
pos = 10
vel = 0
acc = 0
[[axis.x.segment]]
powers = [0, 1, 2, 2.1, 2.2, 2.3]
"""


def test_learn_reads_every_table_motion_writes(tmp_path, capsys):
    # real powers below 3 make the jerk infinite at the segment start: written as inf, documented, read back
    design = tmp_path / "p.toml"
    design.write_text(POWERS_31)
    assert main(["motion", str(design), "-o", str(tmp_path), "--no-plot"]) == 0
    assert "|jerk| infinite" in capsys.readouterr().out
    header, rows = read_table(tmp_path / "p.csv", infinite=True)
    assert rows[0, header.index("x_jerk")] == np.inf and np.isfinite(rows[1:]).all()
    assert main(["learn", str(tmp_path / "p.csv"), "--simulate", "1", "--json"]) == 0
    assert "x_pos" in json.loads(capsys.readouterr().out)["columns"]
    r = run("learn", tmp_path / "p.csv", "--simulate", "1", "--column", "x_jerk")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "column 'x_jerk' row 2 is inf" in r.stderr
    # any --samples, at any cycle time: the 10-digit times are evenly spaced to their precision
    for n, cycle in ((3000, "10.6"), (30000, "10.6"), (2, "0.5")):
        assert main(["motion", str(FUSE), "-o", str(tmp_path), "--no-plot", "--no-machine", "--samples", str(n),
                     "--cycle-time", cycle]) == 0
        capsys.readouterr()
        resp = tmp_path / "resp.csv"
        header, rows = read_table(tmp_path / "fuse.csv")
        resp.write_text(",".join(header) + "\n" + "\n".join(",".join(f"{v:.10g}" for v in row) for row in rows) + "\n")
        assert main(["learn", str(tmp_path / "fuse.csv"), "-r", str(resp), "-o", str(tmp_path / "next.csv"),
                     "--no-filter"]) == 0
        assert "rms error 0," in capsys.readouterr().out


def test_cycle_time_must_be_finite():
    for bad in ("inf", "nan", "0", "-1"):
        r = run("motion", FUSE, "--cycle-time", bad, "--no-plot", "-o", "/tmp/never-written")
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert "cycle time must be a positive, finite number of seconds" in r.stderr


def test_rotation_axis_is_in_degrees_or_radians(tmp_path, capsys):
    design = tmp_path / "rot.toml"
    design.write_text('[motion]\ninput = "time"\n'
                      '[axis.theta]\npoint = [{t = 0, pos = 0, vel = 0, acc = 0}, {t = 1, pos = 90, vel = 0, acc = 0}]\n'
                      '[axis.w]\nunit = "rad"\npoint = [{t = 0, pos = 0}, {t = 1, pos = 1}]\n'
                      '[axis.x]\npoint = [{t = 0, pos = 0}, {t = 1, pos = 10}]\n')
    assert main(["motion", str(design), "-o", str(tmp_path), "--no-plot"]) == 0
    out = capsys.readouterr().out
    assert "axis theta (deg): peak |vel| 168.8 deg/s, |acc| 519.6 deg/s²" in out  # 1.875 · 90, 5.7735 · 90
    assert "axis w (rad): peak |vel| 1 rad/s" in out and "axis x (mm): peak |vel| 10 mm/s" in out
    design.write_text(design.read_text().replace('unit = "rad"', 'unit = "grad"'))
    r = run("motion", design, "-o", tmp_path, "--no-plot")
    assert r.returncode == 2 and "[axis.w] unit = 'grad': use \"mm\" for a linear axis" in r.stderr


def test_segment_times_shorten_each_segment_to_its_limit(tmp_path, capsys):
    from doodlecam.machine import load_machine
    from doodlecam.motion.design import _retimed, _within_limits, load_design, segment_times, solve_design

    assert main(["motion", str(FUSE), "--cycle-time", "10.6", "--segment-times", "-o", str(tmp_path), "--no-plot",
                 "--json"]) == 0
    st = json.loads(capsys.readouterr().out)["segment_times"]
    assert st["complete"] and st["retimed_cycle_s"] < 0.85 * st["design_cycle_s"]
    # read the machine's side back from the written table: within the doodlebot's 150 mm/s and 2000 mm/s² per axis
    header, rows = read_table(tmp_path / "fuse_retimed.csv")
    assert rows[-1, 0] == pytest.approx(st["retimed_cycle_s"])
    for axis in "xy":
        assert np.abs(rows[:, header.index(f"{axis}_vel")]).max() <= 150 * (1 + 1e-6)
        assert np.abs(rows[:, header.index(f"{axis}_acc")]).max() <= 2000 * (1 + 1e-6)
    # each moving segment is as short as it can be: 1 % shorter breaks a limit; dwells keep their time
    d = load_design(FUSE).scaled(10.6)
    machine = load_machine("doodlebot")
    got, retimed = segment_times(d, machine)
    assert [r["shortest_s"] for r in got] == pytest.approx([r["shortest_s"] for r in st["segments"]])
    for r in got:
        if r.get("note"):
            assert r["shortest_s"] == r["design_s"]
        else:
            assert not _within_limits(_retimed(retimed, r["segment"] - 1, 0.99 * r["shortest_s"]), machine, None, 401)
    assert solve_design(retimed).t1 == pytest.approx(st["retimed_cycle_s"])
    r = run("motion", FUSE, "--segment-times", "--no-machine", "-o", tmp_path, "--no-plot")
    assert r.returncode == 2 and "per-segment times need limits" in r.stderr
