"""The ``doodlecam`` command line.

Only click is imported at start-up; every command imports the stages it needs,
so ``doodlecam --help`` answers fast. Errors a user can cause print one line
and exit non-zero, without a traceback.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from . import __version__
from .errors import DoodleError

PLUGIN_DIR = click.option("--plugin-dir", "plugin_dirs", multiple=True, type=click.Path(file_okay=False),
                          help="Folder of drop-in plugin .py files (repeatable; also $DOODLECAM_PLUGIN_PATH).")


def _pairs(values: tuple[str, ...], what: str) -> dict[str, str]:
    out = {}
    for v in values:
        key, sep, val = v.partition("=")
        if not sep or not key:
            raise click.BadParameter(f"'{v}' is not KEY=VALUE", param_hint=what)
        out[key.strip()] = val
    return out


# Commands that live in their own modules, imported only when invoked (or
# when --help lists them): "name": "module:function".
LAZY_COMMANDS: dict[str, str] = {
    "send": "doodlecam.cli_send:send",
    "sim": "doodlecam.cli_send:sim",
    "plot": "doodlecam.cli_plot:plot",
    "motion": "doodlecam.cli_motion:motion",
    "learn": "doodlecam.cli_motion:learn",
    "batch": "doodlecam.cli_batch:batch",
    "plugins": "doodlecam.cli_plugins:plugins",
}


class LazyGroup(click.Group):
    """A click group that imports a command's module only when it is needed."""

    def list_commands(self, ctx):
        return sorted(set(super().list_commands(ctx)) | set(LAZY_COMMANDS))

    def get_command(self, ctx, name):
        if name in LAZY_COMMANDS and name not in self.commands:
            import importlib

            module, attr = LAZY_COMMANDS[name].split(":")
            return getattr(importlib.import_module(module), attr)
        return super().get_command(ctx, name)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="doodlecam")
def cli():
    """Turn pictures into time-optimal pen-plotter jobs.

    \b
    trace -> fit B-splines -> order -> plan (time-optimal) -> sample -> post
    Start with:  doodlecam convert samples/images/camera.png -o out/
    """


