"""A big picture converted with every option at its default keeps its own default tolerances
(issue 27: a 3000 x 2200 drawing once ended "the pen strays up to 0.112 mm off the curve between
velocity samples, over the path tolerance of 0.1 mm; nothing written"). The real command, in a
subprocess, from a folder holding only the picture: no -o, no profile, no option."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from conftest import save
from lineart import big_drawing


def test_a_big_line_drawing_converts_with_the_defaults(tmp_path):
    save(tmp_path, "big.png", big_drawing(seed=1, shape=(2200, 3000)))
    r = subprocess.run([sys.executable, "-m", "doodlecam", "convert", "big.png", "--json"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=600, env=dict(os.environ, PYTHONWARNINGS="ignore"))
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["big.gcode", "big.plc", "big.svg"]
    assert s["path_tolerance_mm"] == 0.1  # the default guarantee was on ...
    assert s["max_between_samples_mm"] <= s["path_tolerance_mm"]  # ... and kept
    assert s["max_fit_error_mm"] <= 0.1 and s["worst_acceleration_ratio"] <= 1 and s["worst_velocity_ratio"] <= 1
    # the picture is big enough to matter: many strokes, and the path tolerance's re-plans were needed
    assert s["strokes"] > 400 and s["strokes_replanned"] > 20, (s["strokes"], s["strokes_replanned"])
