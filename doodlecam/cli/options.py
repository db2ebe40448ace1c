"""The options that several commands share (convert, batch, plot, plugins).
"""

from __future__ import annotations

import click

from doodlecam.cli import complete

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




def post_options(post_opt: tuple[str, ...]) -> dict[str, dict[str, str]]:
    """``--post-opt POST.KEY=VALUE`` values as {post: {key: value}}."""
    out: dict[str, dict[str, str]] = {}
    for key, val in _pairs(post_opt, "--post-opt").items():
        name, dot, opt = key.partition(".")
        if not dot:
            raise click.BadParameter(f"'{key}' must be POST.KEY=VALUE, e.g. gcode.pen_up=M5", param_hint="--post-opt")
        out.setdefault(name, {})[opt] = val
    return out


LAYOUT_OPTIONS = [
    click.option("--width", metavar="LENGTH", help="Target drawing width (aspect kept): mm, or with a unit "
                 "(20cm, 8in, 600px). Default: fill the work area (or the page)."),
    click.option("--height", metavar="LENGTH", help="Target drawing height (aspect kept), as --width."),
    click.option("--page", metavar="SIZE", help="Paper: a4, a3, letter, ... or WxH with units (210x297mm, 5x4in), "
                 "centred on the work area; the drawing fits inside it, within the margin."),
    click.option("--landscape/--portrait", "landscape", default=None, help="Turn the page (default: as named)."),
    click.option("--scale", type=float, metavar="MM", help="Fixed scale: mm per source unit (px, or mm: 1 = an SVG/DXF at true size)."),
    click.option("--margin", metavar="LENGTH", help="Margin inside the work area or page, mm or with a unit (default: the profile's)."),
    click.option("--rotate", type=click.Choice(["0", "90", "180", "270", "auto"]),
                 help="Quarter turns counter-clockwise; auto turns the drawing when it then fits larger."),
    click.option("--fit", type=click.Choice(["canvas", "ink"]),
                 help="Fit the whole picture frame (canvas) or only what is drawn (ink)."),
    click.option("--layer", metavar="NAME", help="Convert only this layer (an SVG/DXF layer or colour), "
                 "placed where it is in the whole drawing."),
    click.option("--keep-direction", is_flag=True, default=None,
                 help="Never draw a stroke backwards (for pens that draw differently each way)."),
]


def layout_options(f):
    """The layout options alone (plot): size, scale, margin, rotation, fit, direction."""
    for opt in reversed(LAYOUT_OPTIONS):
        f = opt(f)
    return f


def layout_kwargs(width, height, page, landscape, scale, margin, rotate, fit, layer, keep_direction) -> dict:
    """``layout``, ``order`` and ``layer`` for pipeline.Settings from the layout options."""
    orientation = None if landscape is None else ("landscape" if landscape else "portrait")
    return dict(layout={k: v for k, v in dict(width=width, height=height, scale=scale, margin=margin, rotate=rotate,
                                                 fit=fit, page=page, orientation=orientation).items() if v is not None},
                order={"reverse": False} if keep_direction else {}, layer=layer)


def job_options(f):
    """The options every job-making command shares (convert, batch, plot ...)."""
    opts = [
        click.option("-m", "--machine", default="doodlebot", show_default=True, shell_complete=complete.machines,
                     help="Machine profile: a name or a .toml path."),
        click.option("--tracer", shell_complete=complete.tracers, help="Tracer plugin (default: chosen by file type; 'auto' for pictures: centre lines for line art, else edges)."),
        click.option("--tracer-opt", multiple=True, metavar="KEY=VALUE", help="Tracer option (repeatable)."),
        click.option("--post", "posts", multiple=True, metavar="NAME", shell_complete=complete.posts,
                     help="Post-processor (repeatable). Default: plc, gcode and svg."),
        click.option("--post-opt", multiple=True, metavar="POST.KEY=VALUE",
                     help="Post option, e.g. gcode.pen_up='M5' (repeatable)."),
        click.option("--solver", shell_complete=complete.solvers, help="Planner: reach (exact, fast; default), lp[:clarabel|highs|osqp] (cross-check), "
                     "qp[:clarabel|highs|osqp] (smoothed). Default: the profile's [machine] solver."),
        click.option("--smoothing", type=float, help="Weight of the smoothing QP against time (solver qp). Default: the profile's."),
        click.option("--path-tolerance", type=float, metavar="MM",
                     help="Keep the pen within MM of the curve between velocity samples too (0 = off: faster "
                     "drawing, the pen may stray ~0.7 mm). Default: the profile's [sampling] path_tolerance, "
                     "else its fit tolerance."),
        *LAYOUT_OPTIONS,
        click.option("--allow-deviation", is_flag=True, default=False,
                     help="Write the job even when a measured figure (fit error, pen off the curve between "
                     "samples, a limit) is over its bound; without it such a job fails with the reason."),
        PLUGIN_DIR,
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def job_kwargs(machine, tracer, tracer_opt, posts, post_opt, solver, smoothing, path_tolerance, width, height, page,
               landscape, scale, margin, rotate, fit, layer, keep_direction, plugin_dirs, allow_deviation=False) -> dict:
    """The shared options, parsed: keyword arguments for pipeline.Settings
    (with ``machine`` still the profile's name or path)."""
    post_opts = post_options(post_opt)
    posts = tuple(posts) or ("plc", "gcode", "svg")
    if path_tolerance is not None and not path_tolerance >= 0:
        raise click.BadParameter(f"must be 0 (off) or a distance in mm, got {path_tolerance:g}", param_hint="--path-tolerance")
    unused = {k for k in post_opts if k.casefold() not in {p.casefold() for p in posts}}  # names in any case
    if unused:
        raise click.BadParameter(f"options given for '{sorted(unused)[0]}', which is not among the posts {', '.join(posts)}",
                                 param_hint="--post-opt")
    return dict(
        machine=machine, tracer=tracer, tracer_options=_pairs(tracer_opt, "--tracer-opt"), posts=posts,
        post_options=post_opts, solver=solver, smoothing=smoothing, path_tolerance=path_tolerance,
        plugin_dirs=tuple(plugin_dirs), allow_deviation=bool(allow_deviation),
        **layout_kwargs(width, height, page, landscape, scale, margin, rotate, fit, layer, keep_direction),
    )