def job_options(f):
    """The options every job-making command shares (convert, batch, plot ...)."""
    opts = [
        click.option("-m", "--machine", default="doodlebot", show_default=True, help="Machine profile: a name or a .toml path."),
        click.option("--tracer", help="Tracer plugin (default: chosen by file type; 'edges' for pictures)."),
        click.option("--tracer-opt", multiple=True, metavar="KEY=VALUE", help="Tracer option (repeatable)."),
        click.option("--post", "posts", multiple=True, metavar="NAME",
                     help="Post-processor (repeatable). Default: plc, gcode and svg."),
        click.option("--post-opt", multiple=True, metavar="POST.KEY=VALUE",
                     help="Post option, e.g. gcode.pen_up='M5' (repeatable)."),
        click.option("--solver", help="Planner: reach (exact, fast; default), lp[:clarabel|highs|osqp] (cross-check), "
                     "qp[:clarabel|highs|osqp] (smoothed). Default: the profile's [machine] solver."),
        click.option("--smoothing", type=float, help="Weight of the smoothing QP against time (solver qp). Default: the profile's."),
        click.option("--path-tolerance", type=float, metavar="MM",
                     help="Keep the pen within MM of the curve between velocity samples too (0 = off: faster "
                     "drawing, the pen may stray ~0.7 mm). Default: the profile's [sampling] path_tolerance, "
                     "else its fit tolerance."),
        click.option("--width", type=float, metavar="MM", help="Target drawing width in mm (aspect kept). Default: fill the work area."),
        click.option("--height", type=float, metavar="MM", help="Target drawing height in mm (aspect kept)."),
        click.option("--scale", type=float, metavar="MM", help="Fixed scale: mm per source unit (px, or mm: 1 = an SVG/DXF at true size)."),
        click.option("--margin", type=float, metavar="MM", help="Margin inside the work area (default: the profile's)."),
        click.option("--rotate", type=click.Choice(["0", "90", "180", "270", "auto"]),
                     help="Quarter turns counter-clockwise; auto turns the drawing when it then fits larger."),
        click.option("--fit", type=click.Choice(["canvas", "ink"]),
                     help="Fit the whole picture frame (canvas) or only what is drawn (ink)."),
        click.option("--keep-direction", is_flag=True, default=None,
                     help="Never draw a stroke backwards (for pens that draw differently each way)."),
        PLUGIN_DIR,
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def job_kwargs(machine, tracer, tracer_opt, posts, post_opt, solver, smoothing, path_tolerance, width, height, scale,
               margin, rotate, fit, keep_direction, plugin_dirs) -> dict:
    """The shared options, parsed: keyword arguments for pipeline.Settings
    (with ``machine`` still the profile's name or path)."""
    post_opts: dict[str, dict[str, str]] = {}
    for key, val in _pairs(post_opt, "--post-opt").items():
        name, dot, opt = key.partition(".")
        if not dot:
            raise click.BadParameter(f"'{key}' must be POST.KEY=VALUE, e.g. gcode.pen_up=M5", param_hint="--post-opt")
        post_opts.setdefault(name, {})[opt] = val
    posts = tuple(posts) or ("plc", "gcode", "svg")
    if path_tolerance is not None and not path_tolerance >= 0:
        raise click.BadParameter(f"must be 0 (off) or a distance in mm, got {path_tolerance:g}", param_hint="--path-tolerance")
    unused = set(post_opts) - set(posts)
    if unused:
        raise click.BadParameter(f"options given for '{sorted(unused)[0]}', which is not among the posts {', '.join(posts)}",
                                 param_hint="--post-opt")
    return dict(
        machine=machine, tracer=tracer, tracer_options=_pairs(tracer_opt, "--tracer-opt"), posts=posts,
        post_options=post_opts, solver=solver, smoothing=smoothing, path_tolerance=path_tolerance,
        plugin_dirs=tuple(plugin_dirs),
        layout={k: v for k, v in dict(width=width, height=height, scale=scale, margin=margin, rotate=rotate, fit=fit).items()
                if v is not None},
        order={"reverse": False} if keep_direction else {},
    )


@cli.command()
@click.argument("input", type=click.Path(path_type=Path))
@click.option("-o", "--out", "outdir", type=click.Path(path_type=Path), default=Path("out"), show_default=True,
              help="Output folder (created if needed).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
@job_options
def convert(input, outdir, as_json, **options):
    """Convert a picture into a machine job: PLC packet file, G-code and SVG preview."""
    from .machine import load_machine
    from .pipeline import Settings, convert as run

    kw = job_kwargs(**options)
    settings = Settings(**{**kw, "machine": load_machine(kw["machine"])})
    result = run(input, outdir, settings)
    s = result.summary()
    if as_json:
        click.echo(json.dumps(s, indent=2))
        return
    click.echo(f"{input} -> {outdir}/  (machine {s['machine']}, solver {result.job.meta['solver']})")
    click.echo(f"  strokes            {s['strokes']}  ({s['control_points']} control points, fit within {s['max_fit_error_mm']:.3f} mm)")
    click.echo(f"  pen-down length    {s['pen_down_mm']:.1f} mm")
    click.echo(f"  travel length      {s['travel_mm']:.1f} mm")
    by_law = s["travel_time_by_law_s"]
    if by_law:
        base = by_law.get("trapezoid", 0.0)
        click.echo(f"  travel law         {s['travel_law']}: {by_law.get(s['travel_law'], 0):.1f} s pen-up; smooth laws cost "
                   + ", ".join(f"{k} {v - base:+.1f} s" for k, v in by_law.items() if k != "trapezoid"))
    click.echo(f"  planned job time   {s['job_time_s']:.1f} s  (drawing {s['draw_time_s']:.1f} s, {s['samples']} velocity samples)")
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
    click.echo("  wrote              " + ", ".join(s["outputs"]))


@cli.command()
def machines():
    """List the machine profiles found on the search path."""
    from .machine import available_machines, load_machine

    for name, path in available_machines().items():
        try:
            desc = load_machine(path).description
        except DoodleError as e:
            desc = f"INVALID: {e}"
        click.echo(f"  {name:<12} {desc}  [{path}]")


@cli.command()
@click.argument("file", type=click.Path(path_type=Path))
@click.option("--csv", "as_csv", is_flag=True, help="Print the commands as CSV.")
@click.option("--limit", default=20, show_default=True, help="Commands to show (0 = all).")
def inspect(file, as_csv, limit):
    """Print a PLC packet file: header and commands."""
    from .errors import InputError
    from .plcfile import read_plc, to_csv

    try:
        data = file.read_bytes()
    except OSError as e:
        raise InputError(f"{file}: cannot read ({e.strerror}); check the path") from None
    header, commands = read_plc(data, name=str(file))
    if as_csv:
        click.echo(to_csv(header, commands), nl=False)
        return
    for key, val in vars(header).items():
        click.echo(f"{key:<16} {val}")
    shown = commands if limit == 0 else commands[:limit]
    click.echo(f"{'command_no':>10} {'type':>5} {'x':>10} {'y':>10}")
    for c in shown:
        click.echo(f"{c.command_no:>10} {('DRAW', 'MOVE')[c.type]:>5} {c.x:>10} {c.y:>10}")
    if len(shown) < len(commands):
        click.echo(f"... {len(commands) - len(shown)} more (--limit 0 shows all)")


def main(argv=None) -> int:
    try:
        rv = cli.main(args=argv, prog_name="doodlecam", standalone_mode=False)
        if isinstance(rv, int):  # click returns Exit codes instead of raising without standalone mode
            return rv
    except click.exceptions.Exit as e:
        return e.exit_code
    except click.ClickException as e:
        e.show()
        return e.exit_code
    except click.exceptions.Abort:
        click.echo("doodlecam: aborted", err=True)
        return 130
    except KeyboardInterrupt:
        click.echo("doodlecam: interrupted; no output was written", err=True)
        return 130
    except DoodleError as e:
        click.echo(f"doodlecam: error: {e}", err=True)
        return e.exit_code
    return 0


def entry() -> None:
    """Console-script entry point."""
    sys.exit(main())
