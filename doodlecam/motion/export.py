"""The MOTDES table and plots (Kirecci §5.2.2).

MOTDES saved a design as "four columns of data corresponding to position,
velocity, acceleration and jerk values ... 300 points". ``table_csv`` writes
that for every axis side by side after a time column (header
``t,x_pos,x_vel,x_acc,x_jerk,y_pos,...``); ``axis_csv`` writes one axis in the
exact four-column form. ``plot_png`` draws the curves (and the X–Y path) with
matplotlib's Agg canvas, without touching pyplot's global state.
Every file is written to a temporary name and renamed into place.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from doodlecam.atomic import write_bytes
from doodlecam.errors import OutputError

COLUMNS = ("pos", "vel", "acc", "jerk")


def atomic_write(path: Path, data: bytes) -> Path:
    try:
        return write_bytes(Path(path), data)
    except OSError as err:
        raise OutputError(f"{path}: cannot write ({err.strerror}); check the folder and permissions") from None


def _fmt(a: np.ndarray) -> np.ndarray:
    return np.char.mod("%.10g", a)


def table(traj, n: int | None = None) -> tuple[list[str], np.ndarray]:
    """(header, rows): t then pos, vel, acc, jerk of every axis at n evenly spaced times."""
    t, axes = traj.sample(n)
    header = ["t"] + [f"{name}_{c}" for name in axes for c in COLUMNS]
    rows = np.column_stack([t] + [axes[name][k] for name in axes for k in range(4)])
    return header, rows


def table_csv(traj, n: int | None = None) -> bytes:
    header, rows = table(traj, n)
    lines = [",".join(header)] + [",".join(r) for r in _fmt(rows)]
    return ("\n".join(lines) + "\n").encode()


def axis_csv(traj, axis: str, n: int | None = None) -> bytes:
    """One axis as the thesis's four columns: position, velocity, acceleration, jerk."""
    t, axes = traj.sample(n)
    rows = _fmt(axes[axis].T)
    return ("\n".join([",".join(COLUMNS)] + [",".join(r) for r in rows]) + "\n").encode()


def read_table(path: Path, infinite: bool = False) -> tuple[list[str], np.ndarray]:
    """A CSV with one header line of column names and numeric rows.

    ``infinite``: accept ``inf`` / ``-inf`` (the jerk a real-power polynomial
    has at its segment's start, §3.6.2, is written so); the caller checks the
    columns it uses. ``nan`` is refused always."""
    from doodlecam.errors import InputError

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file; check the path") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({e}); check the file") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(lines) < 3:
        raise InputError(f"{path}: needs a header line and at least two rows of numbers")
    header = [h.strip() for h in lines[0].split(",")]
    try:
        data = np.loadtxt(io.StringIO("\n".join(lines[1:])), delimiter=",", ndmin=2)
    except ValueError as e:
        raise InputError(f"{path}: not a table of numbers ({e}); one header line, then comma-separated numbers") from None
    if data.shape[1] != len(header):
        raise InputError(f"{path}: {data.shape[1]} columns of numbers but {len(header)} names in the header; make them agree")
    bad = np.isnan(data) if infinite else ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(f"{path}: row {r + 2} column '{header[c]}' is {data[r, c]:g}, not a finite number; fix the table")
    return header, data


def plot_png(traj, report=None, n: int = 2000, dpi: int = 110) -> bytes:
    """PNG of position, velocity, acceleration and jerk against time, one
    column per axis, design points and segment joints marked; with x and y
    also the X–Y path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = [a.name for a in traj.axes]
    has_xy = "x" in names and "y" in names
    ncol = len(names) + (1 if has_xy else 0)
    fig = Figure(figsize=(4.2 * ncol, 9.0))
    FigureCanvasAgg(fig)
    t = np.linspace(traj.t0, traj.t1, n)
    for j, a in enumerate(traj.axes):
        units = a.units()
        f = a.evaluate(t)
        joints = [s.t1 for s in a.segments[:-1]]
        for k in range(4):
            ax = fig.add_subplot(4, ncol, k * ncol + j + 1)
            ax.plot(t, np.where(np.isfinite(f[k]), f[k], np.nan), lw=1.2)
            for tj in joints:
                ax.axvline(tj, color="0.85", lw=0.8, zorder=0)
            given = [(p.t, p.values[k]) for p in a.points if k in p.values]
            if given:
                ax.plot(*zip(*given), "o", ms=3.5, color="C3")
            ax.set_ylabel(f"{a.name} {COLUMNS[k]} ({units[k]})", fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
            if k == 0:
                ax.set_title(f"axis {a.name}", fontsize=9)
            if k == 3:
                ax.set_xlabel("t (s)", fontsize=8)
    if has_xy:
        ax = fig.add_subplot(2, ncol, ncol)  # the top half: a square-ish panel
        fx, fy = traj.axis("x").evaluate(t), traj.axis("y").evaluate(t)
        ax.plot(fx[0], fy[0], lw=1.2)
        px = traj.axis("x").points
        py = {p.index: p for p in traj.axis("y").points}
        pts = [(p.values[0], py[p.index].values[0]) for p in px if 0 in p.values and p.index in py and 0 in py[p.index].values]
        if pts and traj.design.input == "xy":  # rows pair x and y only in the X–Y form
            ax.plot(*zip(*pts), "o", ms=4, color="C3")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title("path (X–Y)", fontsize=9)
        ax.set_xlabel("x (mm)", fontsize=8)
        ax.set_ylabel("y (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    title = traj.design.name
    if report is not None:
        title += "  —  " + ("all checks pass" if report.ok else f"{len(report.findings)} finding(s)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()
