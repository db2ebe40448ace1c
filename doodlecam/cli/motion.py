"""``doodlecam motion`` and ``doodlecam learn``: the thesis's motion design
(MOTDES, Kirecci ch. 5) and iterative learning control (§7.2.3)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from doodlecam.cli import complete

from doodlecam.motion import MotionError


class ChecksFailed(MotionError):
    """--strict and a check failed: exit status 1, like a linter."""

    exit_code = 1


@click.command("motion")
@click.argument("design", type=click.Path(path_type=Path))
@click.option("-o", "--out", "outdir", type=click.Path(path_type=Path), default=Path("out"), show_default=True,
              help="Output folder for NAME.csv (the MOTDES table) and NAME.png.")
@click.option("-m", "--machine", shell_complete=complete.machines, help="Check workspace and actuator limits on this profile (default: the design's [motion] machine).")
@click.option("--no-machine", is_flag=True, help="Skip the workspace and actuator-limit check.")
@click.option("--samples", type=click.IntRange(min=2), help="Rows of the table (default: the design's, else 300).")
@click.option("--cycle-time", type=float, help="Run the design in this many seconds (times stretch, derivatives scale).")
@click.option("--split", is_flag=True, help="Also write NAME_AXIS.csv per axis: the thesis's four columns pos, vel, acc, jerk.")
@click.option("--no-plot", is_flag=True, help="Do not write the PNG.")
@click.option("--strict", is_flag=True, help="Exit with status 1 when a check fails (outputs are still written).")
@click.option("--segment-times", is_flag=True,
              help="Also find each segment's shortest time within every limit (dwells kept) and write NAME_retimed.csv.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def motion(design, outdir, machine, no_machine, samples, cycle_time, split, no_plot, strict, segment_times, as_json):
    """Design a multi-segment trajectory from DESIGN.toml (MOTDES).

    \b
    Solves each axis's segments (polynomials through design points, cam laws,
    arbitrary-power polynomials, cubic splines), checks tolerance envelopes,
    meandering and continuity, and, given a machine, its workspace and
    actuator limits through the machine's kinematics plugin. Writes the table
    of position, velocity, acceleration and jerk (300 rows by default) and a plot.
    Example:  doodlecam motion DESIGN.toml -o out/   (the format: docs/motion.md;
    examples in the source tree's samples/motion/)
    """
    from doodlecam.extras import require
    from doodlecam.motion.design import check, load_design, solve_design
    from doodlecam.motion.export import atomic_write, axis_csv, plot_png, table_csv

    if not no_plot:
        require("plot", "the motion plot (NAME.png)", "or --no-plot")
    d = load_design(design)
    if cycle_time is not None:
        d = d.scaled(cycle_time)
    if samples:
        from dataclasses import replace

        d = replace(d, samples=samples)
    mach = None
    spec = None if no_machine else (machine or d.machine)
    if spec:
        from doodlecam.machine import load_machine

        mach = load_machine(spec)
    traj = solve_design(d)
    rep = check(traj, mach)
    stem = d.name or design.stem
    outputs = [(outdir / f"{stem}.csv", table_csv(traj))]
    timing = None
    if segment_times:
        from doodlecam.motion.design import segment_times as shortest

        rows, retimed = shortest(d, mach)
        rtraj = solve_design(retimed)
        timing = {"segments": rows, "design_cycle_s": traj.t1 - traj.t0, "retimed_cycle_s": rtraj.t1 - rtraj.t0,
                  "complete": all(r["shortest_s"] is not None for r in rows)}
        outputs.append((outdir / f"{stem}_retimed.csv", table_csv(rtraj)))
    if split:
        outputs += [(outdir / f"{stem}_{a.name}.csv", axis_csv(traj, a.name)) for a in traj.axes]
    if not no_plot:
        outputs.append((outdir / f"{stem}.png", plot_png(traj, rep)))
    written = [str(atomic_write(p, data)) for p, data in outputs]  # all built before any is written

    summary = _summary(design, traj, rep, written)
    summary["segment_times"] = timing
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        _print_summary(summary)
    if strict and not rep.ok:
        raise ChecksFailed(f"{design}: {len(rep.findings)} check(s) failed (listed above); the outputs were written")


def _summary(path, traj, rep, written) -> dict:
    import numpy as np

    d = traj.design
    axes = []
    for a in traj.axes:
        segs = []
        for s in a.segments:
            f = s.evaluate(np.linspace(s.t0, s.t1, 801))
            segs.append({"segment": s.number, "points": [s.first_point, s.last_point], "t0": s.t0, "t1": s.t1,
                         "law": s.spec.law, "form": s.impl.describe(),
                         "peak_velocity": float(np.abs(f[1]).max()), "peak_acceleration": float(np.abs(f[2]).max())})
        axes.append({"axis": a.name, "unit": a.unit, "segments": segs, "peaks": rep.peaks[a.name]})
    return {
        "design": str(path), "name": d.name, "input": d.input, "continuity": d.continuity,
        "duration_s": traj.t1 - traj.t0, "samples": d.samples, "axes": axes,
        "machine": rep.machine, "actuators": rep.actuators, "fastest_cycle_s": rep.fastest_cycle,
        "product": rep.product, "drives": rep.drives,
        "findings": [{"kind": f.kind, "where": f.where, "t": f.t, "message": f.message} for f in rep.findings],
        "ok": rep.ok, "outputs": written,
    }


def _print_summary(s: dict) -> None:
    names = ("position", "velocity", "acceleration", "jerk")
    click.echo(f"{s['design']}: '{s['name']}', {len(s['axes'])} axes, {s['duration_s']:.4g} s "
               f"(input {s['input']}, continuous to {names[s['continuity']]})")
    for a in s["axes"]:
        p = a["peaks"]
        jerk = "infinite" if p["jerk_infinite"] else f"{p['jerk']:.4g}"
        u = a["unit"]
        click.echo(f"  axis {a['axis']} ({u}): peak |vel| {p['velocity']:.4g} {u}/s, |acc| {p['acceleration']:.4g} {u}/s², "
                   f"|jerk| {jerk}" + ("" if jerk == "infinite" else f" {u}/s³"))
        for g in a["segments"]:
            click.echo(f"    {g['segment']:>2}  {g['t0']:.4f}-{g['t1']:.4f} s  {g['form']:<40} "
                       f"|vel| {g['peak_velocity']:<10.4g} |acc| {g['peak_acceleration']:.4g}")
    if s["machine"]:
        click.echo(f"  machine {s['machine']}:")
        for act in s["actuators"]:
            click.echo(f"    actuator {act['name']}: velocity {act['peak_velocity']:.4g} of {act['velocity_limit']:g} "
                       f"({act['velocity_ratio']:.3g}x), acceleration {act['peak_acceleration']:.4g} of "
                       f"{act['acceleration_limit']:g} ({act['acceleration_ratio']:.3g}x)")
        if s["fastest_cycle_s"]:
            click.echo(f"    fastest run within the limits: {s['fastest_cycle_s']:.4g} s (--cycle-time)")
    if s["product"]:
        p = s["product"]
        click.echo(f"  product: peak acceleration {p['peak']:.4g} of {p['limit']:g} mm/s² at t = {p['t']:.4g} s ({p['where']})")
    for dr in s["drives"]:
        click.echo(f"  drive {dr['axis']} (eq. 4.1): peak torque {dr['peak_torque']:.4g} of {dr['max_torque']:g} N·m "
                   f"({dr['ratio']:.3g}x) at t = {dr['t']:.4g} s ({dr['where']})")
    if s["ok"]:
        click.echo("  checks: envelopes, meandering, continuity" + (", workspace and limits" if s["machine"] else "") + " all pass")
    else:
        click.echo(f"  {len(s['findings'])} check(s) failed:")
        for f in s["findings"]:
            click.echo(f"    {f['where']}: {f['message']}")
    if s.get("segment_times"):
        st = s["segment_times"]
        click.echo("  shortest segment times within every limit (one after another; dwells keep their time):")
        for r in st["segments"]:
            best = f"{r['shortest_s']:.4g} s" if r["shortest_s"] is not None else "none"
            click.echo(f"    {r['segment']:>2}  points {r['points'][0]}-{r['points'][1]}  {r['design_s']:.4g} s -> {best}"
                       + (f"  ({r['note']})" if r.get("note") else ""))
        click.echo(f"    cycle {st['design_cycle_s']:.4g} s -> {st['retimed_cycle_s']:.4g} s"
                   + ("" if st["complete"] else " (some segments cannot keep the limits; see above)"))
    click.echo("  wrote " + ", ".join(s["outputs"]))


# ------------------------------------------------------------------ learn


def _columns(ref_header: list[str], wanted: tuple[str, ...], ref_path: Path) -> list[str]:
    from doodlecam.errors import InputError

    if wanted:
        missing = [c for c in wanted if c not in ref_header]
        if missing:
            raise InputError(f"{ref_path}: no column '{missing[0]}' (columns: {', '.join(ref_header)})")
        return list(wanted)
    pos = [c for c in ref_header if c.endswith("_pos")]
    cols = pos or [c for c in ref_header if c != "t"]
    if not cols:
        raise InputError(f"{ref_path}: no data columns besides 't'; give one column per axis")
    return cols


def _pick(path: Path, header: list[str], data, cols: list[str], t_ref) -> "object":
    import numpy as np

    from doodlecam.errors import InputError

    if "t" not in header:
        raise InputError(f"{path}: no 't' column; the first line must name the columns, one of them t (s)")
    if len(data) != len(t_ref):
        raise InputError(f"{path}: {len(data)} rows but the reference has {len(t_ref)}; record one full cycle at the reference's times")
    t = data[:, header.index("t")]
    if np.abs(t - t_ref).max() > 1e-6 * max(1.0, float(np.abs(t_ref).max())):
        raise InputError(f"{path}: its times differ from the reference's; sample at the reference's times")
    for c in cols:
        if c not in header:
            raise InputError(f"{path}: no column '{c}' (columns: {', '.join(header)}); name it as in the reference")
    return _finite(path, data, header, cols)


def _finite(path: Path, data, header: list[str], cols: list[str]):
    """The columns ``cols`` of a table, refusing an infinite value in any of them
    (an infinite jerk column is fine as long as it is not learned from)."""
    import numpy as np

    from doodlecam.errors import InputError

    out = data[:, [header.index(c) for c in cols]]
    if not np.all(np.isfinite(out)):
        r, c = np.argwhere(~np.isfinite(out))[0]
        raise InputError(f"{path}: column '{cols[c]}' row {r + 2} is {out[r, c]:g}; learn from finite columns "
                         "(positions, --column NAME)")
    return out


@click.command("learn")
@click.argument("reference", type=click.Path(path_type=Path))
@click.option("-r", "--response", type=click.Path(path_type=Path), help="Recorded response y_n of the last cycle (CSV).")
@click.option("-c", "--command", "command", type=click.Path(path_type=Path),
              help="Command u_n that produced it (CSV; default: the reference, i.e. the first cycle).")
@click.option("-o", "--out", "out", type=click.Path(path_type=Path), help="Where to write the next command u_{n+1} (CSV).")
@click.option("--gain", type=float, default=0.3, show_default=True, help="Learning gain λ, 0 < λ < 1 (the thesis: 0.3).")
@click.option("--cutoff", type=float, help="FIR filter cut-off, rad/s (default: 1 rad per sample, i.e. 1/ΔT; with --simulate "
              "also at most 3/4 of the simulated servo's resonance).")
@click.option("--no-filter", is_flag=True, help="Plain learning, eq. 7.5 (the command roughens; see --simulate).")
@click.option("--filter-mode", type=click.Choice(["correction", "command"]), default="correction", show_default=True,
              help="Filter what learning added (correction) or the whole command as eq. 7.12 prints it (command).")
@click.option("--column", "columns", multiple=True, metavar="NAME",
              help="Column to learn (repeatable; default: every *_pos column, else every column but t).")
@click.option("--simulate", type=click.IntRange(min=1), metavar="CYCLES",
              help="Instead: run this many cycles on a simulated servo axis, with and without the filter, and print the errors.")
@click.option("--json", "as_json", is_flag=True, help="Print the --simulate results as JSON.")
def learn(reference, response, command, out, gain, cutoff, no_filter, filter_mode, columns, simulate, as_json):
    """Iterative learning control: the next command from the last response.

    \b
    u_{n+1} = F(u_n + λ (r − y_n))   (Kirecci eq. 7.12)
    REFERENCE is the designed trajectory r (e.g. the table 'doodlecam motion'
    writes); every CSV has a header line with a 't' column (s). F is the
    thesis's windowed FIR low-pass filter (eq. 7.6-7.11).
    Examples:
      doodlecam learn out/fuse.csv --response run1.csv -o cmd2.csv
      doodlecam learn out/fuse.csv --response run2.csv --command cmd2.csv -o cmd3.csv
      doodlecam learn out/fuse.csv --simulate 20
    """
    import numpy as np

    from doodlecam.errors import InputError
    from doodlecam.motion import MotionError
    from doodlecam.motion.export import atomic_write, read_table
    from doodlecam.motion.ilc import fir_coefficients, learn_step

    if not 0 < gain < 1:
        raise MotionError(f"--gain {gain:g} must lie between 0 and 1 (the thesis uses 0.3)")
    header, data = read_table(reference, infinite=True)
    if "t" not in header:
        raise InputError(f"{reference}: no 't' column; the first line must name the columns, one of them t (s)")
    t = data[:, header.index("t")]
    if not np.all(np.isfinite(t)) or not np.all(np.diff(t) > 0):
        raise InputError(f"{reference}: times in column t must be finite and increase")
    dt = (float(t[-1]) - float(t[0])) / (len(t) - 1)
    # the tables carry 10 significant digits: each time is off by up to 5e-10 of its size
    if np.abs(np.diff(t) - dt).max() > 1e-6 * dt + 1e-9 * float(np.abs(t).max()):
        raise InputError(f"{reference}: samples are not evenly spaced in time; the FIR filter needs a fixed ΔT")
    cols = _columns(header, columns, reference)
    r = _finite(reference, data, header, cols)
    if cutoff is not None and not cutoff > 0:
        raise MotionError(f"--cutoff {cutoff:g} rad/s must be positive")
    cut = cutoff if cutoff is not None else 1.0 / dt
    if simulate and cutoff is None:
        from doodlecam.motion.servo import ServoAxis

        # learning pumps the servo's resonance; the filter must stop below it (the simulated servo's is known)
        cut = min(cut, 0.75 * 2 * np.pi * ServoAxis.bandwidth)
    if cut * dt >= np.pi:
        raise MotionError(f"--cutoff {cut:g} rad/s is above the Nyquist frequency π/ΔT = {np.pi / dt:.4g} rad/s; lower it")
    if simulate:
        if response or command or out:
            raise click.UsageError("--simulate runs the simulated servo; it takes no --response, --command or -o")
        _simulate(t, r, cols, simulate, gain, cut, filter_mode, as_json)
        return
    if response is None or out is None:
        raise click.UsageError("give --response (the recorded cycle) and -o (the next command), or --simulate CYCLES")
    y = _pick(response, *read_table(response, infinite=True), cols, t)
    u = r if command is None else _pick(command, *read_table(command, infinite=True), cols, t)
    coeffs = None if no_filter else fir_coefficients(cut * dt)
    nxt = np.column_stack([learn_step(u[:, i], r[:, i], y[:, i], gain, coeffs, mode=filter_mode) for i in range(len(cols))])
    lines = [",".join(["t"] + cols)] + [",".join(f"{v:.10g}" for v in row) for row in np.column_stack([t, nxt])]
    atomic_write(out, ("\n".join(lines) + "\n").encode())
    err = r - y
    m = "none" if coeffs is None else f"{len(coeffs)} taps, cut-off {cut:.4g} rad/s ({filter_mode})"
    click.echo(f"{response}: rms error {float(np.sqrt(np.mean(err**2))):.4g}, max {float(np.abs(err).max()):.4g} "
               f"(columns {', '.join(cols)})")
    click.echo(f"wrote {out}: next command, gain {gain:g}, filter {m}")


THESIS_CUTOFF = 16.0  # rad/s, the cut-off of the thesis's filtering example (Fig. 7.9)


def _simulate(t, r, cols, cycles, gain, cut, mode, as_json) -> None:
    """Plain learning, the chosen filter and the thesis's filter (eq. 7.12 as
    printed, 16 rad/s) side by side on the simulated servo axis."""
    import numpy as np

    from doodlecam.motion.servo import ServoAxis, learning_cycles

    axis0 = ServoAxis(accel_limit=1.0, noise=0.0005)
    results = {}
    for i, c in enumerate(cols):
        ref = r[:, i]
        acc = np.gradient(np.gradient(ref, t), t)
        peak = float(np.abs(acc).max())
        if peak == 0:
            continue
        from dataclasses import replace

        axis = replace(axis0, accel_limit=3.0 * peak)
        runs = {"plain": learning_cycles(axis, t, ref, cycles, gain, None),
                "filtered": learning_cycles(axis, t, ref, cycles, gain, cut, mode),
                "thesis": learning_cycles(axis, t, ref, cycles, gain, THESIS_CUTOFF, "command")}
        results[c] = {"accel_limit": axis.accel_limit, **{k: [s.__dict__ for s in v] for k, v in runs.items()},
                      **{f"{k}_saturates_at": next((s.cycle for s in v if s.saturated > 0), None) for k, v in runs.items()}}
    if as_json:
        click.echo(json.dumps({"gain": gain, "cutoff_rad_s": cut, "mode": mode, "thesis_cutoff_rad_s": THESIS_CUTOFF,
                               "servo": {"bandwidth_hz": axis0.bandwidth, "damping": axis0.damping, "tick_s": axis0.tick},
                               "columns": results}, indent=2))
        return
    click.echo(f"simulated servo axis: {axis0.bandwidth:g} Hz, damping {axis0.damping:g}, controller every "
               f"{axis0.tick * 1e6:g} µs, actuator limit 3x the reference's peak acceleration; gain {gain:g}")
    click.echo(f"columns: plain learning (eq. 7.5) | filtered ({mode}, cut-off {cut:.4g} rad/s) | "
               f"thesis filter (eq. 7.12 as printed, {THESIS_CUTOFF:g} rad/s); rms error, sat = share of servo ticks saturated")
    for c, res in results.items():
        click.echo(f"{c} (limit {res['accel_limit']:.4g} mm/s²)")
        click.echo(f"{'cycle':>6} {'plain':>10} {'sat':>6}   {'filtered':>10} {'sat':>6}   {'thesis':>10} {'sat':>6}")
        for p, f, h in zip(res["plain"], res["filtered"], res["thesis"]):
            click.echo(f"{p['cycle']:>6} {p['rms_error']:>10.3g} {p['saturated']:>6.1%}   "
                       f"{f['rms_error']:>10.3g} {f['saturated']:>6.1%}   {h['rms_error']:>10.3g} {h['saturated']:>6.1%}")
        said = {k: res[f"{k}_saturates_at"] for k in ("plain", "filtered", "thesis")}
        click.echo("  " + "; ".join(f"{k}: " + (f"saturates at cycle {v}" if v else "never saturates") for k, v in said.items()))
