"""``doodlecam convert``: one picture or vector file into a machine job.
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from doodlecam.cli.options import job_kwargs, job_options


@click.command()
@click.argument("input", type=click.Path(path_type=Path))
@click.option("-o", "--out", "outdir", type=click.Path(path_type=Path), default=Path("out"), show_default=True,
              help="Output folder (created if needed).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@click.option("-w", "--workers", type=click.IntRange(min=1), default=None,
              help="Processes planning the strokes of a large drawing (default: up to 2, the CPUs available); "
              "the files are the same with any number.")
@job_options
def convert(input, outdir, as_json, workers, **options):
    """Convert a picture into a machine job: PLC packet file, G-code and SVG preview."""
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings
    from doodlecam.pipeline import convert as run

    from doodlecam.checks import check_input, check_settings
    from doodlecam.cli.firstrun import first_run_notice

    from doodlecam.plan.stroke import default_workers

    kw = job_kwargs(**options)
    settings = Settings(**{**kw, "machine": load_machine(kw["machine"])}, workers=workers or default_workers())
    check_input(input)
    check_settings(settings, settings.machine, [input], outdir)  # (convert checks again: cheap)
    from doodlecam.cli.progress import Stages, verbosity

    first_run_notice()
    with Stages(input.name, verbosity()) as stages:  # a status line on a terminal; stage times with -v
        result = run(input, outdir, settings, progress=stages)
    s = result.summary()
    if as_json:
        click.echo(json.dumps(s, indent=2))
        return
    click.echo(f"{input} -> {outdir}/  (machine {s['machine']}, solver {result.job.meta['solver']})")
    if s.get("tracer"):
        click.echo(f"  tracer             {s['tracer']} ({s['tracer_reason']})"
                   + (f"; ink lines {s['line_width_mm']:.2f} mm wide" if s.get("line_width_mm") else ""))
    if s.get("tracer_made"):
        click.echo(f"  made               {s['tracer_made']}")
    click.echo(f"  strokes            {s['strokes']}  ({s['control_points']} control points, fit within {s['max_fit_error_mm']:.3f} mm; "
               f"{s['pen_lifts']} pen lift{'s' if s['pen_lifts'] != 1 else ''})")
    click.echo(f"  pen-down length    {s['pen_down_mm']:.1f} mm")
    if s.get("corners_kept"):
        click.echo(f"  corners kept       {s['corners_kept']}: exact, the pen stops on each without lifting")
    click.echo(f"  travel length      {s['travel_mm']:.1f} mm")
    by_law = s["travel_time_by_law_s"]
    if by_law:
        base = by_law.get("trapezoid", 0.0)
        click.echo(f"  travel law         {s['travel_law']}: {by_law.get(s['travel_law'], 0):.1f} s pen-up; smooth laws cost "
                   + ", ".join(f"{k} {v - base:+.1f} s" for k, v in by_law.items() if k != "trapezoid"))
    click.echo(f"  planned job time   {s['job_time_s']:.1f} s  (drawing {s['draw_time_s']:.1f} s, {s['samples']} velocity samples)")
    if s.get("grbl_estimate_s") is not None:
        click.echo(f"  GRBL's time        {s['grbl_estimate_s']:.1f} s for the G-code (GRBL 1.1's planner: its "
                   "junctions, look-ahead and step-rounded targets)")
    click.echo(f"  limits             acceleration <= {s['worst_acceleration_ratio']:.6f}, velocity <= "
               f"{s['worst_velocity_ratio']:.6f} of the limit (checked on a 20x finer grid)")
    if s.get("worst_ramp_ratio") is not None:  # nonlinear kinematics: the cranks along the sampled ramps
        click.echo(f"                     actuators along the sampled ramps <= {s['worst_ramp_ratio']:.6f} of their limits"
                   + (f" ({s['strokes_slowed_for_ramps']} stroke{'s' if s['strokes_slowed_for_ramps'] > 1 else ''} "
                      "planned slower for it)" if s["strokes_slowed_for_ramps"] else ""))
    enforced = s["path_tolerance_mm"] > 0
    click.echo(f"  pen on the curve   within half a step at every sample instant; up to "
               f"{s['max_between_samples_mm']:.3f} mm off between instants"
               + (f" (kept within {s['path_tolerance_mm']:g} mm)" if enforced else ""))
    if not enforced and s["max_between_samples_mm"] > s["max_fit_error_mm"]:
        click.echo("                     (the PLC's linear ramps; set [sampling] path_tolerance in the machine profile "
                   "to keep within it, docs/sampling.md)")
    if s["layers"]:
        how = "grouped by pen" if s["layer_order"] == "pen" else "one after another"
        click.echo(f"  layers             {len(s['layers'])}, plotted {how}: "
                   + ", ".join(f"{n} with {s['pens'][n]}" for n in s["layers"]))
        for c in s["pen_choice"]:
            click.echo(f"                     {c['layer']}" + (f" ({c['colour']})" if c["colour"] else "")
                       + f" -> {c['pen']}: {c['why']}")
    if s["pen_changes"] or s["first_pen_prompt"]:
        first = f" and first to fit {s['first_pen_prompt']}" if s["first_pen_prompt"] else ""
        click.echo(f"  pen changes        {s['pen_changes']}: the job pauses for each{first}, pen up (G-code M0, PLC "
                   "PAUSE); 'doodlecam send' asks the operator")
    click.echo("  wrote              " + ", ".join(s["outputs"]))
    for w in s["warnings"]:
        click.echo(f"  warning: {w}", err=True)
