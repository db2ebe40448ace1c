"""``doodlecam plot``: the report's figures for planned strokes of a picture."""

from __future__ import annotations

from pathlib import Path

import click

from doodlecam.cli import complete

from doodlecam.cli.options import PLUGIN_DIR, _pairs, layout_kwargs, layout_options


@click.command("plot")
@click.argument("input", type=click.Path(path_type=Path))
@click.option("-o", "--out", type=click.Path(path_type=Path), default=None,
              help="Figure file, .png or .svg (or .pdf). Default: out/<picture>.png. "
                   "Several strokes give FILE_strokeN.png each.")
@click.option("-m", "--machine", default="doodlebot", show_default=True, shell_complete=complete.machines, help="Machine profile: a name or a .toml path.")
@click.option("--stroke", "strokes", multiple=True, type=int, metavar="N",
              help="Stroke to plot, numbered from 1 in drawing order (repeatable). Default: the longest.")
@click.option("--tracer", shell_complete=complete.tracers, help="Tracer plugin (default: chosen by file type; 'edges' for pictures).")
@click.option("--tracer-opt", multiple=True, metavar="KEY=VALUE", help="Tracer option (repeatable).")
@click.option("--solver", shell_complete=complete.solvers, help="Planner back-end (as for convert). Default: the profile's.")
@layout_options
@PLUGIN_DIR
def plot(input, out, machine, strokes, tracer, tracer_opt, solver, plugin_dirs, **layout):
    """Plot planned strokes of a picture: path, positions, path velocity, axis
    velocities and accelerations against their limits (report Fig. 2.4.1-2.4.5)."""
    from doodlecam.checks import check_input, check_settings
    from doodlecam.cli.firstrun import first_run_notice
    from doodlecam.extras import require
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, plan_job, select_layer, trace
    from doodlecam.registry import kinematics_for
    from doodlecam.plot import output_paths, pick_strokes, plot_job
    from doodlecam.trace.layout import fit_to_work_area

    require("plot", "doodlecam plot")
    out = Path(out) if out is not None else Path("out") / f"{Path(input).stem}.png"
    output_paths(out, [0])  # a bad extension fails before any work
    settings = Settings(machine=load_machine(machine), tracer=tracer, tracer_options=_pairs(tracer_opt, "--tracer-opt"),
                        posts=(), solver=solver, plugin_dirs=tuple(plugin_dirs), **layout_kwargs(**layout))
    check_input(Path(input))
    check_settings(settings, settings.machine, [Path(input)], out.parent)  # every mistake before the tracing
    first_run_notice()
    drawing = select_layer(fit_to_work_area(trace(Path(input), settings), settings.machine, settings.layout),
                           settings.layer)
    job = plan_job(drawing, settings.machine, settings.solver or settings.machine.solver, settings.plugin_dirs,
                   order=settings.order)
    pick_strokes(job, strokes)  # a bad --stroke fails before drawing
    written = plot_job(job, out, strokes, kinematics_for(settings.machine, settings.plugin_dirs))
    for i, path in written:
        s = job.strokes[i]
        click.echo(f"stroke {i + 1} of {len(job.strokes)} ({s.spline.length:.1f} mm, {s.duration:.2f} s planned) -> {path}")
