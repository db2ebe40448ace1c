"""Every Python block of docs/api.md runs, in order, as a user would run them (issue 16)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_api_examples_run(tmp_path, monkeypatch, capsys):
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 6
    (tmp_path / "samples").symlink_to(ROOT / "samples")
    monkeypatch.chdir(tmp_path)  # the examples write out/ here
    scope: dict = {}
    for block in blocks:
        exec(compile(block, "docs/api.md", "exec"), scope)
    out = capsys.readouterr().out
    assert (tmp_path / "out" / "camera.gcode").read_text().count("M5") > 1  # the post option took
    assert {"spiral.plc", "spiral.gcode", "spiral.svg", "spiral.png"} <= {p.name for p in (tmp_path / "out").iterdir()}
    # the spiral was planned 120 mm wide, within the limits
    import numpy as np

    from doodlecam.link.plc.packetfile import read_plc

    job = scope["spiral_job"]
    pts = np.concatenate([s.spline(np.linspace(0, 1, 2000)) for s in job.strokes])
    assert abs(np.ptp(pts[:, 0]) - 120.0) < 0.2 and job.meta["worst_acceleration_ratio"] <= 1 + 1e-9
    # the simulated PLC executed every command of the file
    _, commands = read_plc((tmp_path / "out" / "spiral.plc").read_bytes())
    assert scope["report"]["commands"] == len(commands) > 2
    assert f"{len(commands)} commands executed" in out
    assert "unknown postprocessor 'gcod' (did you mean 'gcode'?)" in out
