"""The studio's motion design page (Kirecci's MOTDES): a ``doodlecam motion`` design, edited
as tables in the page, solved and checked here by doodlecam.motion.design on every edit."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from doodlecam.errors import InputError

try:  # Python 3.11+
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

PLOT_SAMPLES = 600


def designs(folders: tuple[Path, ...]) -> list[str]:
    """Motion designs (TOML files with a [motion] table) in the folders and their samples/motion/."""
    out = []
    for f in folders:
        for p in sorted([*f.glob("*.toml"), *f.glob("samples/motion/*.toml")]):
            try:
                if "[motion]" in p.read_text(encoding="utf-8", errors="replace"):
                    out.append(str(p.relative_to(folders[0])) if p.is_relative_to(folders[0]) else str(p))
            except OSError:
                continue
    return out


def read(path: Path) -> dict:
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({e}); check the file") from None
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: not valid TOML ({e})") from None


def _finite(a: np.ndarray) -> list:
    """Values for JSON: infinite jerk (a law's step in acceleration) as null."""
    return [None if not math.isfinite(v) else round(float(v), 9) for v in a]


def solve(doc: Any, source: str = "design") -> dict:
    """Solve and check a design given as its parsed TOML document (what the page edits)."""
    from doodlecam.motion import laws
    from doodlecam.motion.design import check, parse_design, solve_design

    if not isinstance(doc, dict):
        raise InputError("the design must be a JSON object (the TOML file's tables)")
    traj = solve_design(parse_design(doc, source))
    rep = check(traj)
    t, axes = traj.sample(PLOT_SAMPLES)
    segments = [{"axis": a.name, "number": s.number, "where": s.where, "t0": s.t0, "t1": s.t1, "law": s.spec.law,
                 "findings": sorted({f.kind for f in rep.findings if f.where == s.where})}
                for a in traj.axes for s in a.segments]
    return {"t": _finite(t), "axes": {n: [_finite(v[k]) for k in range(4)] for n, v in axes.items()},
            "units": {a.name: a.unit for a in traj.axes},  # mm, or deg / rad for an axis that turns (Θ)
            "segments": segments, "findings": [{"kind": f.kind, "where": f.where, "t": f.t, "message": f.message}
                                               for f in rep.findings],
            "laws": sorted([*laws.LAWS, "polynomial", "cubic-spline"])}


def table_csv(doc: Any, source: str = "design") -> bytes:
    """The MOTDES table (doodlecam.motion.export) of a design."""
    from doodlecam.motion.design import parse_design, solve_design
    from doodlecam.motion.export import table_csv as csv

    if not isinstance(doc, dict):
        raise InputError("the design must be a JSON object (the TOML file's tables)")
    return csv(solve_design(parse_design(doc, source)))
