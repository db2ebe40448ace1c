"""Plots of one planned stroke: the figures of the DoodleBot report (2.4.6).

One figure per stroke, eight panels:

* the path with its control polygon and the positions the PLC reaches (Fig. 2.4.1);
* the path-velocity profile sqrt(b(u)) = u-dot against u, under the ceiling
  the velocity limits alone allow (Fig. 2.4.4, top);
* each actuator's position against time, planned and executed (Fig. 2.4.2);
* actuator velocities and accelerations against time, planned and executed,
  with the limits as dashed lines (Fig. 2.4.5);
* the path derivatives q'(u), q''(u) the planner works with (Fig. 2.4.3);
* the drift: distance between where the PLC is and where the plan puts the
  pen, at every sample instant and in between (the report's footnote).

"Planned" is the time-optimal profile on its own clock. "Executed" is what
the PLC does with the velocity samples: it ramps linearly from one target to
the next every dT, so velocity is piecewise linear, acceleration piecewise
constant and position piecewise quadratic. A stroke slowed to whole sample
periods runs at ``time_scale`` of the plan's speed; its position panels and
the drift compare against the plan slowed the same way (what the samples track).

Actuator quantities come from the machine's kinematics plugin, so a five-bar
arm is plotted in crank angles (rad) and an XY plotter in mm. matplotlib is
imported only here, with the Agg backend (no display needed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from doodlecam.atomic import replace_all
from doodlecam.errors import InputError, OutputError
from doodlecam.model import Job
from doodlecam.plan.follow import distance_to_stretch, executed_points

FORMATS = (".png", ".svg", ".pdf")
DENSE = 1500  # points per planned curve
PER_PERIOD = 16  # points per sample period on executed curves


def _legend(ax, rows: int, fontsize: float = 8, ncol: int = 2) -> None:
    """A legend in a band above the data: the y range grows by the legend's height,
    so the legend never covers a curve (loc="best" cannot avoid dense data)."""
    handles, _ = ax.get_legend_handles_labels()
    n_rows = -(-len(handles) // ncol) if rows <= 0 else rows
    lo, hi = ax.get_ylim()
    band = 0.075 * n_rows + 0.04  # share of the axes height the legend takes
    ax.set_ylim(lo, hi + (hi - lo) * band / (1 - band))
    ax.legend(fontsize=fontsize, loc="upper center", ncol=ncol, frameon=False, borderaxespad=0.2,
              handlelength=1.6, columnspacing=1.2)


def pick_strokes(job: Job, requested: tuple[int, ...] | list[int] = ()) -> list[int]:
    """0-based indices for 1-based stroke numbers; default the longest stroke."""
    n = len(job.strokes)
    if n == 0:
        raise InputError(f"{job.source or 'the job'}: has no strokes to plot; try other tracer options or another picture")
    if not requested:
        return [int(np.argmax([s.spline.length for s in job.strokes]))]
    out: list[int] = []
    for k in requested:
        if not 1 <= k <= n:
            raise InputError(f"--stroke {k}: the job has {n} strokes; pick a number from 1 to {n} (default: the longest)")
        if k - 1 not in out:
            out.append(k - 1)
    return out


def output_paths(out: Path, indices: list[int]) -> list[Path]:
    """One file per stroke: ``out`` itself, or ``stem_strokeN.ext`` when several."""
    out = Path(out)
    if out.suffix.lower() not in FORMATS:
        raise OutputError(f"{out}: cannot tell the figure format; give -o FILE.png or FILE.svg (or .pdf)")
    if len(indices) == 1:
        return [out]
    return [out.with_name(f"{out.stem}_stroke{i + 1}{out.suffix}") for i in indices]


def _executed(samples):
    """Dense executed trajectory of one stroke's samples (the PLC's linear ramp).

    Returns (t, x, v, a) with t (K,), x, v, a (K, 2) in mm, mm/s, mm/s^2, and
    the sample instants (ts, xs).
    """
    dt = samples.delta_time
    v = np.vstack([np.zeros((1, 2)), samples.velocity])  # targets at 0, dT, ..., M dT
    xs = samples.integrate()
    m = len(v) - 1
    tau = np.linspace(0.0, dt, PER_PERIOD, endpoint=False)
    j = np.repeat(np.arange(m), PER_PERIOD)
    tt = np.tile(tau, m)
    acc = (v[1:] - v[:-1]) / dt  # constant over each period
    x = executed_points(samples, PER_PERIOD)[:, :-1].reshape(-1, 2)  # each period's start and inner points
    vel = v[j] + acc[j] * tt[:, None]
    t = j * dt + tt
    # close with the final instant (at rest, on the end point)
    t = np.append(t, m * dt)
    x = np.vstack([x, xs[-1]])
    vel = np.vstack([vel, v[-1]])
    a = np.vstack([acc[j], acc[-1:]])
    return t, x, vel, a, dt * np.arange(m + 1), xs


def _distance_to_curve(spline, x: np.ndarray, u0: np.ndarray, candidates: int = 33, iterations: int = 4) -> np.ndarray:
    """Distance (mm) from points x to the spline near u0 (where the plan puts
    the pen at the same time). The nearest point lies within 2 |x - q(u0)| of
    q(u0), so search that stretch of the curve (doodlecam.plan.follow)."""
    delta = np.linalg.norm(spline(u0) - x, axis=1)
    speed = np.maximum(np.linalg.norm(spline(u0, 1), axis=1), 1e-12)
    w = np.minimum(2.0 * delta / speed * 1.5 + 1e-9, 1.0)  # half-width in u, with slack for the speed changing
    return distance_to_stretch(spline, x, np.clip(u0 - w, 0.0, 1.0), np.clip(u0 + w, 0.0, 1.0), candidates, iterations)


def stroke_figure(job: Job, index: int, kinematics):
    """A matplotlib Figure with the report's plots for ``job.strokes[index]``."""
    from matplotlib.figure import Figure

    stroke = job.strokes[index]
    spline, prof = stroke.spline, stroke.profile
    if prof is None:
        raise InputError(f"stroke {index + 1} has no planned profile; plot a planned job")
    samples = job.samples[index] if index < len(job.samples) else None
    names = tuple(kinematics.actuator_names)
    unit = kinematics.actuator_units
    vmax, amax = (np.asarray(x, float) for x in kinematics.actuator_limits())
    pen_speed = getattr(getattr(job.machine, "pen", None), "max_speed", None)

    # planned, on the plan's own clock: a few points inside every grid interval,
    # so the steps of the bang-bang acceleration show where they are
    K = len(prof.t) - 1
    per = max(1, min(6, DENSE * 4 // max(K, 1)))
    if K * per > 20 * DENSE:  # a very fine grid: uniform time is plenty
        t = np.linspace(0.0, prof.duration, 20 * DENSE)
    else:
        frac = np.arange(per) / per
        t = np.append((prof.t[:-1, None] + frac * np.diff(prof.t)[:, None]).ravel(), prof.duration)
    u, ud, udd = prof.state_at(t)
    th, th1, th2 = kinematics.derivatives(spline(u), spline(u, 1), spline(u, 2))
    th_v = th1 * ud[:, None]
    th_a = th1 * udd[:, None] + th2 * (ud**2)[:, None]

    # the path-velocity profile and the ceiling of the velocity limits alone
    uu = np.linspace(0.0, 1.0, DENSE)
    _, g1, _ = kinematics.derivatives(spline(uu), spline(uu, 1), spline(uu, 2))
    with np.errstate(divide="ignore"):
        ceiling = np.min(vmax[None, :] / np.abs(g1), axis=1)
        if pen_speed:
            ceiling = np.minimum(ceiling, pen_speed / np.linalg.norm(spline(uu, 1), axis=1))

    # a fixed layout: constrained layout would double the rendering time
    fig = Figure(figsize=(13, 15))
    # left and wspace leave room for six-digit tick labels and their axis labels
    gs = fig.add_gridspec(4, 2, left=0.085, right=0.98, top=0.945, bottom=0.04, hspace=0.3, wspace=0.24)
    axs = np.array([[fig.add_subplot(gs[r, c]) for c in range(2)] for r in range(3)] + [[None, None]], dtype=object)
    deriv = gs[3, 0].subgridspec(2, 1, hspace=0.12)
    axs[3, 0] = fig.add_subplot(deriv[0])
    ax_dd = fig.add_subplot(deriv[1], sharex=axs[3, 0])
    axs[3, 1] = fig.add_subplot(gs[3, 1])
    colours = ("tab:blue", "tab:orange", "tab:green", "tab:red")

    # (a) the path, its control polygon, the positions reached
    ax = axs[0, 0]
    q = spline(uu)
    ax.plot(q[:, 0], q[:, 1], color="tab:blue", lw=1.8, label="spline")
    c = spline.control
    ax.plot(c[:, 0], c[:, 1], "o--", color="0.55", lw=0.8, ms=3.5, label=f"control points ({len(c)})")
    ax.plot(*spline.start, ">", color="tab:green", ms=8, label="start")
    if samples is not None:
        _, xe, *_ = _executed(samples)
        xs = samples.integrate()
        ax.plot(xe[:, 0], xe[:, 1], color="k", lw=0.6, label="executed")
        ax.plot(xs[:, 0], xs[:, 1], ".", color="k", ms=3, label=f"at samples (every {samples.delta_time * 1000:g} ms)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title="Path (Fig. 2.4.1)")
    ax.legend(fontsize=8, loc="best")

    # (b) sqrt(b(u)) against u
    ax = axs[0, 1]
    ax.plot(prof.u, np.sqrt(np.maximum(prof.b, 0.0)), color="tab:blue", lw=1.5, label=r"planned $\sqrt{b(u)} = \dot u$")
    finite = np.isfinite(ceiling)
    ax.plot(uu[finite], ceiling[finite], "--", color="0.4", lw=1, label="velocity-limit ceiling")
    top = np.sqrt(np.maximum(prof.b, 0)).max()
    ax.set_ylim(0, 1.25 * top if top > 0 else 1)
    ax.set(xlabel="u (path parameter)", ylabel=r"$\dot u$ (1/s)", title=f"Path-velocity profile (Fig. 2.4.4), {len(prof.u)} grid points")
    _legend(ax, 0)

    # executed, on the PLC's clock, mapped to actuators with the same kinematics
    ex = None
    if samples is not None:
        te, xe, ve, ae, ts, xs = _executed(samples)
        ex_th, ex_v, ex_a = kinematics.derivatives(xe, ve, ae)
        scale = samples.time_scale
        ur, _, _ = prof.state_at(scale * te)  # the plan slowed as the samples are
        ref = spline(ur)
        ref[-1] = spline.end
        ref_th = kinematics.inverse(ref)
        ex = (te, ex_th, ex_v, ex_a, ts, xs, ref, ref_th, scale)

    # (c, d) actuator positions
    for i in range(min(2, len(names))):
        ax = axs[1, i]
        if ex is None:
            ax.plot(t, th[:, i], color=colours[i], lw=1.8, label="planned")
        else:
            te, ex_th, _, _, ts, _, _, ref_th, scale = ex
            lbl = "planned" if scale > 1 - 1e-9 else f"planned (slowed to {scale:.3f}x, as executed)"
            ax.plot(te, ref_th[:, i], color=colours[i], lw=1.8, label=lbl)
            ax.plot(te, ex_th[:, i], color="k", lw=0.7, label="executed (PLC ramp)")
            k = np.searchsorted(te, ts).clip(0, len(te) - 1)
            ax.plot(ts, ex_th[k, i], ".", color="k", ms=3)
        ax.set(xlabel="t (s)", ylabel=f"{names[i]} ({unit})", title=f"{names[i]} position (Fig. 2.4.2)")
        _legend(ax, 0)

    # (e, f) actuator velocities and accelerations, limits dashed
    for col, (what, plan_y, lim, u_s) in enumerate((("velocity", th_v, vmax, f"{unit}/s"),
                                                     ("acceleration", th_a, amax, f"{unit}/s²"))):
        ax = axs[2, col]
        for i in range(len(names)):
            ax.plot(t, plan_y[:, i], color=colours[i], lw=1.6 if K < 500 else 0.8, label=f"{names[i]} planned (time-optimal)")
            if ex is not None:
                y = ex[2][:, i] if col == 0 else ex[3][:, i]
                ax.plot(ex[0], y, color=colours[i], lw=0.8, alpha=0.9, ls=(0, (1, 1)), label=f"{names[i]} executed",
                        drawstyle="steps-post" if col == 1 else "default")
            for sign in (1, -1):
                ax.axhline(sign * lim[i], color=colours[i], ls="--", lw=0.9,
                           label=f"{names[i]} limit ±{lim[i]:g}" if sign > 0 else None)
        ax.set(xlabel="t (s)", ylabel=f"{what} ({u_s})", title=f"Actuator {what} (Fig. 2.4.5)")
        _legend(ax, 0, fontsize=7, ncol=len(names))

    # (g) path derivatives along u: q' on top, q'' below
    ax = axs[3, 0]
    d1, d2 = spline(uu, 1), spline(uu, 2)
    for i, axis in enumerate("xy"):
        ax.plot(uu, d1[:, i], color=colours[i], lw=1.3, label=f"{axis}'(u)")
        ax_dd.plot(uu, d2[:, i], color=colours[i], lw=0.9, label=f"{axis}''(u)")
    ax.set(ylabel="q'(u) (mm)", title="Path derivatives (Fig. 2.4.3)")
    ax.tick_params(labelbottom=False)
    ax_dd.set(xlabel="u", ylabel="q''(u) (mm)")
    _legend(ax, 1)
    _legend(ax_dd, 1)
    fig.align_ylabels([ax, ax_dd])

    # (h) drift: at sample instants from the curve point the samples track;
    # in between, from the nearest point of the stretch being drawn
    ax = axs[3, 1]
    if ex is None:
        ax.text(0.5, 0.5, "no velocity samples in this job", ha="center", va="center", transform=ax.transAxes)
        drift_txt = ""
    else:
        te, _, _, _, ts, xs, ref, _, _ = ex
        _, xe, *_ = _executed(samples)
        aim_u = getattr(samples, "sample_u", None)
        if aim_u is not None and len(aim_u) == len(ts):
            # the sampler says which curve point each instant aims at (it may
            # run a little ahead of or behind the plan, along the path)
            u0, aimed, what = np.interp(te, ts, aim_u), spline(np.asarray(aim_u)), "from its aim point at samples"
        else:
            k = np.searchsorted(te, ts).clip(0, len(te) - 1)
            u0, aimed, what = prof.state_at(samples.time_scale * te)[0], ref[k], "from the plan at samples"
        off_curve = _distance_to_curve(spline, xe, u0)
        at = np.linalg.norm(xs - aimed, axis=1)
        ax.plot(te, off_curve * 1000, color="0.5", lw=0.8, label=f"from the curve (max {off_curve.max() * 1000:.1f} µm)")
        ax.plot(ts, at * 1000, ".", color="k", ms=4, label=f"{what} (max {at.max() * 1000:.1f} µm)")
        tol = getattr(job.machine, "tolerance", None)
        if tol:
            ax.axhline(tol * 1000, color="tab:red", ls="--", lw=0.9, label=f"fit tolerance {tol:g} mm")
        end_err = float(np.linalg.norm(xs[-1] - spline.end))
        ax.set(xlabel="t (s)", ylabel="distance (µm)", title=f"Executed path: drift (end point off by {end_err * 1000:.2f} µm)")
        ax.set_ylim(bottom=0)
        _legend(ax, 0, ncol=1)
        drift_txt = f", {len(samples.velocity)} samples of {samples.delta_time * 1000:g} ms"
        if samples.time_scale < 1 - 1e-9:
            drift_txt += f" (executed at {samples.time_scale:.3f}x plan speed: whole periods)"

    fig.suptitle(f"{Path(job.source).name or 'job'}: stroke {index + 1} of {len(job.strokes)} on '{job.machine.name}' — "
                 f"{spline.length:.1f} mm, {len(spline.control)} control points, planned {prof.duration:.3f} s{drift_txt}",
                 fontsize=11, y=0.975)
    return fig


def write_figures(figures, paths: list[Path]) -> list[Path]:
    """Save each figure atomically: temp files first, renamed only when all are written."""
    try:
        return replace_all(
            (final, lambda f, fig=fig, final=final: fig.savefig(
                f, format=final.suffix.lower()[1:], dpi=110,
                metadata={"Date": None} if final.suffix.lower() == ".svg" else None))
            for fig, final in zip(figures, paths))
    except OSError as e:
        raise OutputError(f"{paths[0].parent}: cannot write the figure ({e.strerror}); check the path and permissions") from None


def plot_job(job: Job, out: Path, strokes=(), kinematics=None, plugin_dirs=()) -> list[tuple[int, Path]]:
    """Draw the chosen strokes (1-based; default the longest) of a planned job
    into ``out`` (one file per stroke). Returns [(0-based index, path)]."""
    if kinematics is None:
        from doodlecam.registry import kinematics_for

        kinematics = kinematics_for(job.machine, plugin_dirs)
    indices = pick_strokes(job, tuple(strokes))
    paths = output_paths(Path(out), indices)
    figs = [stroke_figure(job, i, kinematics) for i in indices]
    write_figures(figs, paths)
    return list(zip(indices, paths))
