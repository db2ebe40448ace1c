"""``doodlecam calibrate``: a test pattern to measure steps/mm and find the speed and acceleration to keep.
"""

from __future__ import annotations

from pathlib import Path

import click

from doodlecam.cli import complete

from doodlecam.cli.options import PLUGIN_DIR, post_options


def _factors(ctx, param, value: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value.split(",") if v.strip())
    except ValueError:
        raise click.BadParameter(f"'{value}' is not a comma-separated list of numbers, e.g. 0.5,0.75,1,1.25") from None
    if not out or any(not 0.05 <= f <= 4.0 for f in out):
        raise click.BadParameter("give factors between 0.05 and 4, e.g. 0.5,0.75,1,1.25,1.5")
    return out


@click.command()
@click.option("-m", "--machine", default="doodlebot", show_default=True, shell_complete=complete.machines, help="Machine profile: a name or a .toml path.")
@click.option("-o", "--out", "outdir", type=click.Path(path_type=Path), default=Path("out"), show_default=True,
              help="Output folder: writes calibrate.plc, .gcode, .svg (or the --post files).")
@click.option("--factors", default="0.5,0.75,1,1.25,1.5", show_default=True, callback=_factors,
              help="One row per factor: the profile's speeds and accelerations times it (bottom row first).")
@click.option("--post", "posts", multiple=True, metavar="NAME", shell_complete=complete.posts, help="Post-processor (repeatable). Default: plc, gcode, svg.")
@click.option("--post-opt", multiple=True, metavar="POST.KEY=VALUE", help="Post option, e.g. gcode.pen_up='M5'.")
@PLUGIN_DIR
def calibrate(machine, outdir, factors, posts, post_opt, plugin_dirs):
    """Write a calibration pattern job for MACHINE: rulers to measure, rows of rising speed/acceleration.

    \b
    Draw it, then (README, "Your machine"):
      steps/mm:  new = old x (ruler length printed below) / (length you measure)
      limits:    keep the factor of the last row drawn cleanly: no lost steps,
                 the sine's peaks sharp and in place, the straight line straight
    """
    from doodlecam.calibration import calibration_job
    from doodlecam.checks import check_settings
    from doodlecam.cli.firstrun import first_run_notice
    from doodlecam.machine import load_machine
    from doodlecam.pipeline import Settings, run_posts, write_outputs

    profile = load_machine(machine)
    settings = Settings(machine=profile, posts=tuple(posts) or ("plc", "gcode", "svg"), post_options=post_options(post_opt),
                        plugin_dirs=tuple(plugin_dirs))
    check_settings(settings, profile, (), outdir)  # before the planning
    first_run_notice()
    job, rows = calibration_job(profile, factors, plugin_dirs=plugin_dirs)
    written = write_outputs(outdir, "calibrate", run_posts(job, settings))
    m = profile
    lx = 10 * int(min(200.0, m.width - 2 * m.margin) // 10)
    ly = 10 * int(min(200.0, m.height - 2 * m.margin) // 10)
    click.echo(f"calibration pattern for {m.name}: {job.duration:.1f} s")
    click.echo(f"  rulers   bottom {lx} mm (x: steps/mm {m.x.steps_per_mm:g} x {lx} / measured), "
               f"left {ly} mm (y: steps/mm {m.y.steps_per_mm:g} x {ly} / measured)")
    for r in rows:
        over = "  (above the profile)" if r.factor > 1 else ""
        click.echo(f"  row {r.number}    {'|' * r.number:<6} x{r.factor:g}: {r.velocity:g} mm/s, {r.acceleration:g} mm/s^2, "
                   f"drawn in {r.duration:.1f} s{over}")
    click.echo("  wrote    " + ", ".join(str(p) for p in written))
